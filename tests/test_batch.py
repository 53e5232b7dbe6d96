"""The batch's driver without Ray: pairs, DIR, retries, Ctrl+C, progress and the catalogue, with an
engine that returns prepared outcomes at once (test_batch_ray.py runs the real fits on a local Ray).
"""
from __future__ import annotations

import ast
import csv
import io
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from conftest import ROOT

sys.path.insert(0, str(Path(__file__).resolve().parent))

from fake_backend import fake_params  # noqa: E402

from backend.app.batch import catalogue, output, scheduler  # noqa: E402
from backend.app.batch.job import FitJob, FitOutcome, run_fit_job  # noqa: E402
from backend.app.batch.ray_executor import FitResources, RayConnection  # noqa: E402
from backend.app.cli.main import main  # noqa: E402
from backend.core.pair_jobs import FAILED, PENDING  # noqa: E402
from backend.core.pairs import PhotoFiles  # noqa: E402
from backend.core.protocol import ProtocolError, Reporter, decode, failed_exit_code  # noqa: E402
from backend.core.results import RESULT_FILES, is_complete, missing_files  # noqa: E402


def result_files(name: str) -> dict[str, bytes]:
    """What a finished fit sends back: valid params.json and metrics.json, stand-in images."""
    metrics = {"metrics": {side: {"flip": 0.1, "colour_l1": 0.01, "spectrum_corr": 0.9}
                           for side in ("reflection", "transmission")}, "wall_s": 12.5, "loss": 0.25}
    files = {name_: b"png" for name_ in RESULT_FILES}
    files["params.json"] = json.dumps({**fake_params(name), "interchange": f"{name}-interchange"}).encode()
    files["metrics.json"] = json.dumps(metrics).encode()
    return files


def done(name: str) -> FitOutcome:
    return FitOutcome(name, "done", files=result_files(name), log="warning: a warning\n")


class ScriptedEngine:
    """An Executor whose tasks end at once with the outcomes scripted per pair and attempt
    (a FitOutcome, or an exception for a task the engine lost); unscripted pairs fit fine."""

    def __init__(self, script: dict[str, list] | None = None, hold: set[str] = frozenset()):
        self.script = {name: list(outcomes) for name, outcomes in (script or {}).items()}
        self.hold = set(hold)          # pairs whose tasks never end by themselves (until cancelled)
        self.jobs, self.cancelled, self.running, self.most_at_once = [], [], {}, 0

    def submit(self, job: FitJob):
        handle = len(self.jobs)
        self.jobs.append(job)
        self.running[handle] = job
        self.most_at_once = max(self.most_at_once, len(self.running))
        return handle

    def wait(self, handles, timeout):
        return [h for h in handles if self.running[h].name not in self.hold or h in self.cancelled]

    def outcome(self, handle):
        job = self.running.pop(handle)
        if handle in self.cancelled:
            return FitOutcome(job.name, "cancelled", "cancelled while fitting")
        scripted = self.script.get(job.name)
        result = scripted.pop(0) if scripted else done(job.name)
        if isinstance(result, Exception):
            raise result
        return result

    def cancel(self, handle):
        self.cancelled.append(handle)


def make_photos(folder: Path, names, broken=(), orphans=()) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    image = np.full((8, 8, 3), 128, np.uint8)
    for name in names:
        for side in "RT":
            cv2.imwrite(str(folder / f"{name}_{side}.png"), image)
    for name in broken:
        (folder / f"{name}_R.png").write_bytes(b"\x89PNG broken")
        (folder / f"{name}_T.png").write_bytes(b"\x89PNG broken")
    for name in orphans:
        cv2.imwrite(str(folder / f"{name}_R.png"), image)
    return folder


def run(photos, out, engine, workers=2, resume=False, should_stop=lambda: False, **options):
    events = io.StringIO()
    plan = scheduler.plan(photos, out, resume)
    summary = scheduler.run(plan, scheduler.BatchOptions(workers=workers, **options), engine,
                            Reporter(json_lines=True, stream=events, log=io.StringIO()), should_stop)
    return summary, [decode(line) for line in events.getvalue().splitlines()]


def pair_events(events, status=None):
    return [(e["name"], e["status"], e["attempt"]) for e in events
            if e["event"] == "pair" and (status is None or e["status"] == status)]


# -- the results folder rule ----------------------------------------------------------------------

