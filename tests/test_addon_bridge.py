"""The add-on's plain-Python side (blender_addon/core) without Blender: the facts it reads from the
backend, the backend bridge against a fake backend, the backend check, result folders, the rig's
settings and the batch.

The fake backend (tests/fake_backend.py) speaks the fit command's protocol in a fraction of a
second and can misbehave on request (FAKE_BACKEND_MODE).
"""
from __future__ import annotations

import ast
import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import fake_backend  # noqa: E402
from addon_support import python_without_torch  # noqa: E402
from fake_backend import fake_params  # noqa: E402

import backend.core.dependencies  # noqa: E402
import backend.core.formats  # noqa: E402
import backend.core.pair_jobs  # noqa: E402
import backend.core.pairs  # noqa: E402
import backend.core.params  # noqa: E402
import backend.core.priors  # noqa: E402
import backend.core.protocol  # noqa: E402
import backend.core.results  # noqa: E402
import backend.core.rig  # noqa: E402
import backend.core.weave  # noqa: E402
from blender_addon.core import backend_bridge as bridge  # noqa: E402
from blender_addon.core import backend_setup as setup  # noqa: E402
from blender_addon.core import (  # noqa: E402
    batch,
    batch_queue,
    captures,
    checklist,
    declarations,
    gpu_env,
    paths,
    rig_settings,
)
from blender_addon.core.check_job import BackendCheckJob  # noqa: E402

FAKE_BACKEND = Path(__file__).resolve().parent / "fake_backend.py"
BACKEND_SCRIPT = str(FAKE_BACKEND)
PNG_1x1 = bytes.fromhex("89504e470d0a1a0a0000000d4948445200000001000000010806000000"
                        "1f15c4890000000d49444154789c6360f8cfc0f01f0005000201d1b5a0550000000049454e44ae426082")
HANG_S = 60  # a liveness bound (a hung run fails instead of blocking the suite), not a timing


@pytest.fixture
def photos(tmp_path):
    reflection, transmission = tmp_path / "cloth_R.png", tmp_path / "cloth_T.png"
    reflection.write_bytes(PNG_1x1)
    transmission.write_bytes(PNG_1x1)
    return reflection, transmission


def run_fit(tmp_path, photos, mode="ok", monkeypatch=None, **request):
    if monkeypatch is not None:
        monkeypatch.setenv("FAKE_BACKEND_MODE", mode)
    fit = bridge.FitProcess.fit(bridge.Backend(sys.executable, BACKEND_SCRIPT),
                                bridge.FitRequest(*photos, out_dir=tmp_path / "out", iterations=5, **request),
                                log_path=tmp_path / "out" / "backend.log")
    return fit.start()


# -- the facts the add-on shares with the backend ---------------------------------------------------

def test_the_addon_reads_the_backends_own_declarations():
    """Each shared fact comes from the backend's file itself, so the two sides cannot drift."""
    for name, module in (("core.formats", backend.core.formats), ("core.pairs", backend.core.pairs),
                         ("core.pair_jobs", backend.core.pair_jobs),
                         ("core.params", backend.core.params), ("core.priors", backend.core.priors),
                         ("core.protocol", backend.core.protocol), ("core.results", backend.core.results),
                         ("core.rig", backend.core.rig), ("core.weave", backend.core.weave)):
        assert Path(paths.backend_module(name).__file__).resolve() == Path(module.__file__).resolve(), name
    for suffix in (*backend.core.formats.PHOTO_SUFFIXES, ".txt"):
        for case in (suffix, suffix.upper()):
            assert declarations.is_raw(case) == backend.core.formats.is_raw(case), case
    assert declarations.fit_patterns() == ("auto", *backend.core.priors.FIT_PATTERNS)
    assert declarations.preset_names() == tuple(backend.core.weave.PRESETS)
    assert [s.name for s in declarations.parameters()] == [s.name for s in backend.core.params.PARAMETERS]
    assert declarations.default_params() == backend.core.params.FabricParams().to_dict()
    assert rig_settings.defaults() == backend.core.rig.DEFAULT_RIG.to_dict()
    assert declarations.protocol().STAGES == backend.core.protocol.STAGES
    assert declarations.result_files() == backend.core.results.RESULT_FILES


def test_rig_fields_are_the_capture_rigs_fields_with_its_defaults(tmp_path):
    fields = rig_settings.rig_fields()
    rig = backend.core.rig.DEFAULT_RIG
    assert [f.name for f in fields] == [f.name for f in dataclasses.fields(backend.core.rig.CaptureRig)]
    for field in fields:
        expected = getattr(rig, field.name)
        assert field.default == (0.0 if expected is None else expected), field.name
    kinds = {f.name: f.kind for f in fields}
    assert kinds["front_light"] == "vector" and kinds["film_size"] == "int" and kinds["width_cm"] == "float"
    values = {f.name: f.default for f in fields}
    assert rig_settings.rig_dict(values) == rig.to_dict()  # width_cm 0 is unknown: None
    assert rig_settings.rig_dict({**values, "width_cm": 4.0})["width_cm"] == 4.0
    with pytest.raises(ValueError, match="back_light"):
        rig_settings.rig_dict({**values, "back_light": (0.0, 0.0, 9.0)})
    assert rig_settings.capture_rig({"fov_deg": 40.0, "gamma": None}).to_dict() == \
        dataclasses.replace(rig, fov_deg=40.0).to_dict()
    assert json.loads(captures.write_rig_json(tmp_path, rig.to_dict()).read_text()) == rig.to_dict()


