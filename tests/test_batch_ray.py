"""``python -m backend batch`` on a local Ray: real fits of tiny pairs (one good, one broken), the
catalogue, ``--resume``, the exit code, a worker that dies, and Ctrl+C.

One Ray session serves the whole module (its start takes seconds); the batch command joins it
instead of starting its own. The pairs are rendered on a 128-pixel film with the rig that says so,
and fitted at ``--size 32`` with 2 iterations: seconds of fitting, not minutes.
"""
from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import signal
from pathlib import Path

import pytest

from backend.app.batch import scheduler
from backend.app.batch.ray_executor import FitResources, connect
from backend.app.cli.main import main
from backend.app.folder import EXAMPLE_PARAMS
from backend.core.params import FabricParams
from backend.core.protocol import Reporter, decode
from backend.core.results import RESULT_FILES
from backend.image.png import write_png
from backend.model.render import render_pair
from devtools.bench.batch import small_fabric, small_rig

# One local Ray session and one first batch serve the module's tests: kept on one xdist worker
# (pyproject's --dist loadgroup), and run first (slow: tests/conftest.py).
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("ray")]

FILM = 128
FIT = ["--size", "32", "--iterations", "2", "--output-spp", "1", "--pattern", "twill1"]


@pytest.fixture(scope="module")
def ray_session():
    connection = connect(None)  # the batch's own start: a local Ray with the checkout's backend for the workers
    yield connection.ray
    connection.close()


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> tuple[Path, Path]:
    """good_R/T.png (the example fabric, rendered) and broken_R/T.png (a truncated PNG), and their rig."""
    folder = tmp_path_factory.mktemp("photos")
    rig = small_rig(FILM)
    pair = render_pair(small_fabric(FabricParams.from_interchange(EXAMPLE_PARAMS), FILM), rig, size=FILM, spp=2, seed=5)
    write_png(folder / "good_R.png", pair.reflection, bits=8)
    write_png(folder / "good_T.png", pair.transmission, bits=8)
    shutil.copy(folder / "good_R.png", folder / "broken_R.png")
    (folder / "broken_T.png").write_bytes((folder / "good_T.png").read_bytes()[:200])
    rig_path = folder.parent / f"{folder.name}_rig.json"
    rig_path.write_text(json.dumps(rig.to_dict()))
    return folder, rig_path


class EventStream(io.StringIO):
    """stdout of the command: its JSON lines, with an optional action on the first line that matches."""

    def __init__(self, when=None, action=None):
        super().__init__()
        self.when, self.action = when, action

    def write(self, text):
        written = super().write(text)
        if self.when and self.when in text:
            self.when = None
            self.action()
        return written

    def events(self):
        return [decode(line) for line in self.getvalue().splitlines()]


def batch(*args, stream=None):
    stream = stream or EventStream()
    with contextlib.redirect_stdout(stream):
        code = main(["batch", *map(str, args), "--json-progress"])
    return code, stream.events()


@pytest.fixture(scope="module")
def first_run(ray_session, photos, tmp_path_factory):
    folder, rig = photos
    out = tmp_path_factory.mktemp("batch") / "out"
    code, events = batch(folder, "--out", out, "--rig", rig, *FIT)
    return out, code, events


def test_a_batch_fits_the_good_pair_reports_the_broken_one_and_exits_with_the_failures(first_run, photos):
    out, code, events = first_run
    assert code == 1, events[-3:]
    assert events[0]["event"] == "start" and events[0]["command"] == "batch"
    assert events[-1]["event"] == "result" and (events[-1]["done"], events[-1]["failed"]) == (1, 1)
    # The good pair's folder is what `fit` writes, the recorded photo paths are the photos' own.
    assert sorted(p.name for p in (out / "good").iterdir()) == sorted(RESULT_FILES)
    params = json.loads((out / "good" / "params.json").read_text())
    assert FabricParams.from_dict(params).pattern == "twill1"
    assert params["photos"]["reflection"]["path"] == str(photos[0] / "good_R.png")
    assert params["rig"]["film_size"] == FILM
    # The broken pair: failed once (bad input is not retried), with the fit's own one-line reason.
    failed = [e for e in events if e["event"] == "pair" and e["status"] in ("failed", "retrying")]
    assert [(e["name"], e["status"], e["attempt"]) for e in failed] == [("broken", "failed", 1)]
    assert str(photos[0] / "broken_T.png") in failed[0]["reason"] and not (out / "broken").exists()
    assert "broken_T.png" in (out / "logs" / "broken.log").read_text()
    # The catalogue, both forms.
    rows = {r["name"]: r for r in json.loads((out / "catalogue.json").read_text())["pairs"]}
    assert rows["good"]["status"] == "done" and rows["good"]["pattern"] == "twill1" and rows["good"]["folder"] == "good"
    assert 0 < rows["good"]["flip_R"] < 1 and rows["good"]["interchange"] == params["interchange"]
    assert rows["broken"]["status"] == "failed" and rows["broken"]["attempts"] == 1
    assert (out / "catalogue.csv").read_text().splitlines()[0].startswith("name,status,pattern,tiles_warp")
    progress = [e for e in events if e["event"] == "batch"]
    assert progress[-1]["done"] == 1 and progress[-1]["failed"] == 1 and progress[-1]["running"] == 0