def test_a_results_folder_is_complete_only_with_every_file(tmp_path):
    assert missing_files(tmp_path) == list(RESULT_FILES) and not is_complete(tmp_path)
    for name, data in result_files("a").items():
        (tmp_path / name).write_bytes(data)
    assert is_complete(tmp_path)
    (tmp_path / "report.png").write_bytes(b"")  # a copy cut short
    assert missing_files(tmp_path) == ["report.png"]


def test_the_ray_batch_and_the_addon_s_queue_list_a_folder_s_jobs_alike(tmp_path):
    """Both executors run the one job model: the same jobs, states and reasons for the same folder."""
    from blender_addon.core import batch_queue

    photos = make_photos(tmp_path / "photos", ["denim", "linen"], orphans=["solo"])
    ray_jobs = scheduler.plan(photos, tmp_path / "out", resume=False).jobs
    queued = batch_queue.folder_pairs(photos.resolve())
    assert [(j.name, j.state, j.reason, j.reflection) for j in ray_jobs] == \
        [(j.name, j.state, j.reason, j.reflection) for j in queued]
    assert [j.state for j in ray_jobs] == [PENDING, PENDING, FAILED]


# -- one batch ------------------------------------------------------------------------------------

def test_every_pair_runs_once_failures_are_retried_once_bad_input_is_not(tmp_path):
    photos = make_photos(tmp_path / "photos", ["crash", "denim", "flaky", "linen", "lost", "torn"], orphans=["solo"])
    engine = ScriptedEngine({
        "torn": [FitOutcome("torn", "input", "torn_T.png: not an image", log="error: torn_T.png: not an image\n")],
        "flaky": [FitOutcome("flaky", "internal", "RuntimeError: boom", log="Traceback ...\n"), done("flaky")],
        "lost": [scheduler.TaskLost("WorkerCrashedError: the worker died"),
                 scheduler.TaskLost("NodeDiedError: the machine left")],
        "crash": [FitOutcome("crash", "timeout", "no result after 5 s"), FitOutcome("crash", "input", "bad")],
    })
    summary, events = run(photos, tmp_path / "out", engine, workers=2, threads=3, timeout_s=5.0,
                          fit_options={"iterations": 7}, rig_text='{"film_size": 64}')

    statuses = {name: (row["status"], row["attempts"]) for name, row in summary.rows.items()}
    assert statuses == {"crash": ("failed", 2), "denim": ("done", 1), "flaky": ("done", 2), "linen": ("done", 1),
                        "lost": ("failed", 2), "solo": ("failed", 0), "torn": ("failed", 1)}
    assert failed_exit_code(summary.failed) == 4
    assert summary.rows["lost"]["reason"] == "NodeDiedError: the machine left"
    assert summary.rows["solo"]["reason"] == "no transmission photo (solo_T.*) beside solo_R.png"
    assert sorted(pair_events(events, "retrying")) == [("crash", "retrying", 1), ("flaky", "retrying", 1),
                                                       ("lost", "retrying", 1)]
    retry = next(e for e in events if e["event"] == "pair" and e["status"] == "retrying" and e["name"] == "lost")
    assert retry["reason"] == "WorkerCrashedError: the worker died"
    # At most `workers` tasks at once; every job carries the photos' bytes and the batch's settings.
    assert engine.most_at_once == 2 and len(engine.jobs) == 9
    job = next(j for j in engine.jobs if j.name == "denim")
    assert job.reflection == str(photos / "denim_R.png")
    assert job.reflection_bytes == (photos / "denim_R.png").read_bytes()
    assert (job.threads, job.timeout_s, job.options, job.rig_text) == (3, 5.0, {"iterations": 7}, '{"film_size": 64}')
    # DIR: one complete folder per fitted pair, nothing for the others; the logs keep every attempt.
    out = tmp_path / "out"
    assert sorted(p.name for p in out.iterdir()) == ["catalogue.csv", "catalogue.json", "denim", "flaky", "linen",
                                                     "logs"]
    assert all(is_complete(out / name) for name in ("denim", "flaky", "linen"))
    flaky_log = (out / "logs" / "flaky.log").read_text()
    assert "attempt 1" in flaky_log and "Traceback" in flaky_log and "attempt 2" in flaky_log
    # The last progress line adds up.
    last = [e for e in events if e["event"] == "batch"][-1]
    assert {k: last[k] for k in ("total", "done", "running", "failed", "queued")} == \
        {"total": 7, "done": 3, "running": 0, "failed": 4, "queued": 0}