ADDON = ROOT / "blender_addon"
BLENDER_MODULES = {"bpy", "bmesh", "mathutils", "cycles", "_cycles", "oslquery"}


def _imports(path: Path) -> set[str]:
    """The first part of every module a file imports, anywhere in it (``from ..core import x``: core)."""
    package = list(path.parent.relative_to(ADDON).parts)  # [] for the top level, ["core"], ...
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names.add(node.module)
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1]
            if node.module:
                names.add(".".join([*base, node.module]))
            else:
                names.update(".".join([*base, alias.name]) for alias in node.names)
    return {name.split(".")[0] for name in names}


def test_the_addon_layers_import_one_way():
    """ui -> scene -> core; core never imports bpy; nothing imports torch."""
    for path in sorted(ADDON.rglob("*.py")):
        layer = path.relative_to(ADDON).parts[0] if path.parent != ADDON else "top"
        names = _imports(path)
        assert "torch" not in names, path
        if layer == "core":
            assert not names & (BLENDER_MODULES | {"scene", "ui"}), (path, names)
        if layer == "scene":
            assert "ui" not in names, (path, names)
    # At run time too, with the backend's declarations loaded: neither torch nor bpy comes along.
    probe = ("import sys, pkgutil, importlib, blender_addon.core as core\n"
             "for m in pkgutil.iter_modules(core.__path__): importlib.import_module('blender_addon.core.' + m.name)\n"
             "from blender_addon.core import declarations as d, rig_settings\n"
             "d.parameters(), d.weave_presets(), d.fit_patterns(), d.is_raw('.dng'), d.protocol()\n"
             "rig_settings.rig_fields()\n"
             "print(sorted({'torch', 'bpy'} & set(sys.modules)))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0 and done.stdout.strip() == "[]", done.stdout + done.stderr


# -- the command line ---------------------------------------------------------------------------

def test_fit_request_builds_the_contract_command_line(tmp_path):
    request = bridge.FitRequest(Path("a_R.png"), Path("a_T.png"), tmp_path, pattern="twill1", iterations=50,
                                size=256, device="cpu", rig_json=tmp_path / "rig.json")
    command = bridge.Backend("/py").command(request.arguments())
    assert command[:4] == ["/py", "-m", "backend", "fit"]
    assert command[4:6] == ["a_R.png", "a_T.png"]
    for flag, value in (("--out", str(tmp_path)), ("--pattern", "twill1"), ("--iterations", "50"),
                        ("--size", "256"), ("--device", "cpu"), ("--rig", str(tmp_path / "rig.json"))):
        assert command[command.index(flag) + 1] == value
    assert "--json-progress" in command
    assert "--size" not in bridge.FitRequest(Path("a"), Path("b"), tmp_path).arguments()
    with pytest.raises(bridge.BackendError, match="Unknown weave pattern"):
        bridge.FitRequest(Path("a"), Path("b"), tmp_path, pattern="basket").arguments()


def test_backend_environment_puts_the_backend_first_on_pythonpath(monkeypatch):
    monkeypatch.setenv("PYTHONPATH", "/elsewhere")
    env = bridge.Backend("/py", "fake.py").environment()
    assert env["PYTHONPATH"].split(os.pathsep) == [str(ROOT), "/elsewhere"]
    assert bridge.Backend("/py", "fake.py").command(["fit"]) == ["/py", "fake.py", "fit"]


def test_resolve_backend_precedence(monkeypatch):
    monkeypatch.setenv(setup.ENV_PYTHON, "/env/python")
    monkeypatch.setenv(setup.ENV_BACKEND_SCRIPT, "/env/fake.py")
    assert setup.resolve_backend("/explicit/python") == bridge.Backend("/explicit/python", "/env/fake.py")
    assert setup.resolve_backend() == bridge.Backend("/env/python", "/env/fake.py")
    monkeypatch.delenv(setup.ENV_PYTHON)
    with pytest.raises(bridge.BackendError, match="add-on preferences"):
        setup.resolve_backend(detect=False)


def test_interpreter_candidates_put_the_project_environment_first(tmp_path, monkeypatch):
    project = tmp_path / "project"
    (project / "backend").mkdir(parents=True)
    venv_python = project / ".venv" / "bin" / "python"
    venv_python.parent.mkdir(parents=True)
    venv_python.write_text("")
    monkeypatch.setattr(paths, "backend_root", lambda: project)
    monkeypatch.delenv("VIRTUAL_ENV", raising=False)
    assert setup.interpreter_candidates() == [str(venv_python), sys.executable]


# -- runs against the fake backend ------------------------------------------------------------------

def test_a_fit_reports_progress_and_its_result(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "ok", monkeypatch, rig_json=None)
    seen, fractions, words = [], [], []
    while not fit.done:
        for event in fit.poll():
            seen.append(event["event"])
        fractions.append(fit.progress)
        words.append(fit.status.split(",")[0])
        time.sleep(0.01)
    assert fit.state == bridge.SUCCEEDED, fit.error
    assert seen[0] == "start" and seen[-1] == "result" and "progress" in seen
    assert fractions == sorted(fractions) and fit.progress == 1.0  # one bar over every stage
    phases = [phase.words for phase in declarations.fit_progress().PHASES if phase.name != "duel"]
    assert [w for w in phases if w in words] == [w for w in dict.fromkeys(words) if w in phases], words
    assert fit.returncode == 0 and fit.error == "" and fit.outcome == backend.core.pair_jobs.DONE
    params = captures.read_fit_params(fit.result)
    assert params["pattern"] == "twill1"
    assert Path(fit.result["files"]["report"]).is_file()
    assert "fake backend" in (tmp_path / "out" / "backend.log").read_text()


def test_an_error_event_becomes_a_readable_failure(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "error", monkeypatch)
    assert fit.wait(timeout=HANG_S) == bridge.FAILED
    assert fit.error == "Internal backend error: the optimiser diverged (loss is NaN)"
    assert "error: the optimiser diverged" in fit.details and fit.returncode == 1
    assert fit.outcome == backend.core.pair_jobs.INTERNAL  # worth another try where a batch gives one


def test_bad_input_names_the_file(tmp_path, photos, monkeypatch):
    photos[1].write_text("not an image")
    fit = run_fit(tmp_path, photos, "ok", monkeypatch)
    assert fit.wait(timeout=HANG_S) == bridge.FAILED
    assert fit.error.startswith("Bad input") and str(photos[1]) in fit.error
    assert fit.returncode == 2 and fit.outcome == backend.core.pair_jobs.INPUT  # no second try would help


def test_a_crash_shows_the_exit_code_and_stderr(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "crash", monkeypatch)
    assert fit.wait(timeout=HANG_S) == bridge.FAILED
    assert "stopped unexpectedly (exit code 1)" in fit.error
    assert "RuntimeError: simulated crash" in fit.error
    assert "Traceback" in fit.details


def test_a_garbage_line_is_a_warning_and_the_fit_goes_on(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "garbage", monkeypatch)
    assert fit.wait(timeout=HANG_S) == bridge.SUCCEEDED
    assert any("not part of its progress protocol" in w and "some library printed" in w for w in fit.warnings)


def test_an_exit_without_result_is_a_failure(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "garbage_only", monkeypatch)
    assert fit.wait(timeout=HANG_S) == bridge.FAILED
    assert "ended without reporting a result" in fit.error and "2 line(s)" in fit.error
    assert "this is not JSON" in fit.details
    fit = run_fit(tmp_path, photos, "no_result", monkeypatch)
    assert fit.wait(timeout=HANG_S) == bridge.FAILED and fit.error == "The backend ended without reporting a result."


def test_a_missing_interpreter_is_a_readable_failure(tmp_path, photos):
    fit = bridge.FitProcess.fit(bridge.Backend("/no/such/python"), bridge.FitRequest(*photos, tmp_path)).start()
    assert fit.done and fit.state == bridge.FAILED
    assert "/no/such/python does not exist" in fit.error


def _wait_for_progress(fit):
    for _ in range(HANG_S * 50):
        if any(event["event"] == "progress" for event in fit.poll()):
            return
        time.sleep(0.02)
    raise AssertionError("no progress from the backend")


def _assert_reaped(pid: int):
    status = Path(f"/proc/{pid}/status")
    assert not status.exists() or "State:\tZ" not in status.read_text(), "the backend is a zombie"
    assert not status.exists(), "the backend process still exists"


def test_poll_returns_at_once_while_the_backend_is_silent(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "slow", monkeypatch)
    _wait_for_progress(fit)
    os.kill(fit.pid, signal.SIGSTOP)  # alive, holding its pipes open, writing nothing
    try:
        polls = []
        poller = threading.Thread(target=lambda: polls.extend(fit.poll() for _ in range(3)), daemon=True)
        poller.start()
        poller.join(HANG_S)
        assert not poller.is_alive(), "poll() waited for the backend"
        assert fit.state == bridge.RUNNING
    finally:
        os.kill(fit.pid, signal.SIGCONT)
    assert fit.cancel() == bridge.CANCELLED


def test_cancel_ends_the_process_cleanly(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "slow", monkeypatch)
    _wait_for_progress(fit)
    fit.request_cancel()
    while not fit.done:
        fit.poll()
        time.sleep(0.01)
    # 130: the backend stopped on the stop line on its stdin (no kill after the grace period was needed):
    # the cancel every platform delivers, Windows included, where SIGTERM cannot be caught.
    assert fit.state == bridge.CANCELLED and fit.returncode == 130 and fit.outcome == backend.core.pair_jobs.CANCELLED
    assert "cancelled" in fit.status.lower()
    _assert_reaped(fit.pid)


def test_a_run_past_its_time_limit_is_stopped_and_fails(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "slow", monkeypatch)
    assert fit.wait(timeout=0.5) == bridge.FAILED
    assert fit.error == "The fit took longer than 0.5 s and was stopped."
    assert fit.outcome == backend.core.pair_jobs.TIMEOUT
    _assert_reaped(fit.pid)


def test_cancel_kills_a_backend_that_ignores_the_stop_request(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "stubborn", monkeypatch)
    _wait_for_progress(fit)
    assert fit.cancel(grace=0.5) == bridge.CANCELLED
    assert fit.returncode == -signal.SIGKILL
    _assert_reaped(fit.pid)


# -- checking an interpreter ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def no_torch_python(tmp_path_factory) -> str:
    return python_without_torch(tmp_path_factory.mktemp("venv") / "no_torch")


def test_check_backend_names_every_missing_dependency_in_words(no_torch_python):
    check = setup.check_backend(bridge.Backend(no_torch_python))
    assert not check.ok and check.torch_version == "" and check.device == ""
    # One sentence per runtime dependency: what it is, what for, the pip line that installs it.
    for dependency in backend.core.dependencies.RUNTIME:
        assert any(p.startswith(f"{dependency.label} ({dependency.module}), which {dependency.role}, is not "
                                f"installed for {no_torch_python}") and
                   p.endswith(f'-m pip install "{dependency.requirement}"') for p in check.problems), dependency
    assert "The backend cannot run yet:" in check.summary()


def test_check_backend_imports_the_fit_command_itself(tmp_path):
    """Dependencies that import but do not work (here: empty stand-ins) stop the fit command's import."""
    packages = tmp_path / "site-packages"
    for dependency in backend.core.dependencies.RUNTIME:
        (packages / dependency.module).mkdir(parents=True)
        (packages / dependency.module / "__init__.py").write_text(
            "__version__ = '0.0'\nclass cuda:\n    is_available = staticmethod(lambda: False)\n")
    check = setup.check_backend(setup.bundled_backend(sys.executable, packages))
    assert [p for p in check.problems if p.startswith("The backend's fit command cannot be imported: ")] == \
        check.problems and len(check.problems) == 1, check.problems


def test_check_of_the_bundled_backend_says_to_reinstall_the_zip(tmp_path):
    packages = tmp_path / "site-packages"  # the extension's packages, with PyTorch missing
    packages.mkdir()
    check = setup.check_backend(setup.bundled_backend(sys.executable, packages))
    torch_problem = next(p for p in check.problems if p.startswith("PyTorch (torch)"))
    assert f"is missing from the extension's packages in {packages}: reinstall the extension zip" in torch_problem
    assert check.label == "Blender's Python with the extension's packages"


def test_check_backend_missing_interpreter():
    check = setup.check_backend(bridge.Backend("/no/such/python"))
    assert check.problems == ["The Python interpreter /no/such/python does not exist."]


def test_check_backend_accepts_the_project_environment():
    check = setup.check_backend(bridge.Backend(sys.executable, BACKEND_SCRIPT))
    assert check.ok, check.summary()
    assert any(note.startswith("Backend ") and "PyTorch" in note for note in check.notes), check.notes
    import torch  # the test environment's own, which this check found
    assert check.torch_version == torch.__version__
    assert check.device == (f"CUDA: {torch.cuda.get_device_name(0)}" if torch.cuda.is_available() else "CPU")
    assert Path(check.torch_file).resolve() == Path(torch.__file__).resolve()


def test_the_check_job_runs_one_check_at_a_time_and_keeps_the_last():
    release, calls, logged = threading.Event(), [], []

    def check(backend, device=None):
        calls.append((backend.python, device))
        release.wait(HANG_S)
        return setup.BackendCheck(backend.python, problems=["no torch"])

    job = BackendCheckJob(check=check, log=logged.append)
    assert not job.running and job.last is None
    assert job.start(bridge.Backend("/py/one"), "cuda")
    assert job.running
    assert not job.start(bridge.Backend("/py/two"))  # refused while the first runs
    release.set()
    job.wait(HANG_S)
    assert not job.running and calls == [("/py/one", "cuda")]
    assert job.last.python == "/py/one" and job.last.problems == ["no torch"]
    assert logged == ["Woven Fabric: /py/one: The backend cannot run yet:\n- no torch"]
    assert job.run(bridge.Backend("/py/two")).python == "/py/two" == job.last.python


# -- files around a fit ---------------------------------------------------------------------------

def test_find_pairs_reports_missing_partners_and_ambiguity(tmp_path):
    for name in ("denim_R.png", "denim_T.jpg", "silk_r.tif", "silk_t.TIF", "lonely_R.png", "twice_R.png",
                 "twice_R.jpg", "twice_T.png", "notes.txt", "other.png", "raw_R.dng", "raw_T.exr"):
        (tmp_path / name).write_bytes(b"x")
    pairs, problems = declarations.find_pairs(tmp_path)
    assert [(p.name, p.reflection.name, p.transmission.name) for p in pairs] == [
        ("denim", "denim_R.png", "denim_T.jpg"), ("raw", "raw_R.dng", "raw_T.exr"),
        ("silk", "silk_r.tif", "silk_t.TIF")]
    messages = {p.name: p.message for p in problems}
    assert set(messages) == {"lonely", "twice"}
    assert "no transmission photo (lonely_T.*) beside lonely_R.png" in messages["lonely"]
    assert "more than one reflection photo (twice_R.jpg, twice_R.png)" in messages["twice"]


def test_new_run_folder_never_reuses_a_folder(tmp_path):
    first = captures.new_run_folder(tmp_path, "my cloth/1")
    second = captures.new_run_folder(tmp_path, "my cloth/1")
    assert first.name == "my_cloth_1_001" and second.name == "my_cloth_1_002"
    assert first.is_dir() and second.is_dir()
    assert captures.run_name(second) == "my_cloth_1"
    (tmp_path / "lib.blend").write_bytes(b"")
    assert captures.unused_path(tmp_path / "lib.blend").name == "lib-2.blend"
    assert captures.default_results_parent("/a/b/scene.blend") == Path("/a/b/fabric_fits")


def test_fit_names_and_photo_checks(tmp_path):
    assert captures.fit_name("", Path("denim_R.png")) == "denim"
    assert captures.fit_name("", Path("denim_r.png")) == "denim"
    assert captures.fit_name("", Path("denim.png")) == "denim"
    assert captures.fit_name("Blue", Path("denim_R.png")) == "Blue"
    with pytest.raises(ValueError, match="Choose the reflection photo first"):
        captures.require_photo("reflection", "", Path())
    with pytest.raises(ValueError, match="The transmission photo .* does not exist"):
        captures.require_photo("transmission", "x_T.png", tmp_path / "x_T.png")


# -- the batch, with a library that only records ------------------------------------------------------

class RecordingLibrary:
    """Stands in for scene/materials.AssetLibrary (which needs bpy)."""

    def __init__(self, fail_write: bool = False):
        self.added, self.written, self.fail_write = [], [], fail_write

    def add(self, name, params, width_cm, fit_folder, description, preview):
        self.added.append((name, params["pattern"], width_cm, Path(fit_folder).name, Path(preview).name))
        return f"{name} material"

    def write(self, path):
        if self.fail_write:
            raise OSError("disk full")
        self.written.append(path)


def test_the_batch_fits_good_pairs_and_counts_bad_ones(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv(setup.ENV_PYTHON, sys.executable)
    monkeypatch.setenv(setup.ENV_BACKEND_SCRIPT, BACKEND_SCRIPT)
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("linen_R.png", "linen_T.png", "wool_R.png", "wool_T.png", "torn_R.png", "solo_R.png"):
        (photos / name).write_bytes(PNG_1x1)
    (photos / "torn_T.png").write_text("not an image")
    (tmp_path / "lib.blend").write_bytes(b"")
    library = RecordingLibrary()
    code = batch.main([str(photos), "--out", str(tmp_path / "lib.blend"), "--width-cm", "5"], library=library)
    out = capsys.readouterr().out
    assert code == 2, out
    assert library.added == [("linen", "twill1", 5.0, "linen_001", "reflection.png"),
                             ("wool", "twill1", 5.0, "wool_001", "reflection.png")]
    assert library.written == [tmp_path / "lib-2.blend"]  # an existing library is kept
    assert "SKIP solo: no transmission photo (solo_T.*) beside solo_R.png" in out
    assert "FAIL [2/3] torn: Bad input" in out and "2 fitted, 2 failed" in out
    assert json.loads((photos / "fabric_fits" / "wool_001" / "rig.json").read_text())["width_cm"] == 5.0

    failing = RecordingLibrary(fail_write=True)
    assert batch.main([str(photos), "--fits", str(tmp_path / "again")], library=failing) == 4
    assert "ERROR cannot write" in capsys.readouterr().out


def write_results(folder: Path, name: str, files=None) -> Path:
    """A results folder as `python -m backend fit --out` leaves it (some files only, when ``files`` says)."""
    folder.mkdir(parents=True)
    for file in files or backend.core.results.RESULT_FILES:
        content = {"params.json": json.dumps({**fake_params(name), "photos": {
            "reflection": {"path": f"/photos/{name}_R.png"}, "transmission": {"path": f"/photos/{name}_T.png"}}}),
                   "metrics.json": "{}"}.get(file)
        (folder / file).write_text(content) if content else (folder / file).write_bytes(PNG_1x1)
    return folder


def test_the_batch_builds_a_library_from_results_without_fitting(tmp_path, capsys):
    results = tmp_path / "results"   # what `python -m backend batch --out results` leaves
    write_results(results / "linen", "linen")
    write_results(results / "wool", "wool")
    write_results(results / "half", "half", files=["params.json", "reflection.png"])  # a copy cut short
    crafted = write_results(results / "crafted", "crafted") / "params.json"  # edited by hand: not a fit
    crafted.write_text(crafted.read_text().replace('"roughness": [0.6, 0.66]', '"roughness": [NaN, 0.66]'))
    (results / "logs").mkdir()
    (results / "logs" / "wool.log").write_text("warning: ...")
    write_results(results / ".staging" / "denim", "denim")  # the batch's own hidden folders are passed by
    (results / "catalogue.json").write_text("{}")
    library = RecordingLibrary()
    # No backend is asked for: a misconfigured one would make this fail.
    code = batch.main(["--from-results", str(results), "--width-cm", "4"], library=library,
                      preferred_backend=lambda: bridge.Backend("/nonexistent/python", ""))
    out = capsys.readouterr().out
    assert code == 2, out  # the failed folders' count
    assert library.added == [("linen", "twill1", 4.0, "linen", "reflection.png"),
                             ("wool", "twill1", 4.0, "wool", "reflection.png")]
    assert library.written == [results / "fabric_materials.blend"]
    assert "FAIL half: incomplete results folder" in out and "no metrics.json, transmission.png, report.png" in out
    assert f"FAIL crafted: {crafted}: not a fit's parameters: roughness: nan is outside" in out
    assert "2 imported, 2 failed" in out

    single = RecordingLibrary()  # one fit's folder, given itself
    assert batch.main(["--from-results", str(results / "linen"), "--out", str(tmp_path / "one.blend")],
                      library=single) == 0
    assert [a[0] for a in single.added] == ["linen"] and single.written == [tmp_path / "one.blend"]
    assert batch.main(["--from-results", str(tmp_path / "results" / "logs")], library=RecordingLibrary()) == 1
    assert "no fit results" in capsys.readouterr().out
    assert batch.main([str(results), "--from-results", str(results)], library=RecordingLibrary()) == 1
    assert "either the folder of photo pairs or --from-results" in capsys.readouterr().err


def test_the_batch_exit_code_is_the_backends(tmp_path):
    report = batch.BatchReport(failed=[("pair", "bad")] * 300)
    assert report.exit_code == backend.core.protocol.failed_exit_code(300) == 125
    assert batch.BatchReport(failed=[("pair", "bad")] * 3).exit_code == 3


def test_the_batch_refuses_bad_arguments_before_any_fit(tmp_path, capsys):
    library = RecordingLibrary()
    assert batch.main([str(tmp_path / "missing")], library=library, preferred_backend=lambda: bridge.Backend(
        sys.executable, BACKEND_SCRIPT)) == 1
    assert "not a folder" in capsys.readouterr().err
    assert batch.main([str(tmp_path), "--pattern", "basket"], library=library) == 1
    assert batch.main(["--help"], library=library) == 0
    # the fit options' flags, help and checks are the backend's declaration's
    assert batch.main([str(tmp_path), "--size", "16"], library=library) == 1
    assert "--size: must be at least 32 pixels, got 16" in capsys.readouterr().err
    assert library.added == [] and library.written == []


def test_the_batch_passes_the_declared_fit_options_on_and_checks_them_before_the_first_fit(tmp_path):
    (tmp_path / "linen_R.png").write_bytes(PNG_1x1)
    (tmp_path / "linen_T.png").write_bytes(PNG_1x1)
    args = batch.build_parser().parse_args([str(tmp_path), "--size", "64", "--output-spp", "4", "--strict"])
    assert batch._fit_options(args) == {"size": 64, "output_spp": 4, "strict": True}  # the rest: the backend's
    backend_ = bridge.Backend(sys.executable, BACKEND_SCRIPT)
    refused = batch_queue.BatchQueue(tmp_path, backend_, tmp_path / "fits", {}, lambda *a: "",
                                     batch_queue.BatchOptions({"iterations": 0}))
    with pytest.raises(bridge.BackendError, match="^--iterations: must be at least 1, got 0$"):
        refused.start()
    assert not (tmp_path / "fits").exists() and refused.jobs[0].state == batch_queue.PENDING
    with pytest.raises(bridge.BackendError, match="not an option of a fit"):
        captures.check_fit_options({"colour": "red"})


def test_an_unsaved_files_fits_go_where_the_artist_finds_them(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    assert captures.default_results_parent("", home) == home / captures.UNSAVED_RESULTS
    (home / "Documents").mkdir()
    assert captures.default_results_parent("", home) == home / "Documents" / captures.UNSAVED_RESULTS
    assert captures.default_results_parent(str(tmp_path / "scene.blend"), home) == tmp_path / "fabric_fits"


def test_a_cancelled_fit_leaves_its_best_parameters_or_its_fit(tmp_path):
    assert captures.cancelled_fit_params(tmp_path) is None
    (tmp_path / backend.core.protocol.PARTIAL_PARAMS_FILE).write_text(json.dumps(fake_params("a")))
    assert captures.cancelled_fit_params(tmp_path) == (fake_params("a"), True)
    (tmp_path / "params.json").write_text(json.dumps(fake_params("b")))   # cancelled in its re-renders
    assert captures.cancelled_fit_params(tmp_path) == (fake_params("b"), False)
    # the backend writes the protocol's partial file (backend/app/folder.py)
    assert f'"{backend.core.protocol.PARTIAL_PARAMS_FILE}"' in (ROOT / "backend/app/folder.py").read_text()


def test_photos_that_look_swapped_are_refused_with_the_protocols_words(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "swapped", monkeypatch, strict=True)
    assert fit.wait(timeout=HANG_S) == bridge.FAILED and fit.refused_swapped
    assert "--strict" in fit.arguments
    warned = run_fit(tmp_path / "given", photos, "swapped", monkeypatch)
    assert warned.wait(timeout=HANG_S) == bridge.SUCCEEDED and not warned.refused_swapped
    assert [w for w in warned.warnings if backend.core.protocol.SWAPPED_PHOTOS in w]
    assert fake_backend.SWAPPED == backend.core.protocol.SWAPPED_PHOTOS
    # the backend's own warning and refusal hold the words (backend/image/photos.py)
    from test_photos import synthetic_pair

    from backend.image.errors import PhotoError
    from backend.image.photos import load_pair
    reflection, transmission = synthetic_pair(tmp_path)
    assert backend.core.protocol.SWAPPED_PHOTOS in load_pair(transmission, reflection, size=256).warnings[0]
    with pytest.raises(PhotoError, match=backend.core.protocol.SWAPPED_PHOTOS):
        load_pair(transmission, reflection, size=256, strict=True)


def test_the_rigs_labels_read_as_words():
    labels = {field.name: field.label for field in rig_settings.rig_fields()}
    assert (labels["sample_rotation_deg"], labels["sample_skew_deg"]) == ("Sample rotation", "Sample skew")
    assert not [label for label in labels.values() if label.split()[-1] in ("deg", "px", "cm")], labels
    assert rig_settings._label("new_setting_px") == "New setting"


# -- the bundled backend: isolation and precedence ----------------------------------------------------

def test_a_backend_with_packages_runs_isolated_with_exactly_those_on_its_path(tmp_path):
    packages = tmp_path / "site-packages"
    (packages / "only_here").mkdir(parents=True)
    (packages / "only_here" / "__init__.py").write_text("")
    isolated = setup.bundled_backend(sys.executable, packages)
    assert isolated.command(["fit"])[:5] == [sys.executable, "-S", "-P", "-m", "backend"]
    env = isolated.environment()
    assert env["PYTHONPATH"].split(os.pathsep) == [str(ROOT), str(packages)] and env["PYTHONNOUSERSITE"] == "1"
    probe = ("import importlib.util as u, json, sys\n"
             "print(json.dumps([sys.flags.no_site, [u.find_spec(m) is not None for m in "
             "('only_here', 'pytest', 'numpy', 'backend')]]))")
    done = subprocess.run(isolated.python_command(["-c", probe]), env=env, capture_output=True, text=True,
                          cwd=tmp_path)
    # The test environment's packages (pytest, numpy) are out of reach; the backend and the folder are not.
    assert json.loads(done.stdout) == [1, [True, False, False, True]], done.stderr
    assert bridge.Backend(sys.executable).command(["fit"])[:3] == [sys.executable, "-m", "backend"]


def test_resolve_backend_puts_the_bundled_backend_after_explicit_choices(monkeypatch, tmp_path):
    bundled = setup.bundled_backend("/blender/python", tmp_path)
    monkeypatch.delenv(setup.ENV_PYTHON, raising=False)
    monkeypatch.delenv(setup.ENV_BACKEND_SCRIPT, raising=False)
    assert setup.resolve_backend(bundled=bundled, detect=False) == bundled
    assert setup.resolve_backend(script="fake.py", bundled=bundled).script == "fake.py"
    assert setup.resolve_backend("/explicit/python", bundled=bundled) == bridge.Backend("/explicit/python")
    monkeypatch.setenv(setup.ENV_PYTHON, "/env/python")
    assert setup.resolve_backend(bundled=bundled) == bridge.Backend("/env/python")
    gpu = setup.bundled_backend("/blender/python", tmp_path / "site", tmp_path / "gpu")
    assert gpu.packages == (str(tmp_path / "gpu"), str(tmp_path / "site"))


def test_the_batch_keeps_the_bundled_backends_packages(tmp_path):
    preferred = setup.bundled_backend(sys.executable, tmp_path)
    args = batch.build_parser().parse_args([str(tmp_path), "--backend-script", BACKEND_SCRIPT])
    chosen = batch._backend(args, preferred)
    assert chosen.packages == (str(tmp_path),) and chosen.script == BACKEND_SCRIPT
    flagged = batch._backend(batch.build_parser().parse_args([str(tmp_path), "--python", "/other/python"]), preferred)
    assert flagged.python == "/other/python" and flagged.packages == ()


# -- the first-run checklist --------------------------------------------------------------------------

def test_the_first_run_checklist_in_words():
    states = lambda items: [item.state for item in items]  # noqa: E731
    pending = checklist.first_run_checklist(None, False, None, "")
    assert states(pending) == ["pending", "pending", "pending", "ok"]
    assert pending[0].text == "Backend: not checked yet (press Check Backend)"
    assert checklist.first_run_checklist(None, True, None, "")[0].text == "Backend: checking ..."
    ready = setup.BackendCheck("/py", label="Blender's Python with the extension's packages",
                               torch_version="2.13.0+cpu", device="CPU")
    items = checklist.first_run_checklist(ready, False, None, "")
    assert [(i.state, i.text) for i in items] == [
        ("ok", "Backend: Blender's Python with the extension's packages: /py"), ("ok", "PyTorch 2.13.0+cpu"),
        ("ok", "Device: CPU"),
        ("ok", "OSL: Cycles can run the fitted shader (Cycles on the CPU or OptiX, Open Shading Language on)")]
    no_osl = checklist.first_run_checklist(ready, False, None, "this Blender's Cycles was built without OSL")
    assert no_osl[3] == checklist.Item("problem", "OSL: this Blender's Cycles was built without OSL; materials "
                                                  "render with the approximate fallback")
    assert checklist.first_run_checklist(ready, False, "cuda", "")[2].state == "problem"
    gpu = dataclasses.replace(ready, device="CUDA: RTX 4090")
    assert checklist.first_run_checklist(gpu, False, "cuda", "")[2] == checklist.Item("ok", "Device: CUDA: RTX 4090")
    assert "choose the CUDA device" in checklist.first_run_checklist(gpu, False, None, "")[2].text
    missing = setup.BackendCheck("/nowhere", problems=["The Python interpreter /nowhere does not exist."])
    assert states(checklist.first_run_checklist(missing, False, None, "")) == ["problem", "problem", "pending", "ok"]
    no_torch = setup.BackendCheck("/py", problems=["PyTorch (torch), which ..., is not installed for /py: ..."])
    assert states(checklist.first_run_checklist(no_torch, False, None, "")) == ["ok", "problem", "pending", "ok"]


# -- the GPU route's install, with a stand-in pip -------------------------------------------------------

FAKE_PIP = '''
import os, sys, time
target = sys.argv[sys.argv.index("--target") + 1]
mode = os.environ["FAKE_PIP_MODE"]
print("Collecting torch==2.13.0", flush=True)
print("  Downloading torch-2.13.0+cu130-cp311-cp311-win_amd64.whl (2.6 GB)", flush=True)
print("Progress 50 of 100", flush=True)
if mode == "slow":
    time.sleep(60)
if mode == "fail":
    print("ERROR: No matching distribution found for torch==2.13.0", flush=True)
    sys.exit(1)
os.makedirs(os.path.join(target, "torch"))
open(os.path.join(target, "torch", "__init__.py"), "w").close()
print("Installing collected packages: torch", flush=True)
print("Successfully installed torch-2.13.0+cu130", flush=True)
'''


@pytest.fixture
def fake_pip(tmp_path):
    """A folder of packages whose ``pip`` is a stand-in (``python -S -P -m pip`` runs it)."""
    packages = tmp_path / "packages"
    (packages / "pip").mkdir(parents=True)
    (packages / "pip" / "__init__.py").write_text("")
    (packages / "pip" / "__main__.py").write_text(FAKE_PIP)
    return setup.bundled_backend(sys.executable, packages)


def _earlier_install(folder: Path) -> Path:
    (folder / "torch").mkdir(parents=True)
    (folder / "torch" / "__init__.py").write_text("# the earlier install\n")
    return folder


def test_the_gpu_install_reports_progress_and_replaces_the_folder_when_done(fake_pip, tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_PIP_MODE", "ok")
    folder = _earlier_install(tmp_path / "user" / gpu_env.FOLDER_NAME)
    job = gpu_env.TorchInstall(fake_pip, folder, "torch==2.13.0").start(online=True)
    assert job.wait(timeout=HANG_S) == gpu_env.SUCCEEDED, job.error
    assert gpu_env.installed(folder) and (folder / "torch" / "__init__.py").read_text() == ""  # the new one
    assert not job.partial.exists() and job.progress == 1.0
    assert job.status == f"Installed torch==2.13.0 in {folder}"
    assert "Downloading torch-2.13.0+cu130-cp311-cp311-win_amd64.whl (2.6 GB)" in [line.strip() for line in job.output]
    assert gpu_env.pip_arguments(Path("T"), "torch==2.13.0", gpu_env.CUDA_INDEX)[-2:] == ["--index-url",
                                                                                         gpu_env.CUDA_INDEX]


def test_the_gpu_install_can_be_cancelled_and_a_failure_changes_nothing(fake_pip, tmp_path, monkeypatch):
    folder = _earlier_install(tmp_path / gpu_env.FOLDER_NAME)
    monkeypatch.setenv("FAKE_PIP_MODE", "slow")
    job = gpu_env.TorchInstall(fake_pip, folder, "torch==2.13.0").start(online=True)
    for _ in range(HANG_S * 50):
        job.poll()
        if job.progress == 0.5:
            break
        time.sleep(0.02)
    assert job.state == gpu_env.RUNNING and job.status.startswith("Downloading torch-2.13.0")
    job.request_cancel()
    assert job.wait(timeout=HANG_S) == gpu_env.CANCELLED
    assert job.error == "The GPU PyTorch install was cancelled; nothing was changed."
    monkeypatch.setenv("FAKE_PIP_MODE", "fail")
    failed = gpu_env.TorchInstall(fake_pip, folder, "torch==2.13.0").start(online=True)
    assert failed.wait(timeout=HANG_S) == gpu_env.FAILED
    assert failed.error == ("pip could not install torch==2.13.0: ERROR: No matching distribution found for "
                            "torch==2.13.0")
    assert (folder / "torch" / "__init__.py").read_text() == "# the earlier install\n"  # untouched both times


def test_the_gpu_install_refuses_offline_or_without_the_bundled_packages(fake_pip, tmp_path):
    with pytest.raises(gpu_env.InstallRefused, match="Allow Online Access in Edit > Preferences > System > Network"):
        gpu_env.TorchInstall(fake_pip, tmp_path / "gpu", "torch==2.13.0").start(online=False)
    with pytest.raises(gpu_env.InstallRefused, match="install the extension zip made for your platform"):
        gpu_env.TorchInstall(bridge.Backend(sys.executable), tmp_path / "gpu", "torch==2.13.0").start(online=True)
    assert not (tmp_path / "gpu").exists() and not (tmp_path / "gpu.partial").exists()
    assert gpu_env.torch_requirement() == backend.core.dependencies.TORCH.requirement


def test_a_warning_reaches_the_runs_log_as_well_as_its_event():
    """With --json-progress a warning is an event for the caller and a line on stderr, which the
    add-on keeps as the fit's backend.log (and the batch as its logs/<name>.log)."""
    import io

    protocol = backend.core.protocol
    stream, log = io.StringIO(), io.StringIO()
    protocol.Reporter(json_lines=True, stream=stream, log=log).warning("the photos may be swapped", "a.png")
    assert protocol.decode(stream.getvalue()) == {"event": "warning", "message": "the photos may be swapped",
                                                  "file": "a.png"}
    assert log.getvalue() == "warning: the photos may be swapped\n"