def test_resume_keeps_the_fitted_pair_and_tries_the_broken_one_again(first_run, photos):
    out, _, _ = first_run
    folder, rig = photos
    code, events = batch(folder, "--out", out, "--rig", rig, *FIT)
    assert code == 2 and events[-1]["event"] == "error" and "--resume" in events[-1]["message"]
    before = (out / "good" / "params.json").stat().st_mtime_ns
    code, events = batch(folder, "--out", out, "--rig", rig, *FIT, "--resume")
    assert code == 1
    statuses = [(e["name"], e["status"]) for e in events if e["event"] == "pair"]
    assert ("good", "kept") in statuses and ("good", "started") not in statuses
    assert ("broken", "started") in statuses and ("broken", "failed") in statuses
    assert (out / "good" / "params.json").stat().st_mtime_ns == before
    rows = {r["name"]: r["status"] for r in json.loads((out / "catalogue.json").read_text())["pairs"]}
    assert rows == {"good": "kept", "broken": "failed"}


def test_a_task_whose_worker_dies_is_retried_once_and_reported(ray_session, photos, tmp_path):
    def die(job):  # what a crash or the out-of-memory killer does to a worker
        os._exit(1)

    folder = tmp_path / "photos"
    folder.mkdir()
    for side in "RT":
        shutil.copy(photos[0] / f"good_{side}.png", folder / f"good_{side}.png")
    events = EventStream()
    executor = connect(None).executor(FitResources())
    executor.task = ray_session.remote(num_cpus=1, max_retries=0)(die)
    summary = scheduler.run(scheduler.plan(folder, tmp_path / "out", resume=False),
                            scheduler.BatchOptions(workers=1), executor, Reporter(json_lines=True, stream=events))
    pairs = [(e["status"], e["attempt"], e["reason"]) for e in events.events() if e["event"] == "pair"]
    assert [p[:2] for p in pairs] == [("started", 1), ("retrying", 1), ("started", 2), ("failed", 2)]
    assert all(p[2].startswith(("WorkerCrashedError", "ActorDiedError", "RayTaskError")) for p in pairs[1::2]), pairs
    assert summary.failed == 1 and not (tmp_path / "out" / "good").exists()


def test_ctrl_c_stops_the_batch_and_keeps_what_is_finished(first_run, photos, tmp_path):
    out, _, _ = first_run
    folder = tmp_path / "photos"
    folder.mkdir()
    for name in ("good", "second", "third"):  # good is fitted already; the others are what Ctrl+C stops
        for side in "RT":
            shutil.copy(photos[0] / f"good_{side}.png", folder / f"{name}_{side}.png")
    shutil.copytree(out / "good", tmp_path / "out" / "good")
    # Ctrl+C as soon as a fit has started; the fits are long enough that none ends first (with FIT's two
    # iterations, one of the two fits at once could finish before the stop reached it on a busy machine).
    stream = EventStream('"status":"started"', lambda: signal.raise_signal(signal.SIGINT))
    long_fit = [*FIT[:3], "1000", *FIT[4:]]  # FIT with 1000 iterations
    code, events = batch(folder, "--out", tmp_path / "out", "--rig", photos[1], *long_fit, "--resume", stream=stream)
    assert code == 130 and events[-1]["event"] == "error" and events[-1]["kind"] == "cancelled"
    rows = {r["name"]: r["status"] for r in json.loads((tmp_path / "out" / "catalogue.json").read_text())["pairs"]}
    assert rows == {"good": "kept", "second": "cancelled", "third": "cancelled"}
    assert (tmp_path / "out" / "good" / "params.json").is_file() and not (tmp_path / "out" / "second").exists()
    assert not (tmp_path / "out" / ".staging").exists()
