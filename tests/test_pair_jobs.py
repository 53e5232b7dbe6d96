"""The job model every batch runs (backend/core/pair_jobs.py; plain Python, no torch, no bpy): the
jobs of a folder, the states an attempt's outcome leads to, the retry rule, stopping, the counts."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from backend.core import pair_jobs
from backend.core.pair_jobs import (
    CANCELLED,
    DONE,
    FAILED,
    INPUT,
    INTERNAL,
    LOST,
    NOT_STARTED,
    PENDING,
    RETRIED,
    RUNNING,
    TIMEOUT,
    PairJob,
    PairJobs,
)
from backend.core.protocol import MAX_FAILED_EXIT


def photos(folder: Path, *names: str) -> Path:
    folder.mkdir(exist_ok=True)
    for name in names:
        (folder / name).write_bytes(b"")
    return folder


def jobs_of(*names: str) -> list[PairJob]:
    return [PairJob(name, Path(f"{name}_R.png"), Path(f"{name}_T.png")) for name in names]


# -- the jobs of a folder ----------------------------------------------------------------------------

def test_a_folder_has_a_pending_job_per_pair_then_a_failed_one_per_name_without_its_pair(tmp_path):
    folder = photos(tmp_path / "photos", "wool_R.png", "wool_t.jpg", "linen_r.PNG", "linen_T.png", "solo_R.png",
                    "twice_T.png", "twice_t.tif", "notes.txt", "cloth.png")
    jobs = pair_jobs.folder_jobs(folder)
    assert [(j.name, j.state, j.attempts) for j in jobs] == [("linen", PENDING, 0), ("wool", PENDING, 0),
                                                             ("solo", FAILED, 0), ("twice", FAILED, 0)]
    assert (jobs[0].reflection, jobs[0].transmission) == (folder / "linen_r.PNG", folder / "linen_T.png")
    assert jobs[2].reason == "no transmission photo (solo_T.*) beside solo_R.png"
    assert jobs[2].reflection is None and jobs[2].transmission is None
    # A name with two problems is one job whose reason says both.
    assert jobs[3].reason == ("no reflection photo (twice_R.*) beside twice_T.png, twice_t.tif; "
                              "more than one transmission photo (twice_T.png, twice_t.tif); keep one")


def test_a_folder_without_pairs_is_refused_by_name(tmp_path):
    with pytest.raises(pair_jobs.FolderError, match="missing: not a folder"):
        pair_jobs.folder_jobs(tmp_path / "missing")
    with pytest.raises(pair_jobs.FolderError, match=r"empty: no <name>_R\.\* / <name>_T\.\* photo pairs"):
        pair_jobs.folder_jobs(photos(tmp_path / "empty", "cloth.png"))


def test_an_executor_s_jobs_carry_fields_of_their_own(tmp_path):
    @dataclass
    class Shown(PairJob):
        progress: float = 0.0

    jobs = pair_jobs.folder_jobs(photos(tmp_path / "photos", "wool_R.png", "wool_T.png", "solo_R.png"), Shown)
    assert [type(j) for j in jobs] == [Shown, Shown] and jobs[0].progress == 0.0


# -- an attempt's outcome ------------------------------------------------------------------------------

def test_jobs_start_in_order_and_a_retried_job_goes_first(tmp_path):
    batch = PairJobs(jobs_of("a", "b", "c"), max_attempts=2)
    a = batch.start_next()
    assert (a.name, a.state, a.attempts) == ("a", RUNNING, 1) and batch.running == [a]
    assert batch.end(a, INTERNAL, "RuntimeError: boom", wall_s=3.0) == PENDING
    assert (a.reason, a.wall_s) == ("RuntimeError: boom", 3.0)
    assert [batch.start_next().name for _ in range(3)] == ["a", "b", "c"] and a.attempts == 2
    assert batch.start_next() is None


@pytest.mark.parametrize("outcome", RETRIED)
def test_a_failure_worth_a_second_try_gets_one(outcome):
    batch = PairJobs(jobs_of("a"), max_attempts=2)
    job = batch.start_next()
    assert batch.end(job, outcome, "first") == PENDING
    job = batch.start_next()
    assert batch.end(job, outcome, "second") == FAILED
    assert (job.attempts, job.reason) == (2, "second") and batch.finished


def test_bad_photos_fail_at_once_and_a_done_job_is_done():
    batch = PairJobs(jobs_of("bad", "good"), max_attempts=2)
    bad, good = batch.start_next(), batch.start_next()
    assert batch.end(bad, INPUT, "bad_T.png: not an image") == FAILED and bad.attempts == 1
    assert batch.end(good, DONE, "ignored", wall_s=2.0) == DONE and good.reason is None and good.wall_s == 2.0
    assert batch.finished and batch.count(DONE) == 1 and batch.failures() == [bad]


def test_one_attempt_means_no_second_try():
    batch = PairJobs(jobs_of("a"))
    job = batch.start_next()
    assert batch.end(job, LOST, "the worker died") == FAILED and batch.start_next() is None


def test_stopping_cancels_the_waiting_jobs_and_makes_every_end_final():
    batch = PairJobs(jobs_of("retried", "running", "done", "waiting"), max_attempts=2)
    retried, running, done = batch.start_next(), batch.start_next(), batch.start_next()
    assert batch.end(retried, TIMEOUT, "no result after 5 s") == PENDING
    assert [(j.name, j.attempts) for j in batch.stop()] == [("retried", 1), ("waiting", 0)]
    assert all(j.state == CANCELLED and j.reason == NOT_STARTED for j in (retried, batch.jobs[3]))
    assert batch.start_next() is None
    assert batch.end(running, INTERNAL, "RuntimeError: boom") == FAILED      # no second try while stopping
    assert batch.end(done, DONE) == DONE                                      # a finished fit is kept
    stopped = PairJobs(jobs_of("x"), max_attempts=2)
    job = stopped.start_next()
    stopped.stop()
    assert stopped.end(job, CANCELLED, "cancelled while fitting") == CANCELLED
    assert batch.finished and stopped.finished


def test_the_exit_code_is_the_number_of_failed_jobs_capped():
    batch = PairJobs(jobs_of(*(f"p{i}" for i in range(MAX_FAILED_EXIT + 5))))
    assert batch.exit_code == 0
    while (job := batch.start_next()) is not None:
        batch.end(job, INPUT, "bad")
    assert batch.count(FAILED) == MAX_FAILED_EXIT + 5 and batch.exit_code == MAX_FAILED_EXIT


def test_unknown_outcomes_and_states_are_refused():
    batch = PairJobs(jobs_of("a"))
    job = batch.start_next()
    with pytest.raises(ValueError, match="unknown outcome 'crashed'"):
        batch.end(job, "crashed")
    with pytest.raises(ValueError, match="unknown job state 'running'"):
        job.end(RUNNING)