def test_the_catalogue_lists_every_pair_with_its_parameters_and_metrics(tmp_path):
    photos = make_photos(tmp_path / "photos", ["denim", "torn"])
    engine = ScriptedEngine({"torn": [FitOutcome("torn", "input", "torn_T.png: not an image")]})
    summary, _ = run(photos, tmp_path / "out", engine)
    data = json.loads(summary.catalogue.read_text())
    assert data["photos"] == str(photos.resolve()) and data["columns"] == list(catalogue.COLUMNS)
    denim, torn = data["pairs"]
    params = fake_params("denim")
    assert (denim["name"], denim["status"], denim["pattern"], denim["folder"]) == ("denim", "done", "twill1", "denim")
    assert (denim["tiles_warp"], denim["tiles_weft"]) == tuple(params["tiles"])
    assert denim["diffuse_reflection_g"] == params["diffuse_reflection"][1]
    assert (denim["flip_R"], denim["spectrum_corr_T"], denim["loss"], denim["fit_s"]) == (0.1, 0.9, 0.25, 12.5)
    assert denim["interchange"] == "denim-interchange" and denim["attempts"] == 1 and denim["wall_s"] >= 0
    assert (torn["status"], torn["reason"], torn["pattern"]) == ("failed", "torn_T.png: not an image", None)
    with open(summary.csv, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert tuple(rows[0]) == catalogue.COLUMNS
    assert [(r["name"], r["status"], r["tiles_warp"], r["reason"]) for r in rows] == [
        ("denim", "done", str(params["tiles"][0]), ""), ("torn", "failed", "", "torn_T.png: not an image")]


def test_resume_keeps_complete_folders_and_redoes_the_rest(tmp_path):
    photos = make_photos(tmp_path / "photos", ["denim", "half", "linen", "wool"])
    out = tmp_path / "out"
    first, _ = run(photos, out, ScriptedEngine({"wool": [FitOutcome("wool", "input", "bad")]}))
    assert first.count("done") == 3
    (out / "half" / "report.png").unlink()            # a folder cut short
    (out / "linen" / "params.json").write_text("{")   # complete by its files, unreadable
    before = (out / "denim" / "params.json").stat().st_mtime_ns

    with pytest.raises(output.OutputError, match="already holds results of 3 of these pairs; pass --resume"):
        scheduler.plan(photos, out, resume=False)
    engine = ScriptedEngine()
    summary, events = run(photos, out, engine, resume=True)
    assert sorted(j.name for j in engine.jobs) == ["half", "linen", "wool"]  # denim is not fitted twice
    assert {n: r["status"] for n, r in summary.rows.items()} == {"denim": "kept", "half": "done", "linen": "done",
                                                                 "wool": "done"}
    assert ("denim", "kept", 1) in pair_events(events)
    assert (out / "denim" / "params.json").stat().st_mtime_ns == before
    assert summary.rows["denim"]["tiles_warp"] == fake_params("denim")["tiles"][0]  # the kept row has its values
    aside = sorted(p.name for p in (out / ".incomplete").iterdir())
    assert aside == ["half-1", "linen-1"] and not (out / ".incomplete" / "half-1" / "report.png").exists()
    assert all(is_complete(out / name) for name in ("denim", "half", "linen", "wool"))


def test_a_new_batch_never_writes_into_earlier_results(tmp_path):
    photos = make_photos(tmp_path / "photos", ["denim"])
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "catalogue.json").write_text("{}")
    with pytest.raises(output.OutputError, match="an earlier batch's catalogue; pass --resume"):
        scheduler.plan(photos, tmp_path / "out", resume=False)
    (tmp_path / "file").write_text("")
    with pytest.raises(output.OutputError, match="exists and is not a folder"):
        scheduler.plan(photos, tmp_path / "file", resume=False)
    with pytest.raises(scheduler.BatchError, match="no <name>_R.* / <name>_T.* photo pairs"):
        scheduler.plan(tmp_path / "out", tmp_path / "out2", resume=False)
    with pytest.raises(scheduler.BatchError, match="not a folder"):
        scheduler.plan(tmp_path / "missing", tmp_path / "out2", resume=False)


