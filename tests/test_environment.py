"""The fit command's compile choice, read from the environment by the application
(backend.app.environment), and the kernels made ahead in the background (backend.app.warm_compile)."""
import os
import stat
import time
import types

import pytest

from backend.app import warm_compile
from backend.app.environment import compiler_found, kernels_wanted, renderer_compiles
from backend.model import compile_cache
from backend.model.compile_cache import ENV, WARM_RECORD, kernels_key, kernels_warm, mark_warm


def _fake_compiler(folder, name):
    path = folder / name
    path.write_text("#!/bin/sh\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


@pytest.fixture
def machine(tmp_path):
    """An environment with a C++ compiler on its PATH and an empty kernel cache of its own."""
    tools = tmp_path / "bin"
    tools.mkdir()
    _fake_compiler(tools, "g++")
    return {"PATH": str(tools), ENV: str(tmp_path / "kernels")}


def test_wfc_compile_forces_the_choice_either_way(machine):
    assert renderer_compiles({"WFC_COMPILE": "1", "PATH": ""}) is True   # even without a compiler
    assert renderer_compiles({**machine, "WFC_COMPILE": "0"}) is False
    assert not kernels_wanted({**machine, "WFC_COMPILE": "0"}) and not kernels_wanted({**machine, "WFC_COMPILE": "1"})


def test_without_the_switch_a_compiler_on_the_path_decides(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert not compiler_found({"PATH": str(empty)})
    assert renderer_compiles({"PATH": str(empty), "WFC_COMPILE": "yes"}) is False  # only 0 and 1 force
    _fake_compiler(tmp_path, "clang++")
    assert renderer_compiles({"PATH": str(tmp_path)}, device="cuda") is True


def test_on_the_cpu_a_fit_compiles_once_the_kernels_are_warm_and_wants_them_made_till_then(machine):
    assert not kernels_warm(machine)
    assert renderer_compiles(machine) is False and kernels_wanted(machine)
    assert renderer_compiles(machine, device="cuda:0") is True and not kernels_wanted(machine, device="cuda")
    mark_warm(machine)
    assert kernels_warm(machine) and renderer_compiles(machine) is True and not kernels_wanted(machine)


def test_kernels_of_another_torch_or_model_code_are_cold(machine, monkeypatch):
    folder = mark_warm(machine).parent
    assert (folder / WARM_RECORD).read_text().count(kernels_key()) == 1
    monkeypatch.setattr(compile_cache, "kernels_key", lambda: "2.99.0/0123456789abcdef0123")
    assert not kernels_warm(machine)
    (folder / WARM_RECORD).write_text("not json")
    assert not kernels_warm(machine)


def test_the_key_follows_the_model_s_code(tmp_path, monkeypatch):
    key = kernels_key()
    model = tmp_path / "model"
    model.mkdir()
    (model / "compile_cache.py").write_text("")
    (model / "bsdf.py").write_text("a = 1\n")
    monkeypatch.setattr(compile_cache, "__file__", str(model / "compile_cache.py"))
    first = kernels_key()
    (model / "bsdf.py").write_text("a = 2\n")
    assert len({key, first, kernels_key()}) == 3


def test_a_cold_fit_starts_one_background_warm_up_at_a_time(machine, monkeypatch):
    started = []
    monkeypatch.setattr(warm_compile.subprocess, "Popen", lambda argv, **kwargs: started.append((argv, kwargs)))
    assert warm_compile.start_warming(machine)
    argv, kwargs = started[0]
    assert argv[-3:] == ["-m", "backend", "warm-compile"] and kwargs["stdin"] == warm_compile.subprocess.DEVNULL
    assert argv[1:-3] == warm_compile.interpreter_flags()
    assert kwargs.get("start_new_session") or kwargs.get("creationflags")  # its own session: it outlives no one's
    assert not warm_compile.start_warming(machine)  # one is running: its lock is fresh
    lock = compile_cache.cache_folder(machine) / warm_compile.LOCK
    old = time.time() - warm_compile.STALE_LOCK_S - 60
    os.utime(lock, (old, old))
    assert warm_compile.start_warming(machine) and len(started) == 2  # a stale lock: the last one died
    lock.unlink()
    mark_warm(machine)
    assert not warm_compile.start_warming(machine) and not warm_compile.start_warming({**machine, "WFC_COMPILE": "0"})
    assert len(started) == 2


def test_the_warm_up_compiles_the_fit_renderer_s_graphs_then_records_them(machine, monkeypatch):
    """The renderers it builds are a fit's (compiled, every optimised parameter's gradient, a chunk of
    2^20 samples), with and without a variation's per-sample albedo; the record follows."""
    built = []
    real = warm_compile.Renderer

    class Recording(real):
        def __init__(self, *args, **kwargs):
            built.append((args, kwargs))
            super().__init__(*args, **{**kwargs, "compile": False})

        @property
        def compiled(self):
            return True

    for name, value in machine.items():
        monkeypatch.setenv(name, value)
    monkeypatch.setattr(warm_compile, "Renderer", Recording)
    warm_compile.warm_kernels(size=32, spp=4)
    assert [kwargs["compile"] for _, kwargs in built] == [True, True]
    assert all(tuple(kwargs["gradient_inputs"]) == tuple(warm_compile.OPTIMISED) for _, kwargs in built)
    assert warm_compile.WARM_FABRIC.brightness_variation == (0.0, 0.0) != warm_compile.WARM_VARIED.brightness_variation
    assert kernels_warm(machine)
    assert warm_compile.warm_kernels.__defaults__ == (512, 4)  # 512 px x 4 spp: one chunk of 2^20 samples


def test_the_warm_up_runs_with_the_fit_s_isolation_flags():
    blender = types.SimpleNamespace(no_site=1, no_user_site=0, safe_path=True)  # the add-on's -S -P
    assert warm_compile.interpreter_flags(blender) == ["-S", "-P"]
    assert warm_compile.interpreter_flags(types.SimpleNamespace(no_site=0, no_user_site=0)) == []


def test_cxx_names_the_compiler(tmp_path):
    _fake_compiler(tmp_path, "my-cxx")
    assert compiler_found({"PATH": str(tmp_path), "CXX": "my-cxx"})
    assert not compiler_found({"PATH": str(tmp_path)})
