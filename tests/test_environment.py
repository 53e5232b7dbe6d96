"""The fit command's compile choice, read from the environment by the application (backend.app.environment)."""
import os
import stat

from backend.app.environment import compiler_found, renderer_compiles


def _fake_compiler(folder, name):
    path = folder / name
    path.write_text("#!/bin/sh\n")
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def test_wfc_compile_forces_the_choice_either_way():
    assert renderer_compiles({"WFC_COMPILE": "1", "PATH": ""}) is True   # even without a compiler
    assert renderer_compiles({"WFC_COMPILE": "0", "PATH": os.environ.get("PATH", "")}) is False


def test_without_the_switch_a_compiler_on_the_path_decides(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert not compiler_found({"PATH": str(empty)})
    assert renderer_compiles({"PATH": str(empty), "WFC_COMPILE": "yes"}) is False  # only 0 and 1 force
    _fake_compiler(tmp_path, "clang++")
    assert renderer_compiles({"PATH": str(tmp_path)}) is True


def test_cxx_names_the_compiler(tmp_path):
    _fake_compiler(tmp_path, "my-cxx")
    assert compiler_found({"PATH": str(tmp_path), "CXX": "my-cxx"})
    assert not compiler_found({"PATH": str(tmp_path)})