def test_pairs_named_like_the_batch_s_own_files_are_refused(tmp_path):
    photos = make_photos(tmp_path / "photos", ["logs", "denim"])
    summary, _ = run(photos, tmp_path / "out", ScriptedEngine())
    assert summary.rows["logs"]["status"] == "failed" and "reserved" in summary.rows["logs"]["reason"]
    assert summary.rows["denim"]["status"] == "done"


def test_stopping_keeps_what_finished_and_cancels_the_rest(tmp_path):
    photos = make_photos(tmp_path / "photos", ["a", "b", "c", "d"])
    engine = ScriptedEngine(hold={"b"})
    summary, events = run(photos, tmp_path / "out", engine, workers=2, cancel_grace_s=1.0,
                          should_stop=lambda: any(e.name == "c" for e in engine.jobs))
    assert summary.cancelled
    assert {n: r["status"] for n, r in summary.rows.items()} == {"a": "done", "b": "cancelled", "c": "done",
                                                                 "d": "cancelled"}
    assert summary.rows["d"]["reason"] == "not started: the batch was stopped"
    assert [engine.jobs[h].name for h in engine.cancelled] == ["b"]
    assert is_complete(tmp_path / "out" / "a") and not (tmp_path / "out" / "b").exists()
    assert json.loads(summary.catalogue.read_text())["pairs"][1]["status"] == "cancelled"


def test_the_time_left_comes_from_the_finished_fits(tmp_path):
    photos = make_photos(tmp_path / "photos", ["a", "b", "c", "d", "e"])
    summary, events = run(photos, tmp_path / "out", ScriptedEngine(), workers=1)
    progress = [e for e in events if e["event"] == "batch"]
    assert progress[0]["eta_s"] is None  # nothing finished yet
    assert all(e["eta_s"] is not None for e in progress if e["done"] >= 1)
    assert progress[-1]["eta_s"] == 0.0 and progress[-1]["done"] == 5


class MachinesOnly:
    """What RayConnection reads of Ray: its machines (one gone) and their resources."""

    def __init__(self, *machines):
        self.machines = machines

    def nodes(self):
        return [{"Alive": True, "Resources": m} for m in self.machines] + [{"Alive": False, "Resources": {"CPU": 64}}]


def test_the_fits_at_once_follow_each_machine_s_cpus_gpus_and_memory():
    gb = 2**30
    ray = RayConnection(MachinesOnly({"CPU": 16, "GPU": 1, "memory": 20 * gb}, {"CPU": 4, "memory": 64 * gb}),
                        started_here=False, local=False)
    assert ray.capacity(FitResources(1, 0, 2)) == 10 + 4        # the first machine runs out of memory first
    assert ray.capacity(FitResources(2, 0, 0)) == 8 + 2
    assert ray.capacity(FitResources(1, 0.25, 2)) == 4          # four fits share the one GPU
    assert FitResources(2, 0.5, 1.5).ray_options() == {"num_cpus": 2, "num_gpus": 0.5, "memory": int(1.5 * gb)}
    assert ray.check_fits_on_a_machine(FitResources(16, 0, 2)) is None
    problem = ray.check_fits_on_a_machine(FitResources(32, 0, 2))
    assert "no machine of this Ray has that much (the largest: 16 CPUs, 1 GPUs, 20.0 GB for tasks)" in problem
    assert RayConnection(MachinesOnly(), started_here=False, local=True).capacity(FitResources()) == 1


# -- the task itself (in this process, no Ray) ----------------------------------------------------

def test_a_fit_job_reports_bad_photos_by_their_own_paths(tmp_path):
    photos = make_photos(tmp_path / "photos", [], broken=["torn"])
    pair = PhotoFiles("torn", photos / "torn_R.png", photos / "torn_T.png")
    threads = torch.get_num_threads()
    try:
        outcome = run_fit_job(FitJob.of(pair, tmp_path / "out" / "torn", {"size": 32}, None, 1, None))
    finally:  # the job sets this process's threads (a Ray worker's); give the other tests theirs back
        torch.set_num_threads(threads)
    assert outcome.status == "input" and outcome.files == {}
    assert outcome.reason.startswith(str(photos / "torn_R.png")), outcome.reason  # not the temporary copy
    assert "fabric-batch-" not in outcome.log


# -- the protocol's batch events --------------------------------------------------------------------

