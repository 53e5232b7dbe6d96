"""The add-on's plain-Python side without Blender: the backend bridge against a fake backend,
photo pairing, result folders and the rig settings.

The fake backend (tests/fake_backend.py) speaks the fit command's protocol in a fraction of a
second. To run these tests against the real backend once ``python -m backend fit`` exists, set
BACKEND_SCRIPT to "" (the tests that need a fake behaviour are skipped then).
"""
from __future__ import annotations

import json
import os
import shutil
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from blender_addon.core import backend_bridge as bridge  # noqa: E402
from blender_addon.core import backend_setup as setup  # noqa: E402
from blender_addon.core import captures  # noqa: E402

FAKE_BACKEND = Path(__file__).resolve().parent / "fake_backend.py"
BACKEND_SCRIPT = str(FAKE_BACKEND)  # "" runs the real backend (python -m backend)
PNG_1x1 = bytes.fromhex("89504e470d0a1a0a0000000d4948445200000001000000010806000000"
                        "1f15c4890000000d49444154789c6360f8cfc0f01f0005000201d1b5a0550000000049454e44ae426082")

fake_only = pytest.mark.skipif(not BACKEND_SCRIPT, reason="needs the fake backend's modes")


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


def test_interpreter_candidates_include_the_project_environment():
    candidates = setup.interpreter_candidates()
    assert str(ROOT / ".venv" / "bin" / "python") in candidates
    assert candidates[-1] == sys.executable or sys.executable in candidates


def test_progress_fraction_is_monotonic_over_the_stages():
    assert tuple(bridge.STAGE_WEIGHTS) == bridge.protocol().STAGES == tuple(bridge.STAGE_NAMES)
    assert sum(bridge.STAGE_WEIGHTS.values()) == pytest.approx(1.0)
    fractions = [bridge.progress_fraction(stage, i, 4) for stage in bridge.STAGE_WEIGHTS for i in range(5)]
    assert fractions == sorted(fractions)
    assert fractions[0] == 0.0 and fractions[-1] == pytest.approx(1.0)
    assert bridge.progress_fraction("optimise", 3, 0) == pytest.approx(0.22)
    assert bridge.describe_progress({"stage": "optimise", "iteration": 12, "total": 300, "loss": 0.0312,
                                     "eta_s": 41.5}) == "Optimising 12/300, loss 0.0312, about 42 s left"


# -- runs against the fake backend ------------------------------------------------------------------

def test_a_fit_reports_progress_and_its_result(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "ok", monkeypatch, rig_json=None)
    seen, fractions = [], []
    while not fit.done:
        for event in fit.poll():
            seen.append(event["event"])
            fractions.append(fit.progress)
        time.sleep(0.01)
    assert fit.state == bridge.SUCCEEDED, fit.error
    assert seen[0] == "start" and seen[-1] == "result" and "progress" in seen
    assert fractions == sorted(fractions) and fit.progress == 1.0
    assert fit.returncode == 0 and fit.error == ""
    params = captures.read_fit_params(fit.result)
    assert params["pattern"] == "twill1"
    assert Path(fit.result["files"]["report"]).is_file()
    assert "fake backend" in (tmp_path / "out" / "backend.log").read_text()


@fake_only
def test_an_error_event_becomes_a_readable_failure(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "error", monkeypatch)
    assert fit.wait(timeout=20) == bridge.FAILED
    assert fit.error == "Internal backend error: the optimiser diverged (loss is NaN)"
    assert "error: the optimiser diverged" in fit.details and fit.returncode == 1


def test_bad_input_names_the_file(tmp_path, photos, monkeypatch):
    photos[1].write_text("not an image")
    fit = run_fit(tmp_path, photos, "ok", monkeypatch)
    assert fit.wait(timeout=60) == bridge.FAILED
    assert fit.error.startswith("Bad input") and str(photos[1]) in fit.error
    assert fit.returncode == 2


@fake_only
def test_a_crash_shows_the_exit_code_and_stderr(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "crash", monkeypatch)
    assert fit.wait(timeout=20) == bridge.FAILED
    assert "stopped unexpectedly (exit code 1)" in fit.error
    assert "RuntimeError: simulated crash" in fit.error
    assert "Traceback" in fit.details


@fake_only
def test_a_garbage_line_is_a_warning_and_the_fit_goes_on(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "garbage", monkeypatch)
    assert fit.wait(timeout=20) == bridge.SUCCEEDED
    assert any("not part of its progress protocol" in w and "some library printed" in w for w in fit.warnings)


@fake_only
def test_an_exit_without_result_is_a_failure(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "garbage_only", monkeypatch)
    assert fit.wait(timeout=20) == bridge.FAILED
    assert "ended without reporting a result" in fit.error and "2 line(s)" in fit.error
    assert "this is not JSON" in fit.details
    fit = run_fit(tmp_path, photos, "no_result", monkeypatch)
    assert fit.wait(timeout=20) == bridge.FAILED and fit.error == "The backend ended without reporting a result."