def test_pair_and_batch_events_on_both_outputs():
    stream, log = io.StringIO(), io.StringIO()
    reporter = Reporter(json_lines=True, stream=stream, log=log)
    reporter.pair("denim", "retrying", 1, reason="WorkerCrashedError: gone", wall_s=3.14159)
    reporter.batch(total=4, done=1, running=2, failed=0, queued=1, eta_s=125.04)
    pair, batch = (decode(line) for line in stream.getvalue().splitlines())
    assert pair == {"event": "pair", "name": "denim", "status": "retrying", "attempt": 1,
                    "reason": "WorkerCrashedError: gone", "out_dir": None, "wall_s": 3.14}
    assert {k: batch[k] for k in ("total", "done", "running", "failed", "queued", "eta_s")} == \
        {"total": 4, "done": 1, "running": 2, "failed": 0, "queued": 1, "eta_s": 125.0}
    with pytest.raises(ProtocolError, match="unknown pair status"):
        reporter.pair("denim", "lost")

    terminal = Reporter(json_lines=False, stream=io.StringIO(), log=log)
    terminal.batch(total=4, done=1, running=2, failed=1, queued=0, eta_s=125)
    terminal.pair("denim", "failed", 2, reason="bad photo", wall_s=61)
    terminal.pair("linen", "started")  # the bar says how many run; no line per start
    assert log.getvalue().endswith("   batch [###############...............] 1/4 done, 2 running, 1 failed, "
                                   "eta 2m05s\nfailed    denim (attempt 2, 61 s): bad photo\n")
    assert failed_exit_code(0) == 0 and failed_exit_code(7) == 7 and failed_exit_code(4000) == 125


# -- the command line, before Ray starts ---------------------------------------------------------------

def test_without_ray_the_batch_says_how_to_install_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as where it is not installed
    photos = make_photos(tmp_path / "photos", ["denim"])
    assert main(["batch", str(photos), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "error: the batch runs on Ray, which is not installed: pip install -e '.[cluster]' (or pip install ray)")


def test_ray_is_imported_in_one_place_and_only_when_the_batch_runs():
    # Ray is an optional extra: `fit`, the other commands and the add-on must import without it.
    found = []
    for path in sorted((ROOT / "backend").rglob("*.py")) + sorted((ROOT / "blender_addon").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            if any(name == "ray" or name.startswith("ray.") for name in names):
                found.append((path.relative_to(ROOT).as_posix(), node.col_offset > 0))
    assert found == [("backend/app/batch/ray_executor.py", True)]  # inside connect(), not at the top


def test_the_batch_refuses_bad_input_before_starting_ray(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # were Ray reached, the error would say so
    assert main(["batch", str(tmp_path / "missing"), "--out", str(tmp_path / "out"), "--json-progress"]) == 2
    error = decode(capsys.readouterr().out.splitlines()[-1])
    assert error["event"] == "error" and error["kind"] == "input" and "missing: not a folder" in error["message"]
    rig = tmp_path / "rig.json"
    rig.write_text('{"film_size": -1}')
    assert main(["batch", str(tmp_path), "--out", str(tmp_path / "out"), "--rig", str(rig)]) == 2
    assert "rig.film_size: must be a positive number" in capsys.readouterr().err
    photos = make_photos(tmp_path / "photos", ["denim"])
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "catalogue.json").write_text("{}")
    assert main(["batch", str(photos), "--out", str(tmp_path / "out")]) == 2
    assert "already holds an earlier batch's catalogue; pass --resume" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["batch", str(photos), "--out", str(tmp_path / "out"), "--cpus-per-fit", "0"])
    assert "--cpus-per-fit: must be more than 0" in capsys.readouterr().err


def test_a_resume_with_nothing_left_to_fit_needs_no_ray(tmp_path, monkeypatch, capsys):
    photos = make_photos(tmp_path / "photos", ["denim", "linen"])
    run(photos, tmp_path / "out", ScriptedEngine())
    monkeypatch.setitem(sys.modules, "ray", None)
    assert main(["batch", str(photos), "--out", str(tmp_path / "out"), "--resume", "--json-progress"]) == 0
    events = [decode(line) for line in capsys.readouterr().out.splitlines()]
    assert events[-1]["event"] == "result" and (events[-1]["done"], events[-1]["failed"]) == (2, 0)
    rows = json.loads((tmp_path / "out" / "catalogue.json").read_text())["pairs"]
    assert [(r["name"], r["status"]) for r in rows] == [("denim", "kept"), ("linen", "kept")]