def test_a_missing_interpreter_is_a_readable_failure(tmp_path, photos):
    fit = bridge.FitProcess.fit(bridge.Backend("/no/such/python"), bridge.FitRequest(*photos, tmp_path)).start()
    assert fit.done and fit.state == bridge.FAILED
    assert "/no/such/python does not exist" in fit.error


def _wait_for_progress(fit, timeout=20.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if any(event["event"] == "progress" for event in fit.poll()):
            return
        time.sleep(0.02)
    raise AssertionError("no progress from the backend")


def _assert_reaped(pid: int):
    status = Path(f"/proc/{pid}/status")
    assert not status.exists() or "State:\tZ" not in status.read_text(), "the backend is a zombie"
    assert not status.exists(), "the backend process still exists"


@fake_only
def test_cancel_ends_the_process_cleanly_and_quickly(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "slow", monkeypatch)
    _wait_for_progress(fit)
    started = time.monotonic()
    polls = []
    fit.request_cancel()
    while not fit.done:
        t = time.monotonic()
        fit.poll()
        polls.append(time.monotonic() - t)
        time.sleep(0.01)
    assert time.monotonic() - started < 3.0
    assert max(polls) < 0.1, "poll() must never block"
    assert fit.state == bridge.CANCELLED and fit.returncode == 130
    assert "cancelled" in fit.status.lower()
    _assert_reaped(fit.pid)


@fake_only
def test_a_run_past_its_time_limit_is_stopped_and_fails(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "slow", monkeypatch)
    started = time.monotonic()
    assert fit.wait(timeout=0.5) == bridge.FAILED
    assert time.monotonic() - started < 4.0
    assert fit.error == "The fit took longer than 0.5 s and was stopped."
    _assert_reaped(fit.pid)


@fake_only
def test_cancel_kills_a_backend_that_ignores_sigterm(tmp_path, photos, monkeypatch):
    fit = run_fit(tmp_path, photos, "stubborn", monkeypatch)
    _wait_for_progress(fit)
    started = time.monotonic()
    assert fit.cancel(grace=0.5) == bridge.CANCELLED
    assert time.monotonic() - started < 3.0
    assert fit.returncode == -9
    _assert_reaped(fit.pid)


# -- checking an interpreter ----------------------------------------------------------------------

def _python_without_torch():
    for candidate in ("/usr/bin/python3", shutil.which("python3")):
        if candidate and Path(candidate).exists():
            import subprocess

            if subprocess.run([candidate, "-c", "import torch"], capture_output=True).returncode != 0:
                return candidate
    pytest.skip("no Python without torch on this machine")


def test_check_backend_says_in_words_that_torch_is_missing():
    python = _python_without_torch()
    check = setup.check_backend(bridge.Backend(python))
    assert not check.ok
    assert any(p.startswith("PyTorch (torch) is not installed for") and "pip install torch" in p
               for p in check.problems), check.problems
    assert "The backend cannot run yet:" in check.summary()


def test_check_backend_missing_interpreter():
    check = setup.check_backend(bridge.Backend("/no/such/python"))
    assert check.problems == ["The Python interpreter /no/such/python does not exist."]


def test_check_backend_accepts_the_project_environment():
    check = setup.check_backend(bridge.Backend(sys.executable, BACKEND_SCRIPT))
    assert check.ok, check.summary()
    assert any(note.startswith("Backend ") and "PyTorch" in note for note in check.notes), check.notes


# -- files around a fit ---------------------------------------------------------------------------

def test_find_pairs_reports_missing_partners_and_ambiguity(tmp_path):
    for name in ("denim_R.png", "denim_T.jpg", "silk_r.tif", "silk_t.TIF", "lonely_R.png", "twice_R.png",
                 "twice_R.jpg", "twice_T.png", "notes.txt", "other.png", "raw_R.dng", "raw_T.exr"):
        (tmp_path / name).write_bytes(b"x")
    pairs, problems = captures.find_pairs(tmp_path)
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
    (tmp_path / "lib.blend").write_bytes(b"")
    assert captures.unused_path(tmp_path / "lib.blend").name == "lib-2.blend"
    assert captures.default_results_parent("/a/b/scene.blend") == Path("/a/b/fabric_fits")


def test_rig_fields_carry_the_spec_defaults(tmp_path):
    fields = {f.name: f for f in captures.rig_fields()}
    assert fields["camera_height"].default == 8.0 and fields["fov_deg"].default == 53.0
    assert fields["front_light"].kind == "vector" and fields["front_light"].default == (0.0, 8.0, 8.0)
    assert fields["film_size"].kind == "int" and fields["width_cm"].default == 0.0
    values = {f.name: f.default for f in fields.values()}
    rig = captures.rig_dict(values)
    assert rig["width_cm"] is None and rig["back_light"] == [0.0, 0.0, -9.0]
    assert captures.rig_dict({**values, "width_cm": 4.0})["width_cm"] == 4.0
    with pytest.raises(ValueError, match="back_light"):
        captures.rig_dict({**values, "back_light": (0.0, 0.0, 9.0)})
    assert json.loads(captures.write_rig_json(tmp_path, rig).read_text()) == rig
