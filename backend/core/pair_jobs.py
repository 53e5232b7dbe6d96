"""Fitting a folder of photo pairs: one job per pair, its states and the retry rule, for every batch.

Three executors run this model: the Ray batch (backend/app/batch: many fits at once, on this
machine or a cluster) and the add-on's sidebar queue and headless batch
(blender_addon/core/batch_queue.py, batch.py: one backend subprocess at a time). The model says
what a folder's jobs are and what the end of an attempt does to its job; an executor says how a
fit runs and what its result becomes (a results folder and a catalogue row, an asset material).

The jobs of a folder (:func:`folder_jobs`): a pending job per ``<name>_R.* / <name>_T.*`` pair
(core/pairs.py, sorted by name), then a failed job per name without its partner or with two photos
for one side (its reason names the files). A job's state::

    pending --start--> running --done--> done
                          |--------> failed | cancelled
                          '--tried again--> pending (first in line)
    kept: a complete results folder of an earlier run (core/results.py), not fitted again

An attempt ends with an :data:`OUTCOMES` value. ``done``: the fit's results are there. ``input``
(the photos are bad: the fit's exit code 2) fails the job at once, since a second try would fail
the same way. :data:`RETRIED` outcomes (an internal error, a timeout, a cancel by anyone but the batch, a task the
engine lost) are tried again while the job has attempts left (``max_attempts``). Once the batch is
stopping an attempt's end is final (cancelled if it was cancelled, else failed) and the jobs not
started are cancelled. The batch's exit code is the number of failed jobs (core/protocol.py).
Plain Python: the add-on reads this module without torch.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path

from .pairs import find_pairs
from .protocol import failed_exit_code

PENDING, RUNNING, DONE, KEPT, FAILED, CANCELLED = "pending", "running", "done", "kept", "failed", "cancelled"
FINISHED = (DONE, KEPT, FAILED, CANCELLED)
INPUT, INTERNAL, TIMEOUT, LOST = "input", "internal", "timeout", "lost"
OUTCOMES = (DONE, INPUT, INTERNAL, TIMEOUT, CANCELLED, LOST)  # how an attempt ends
RETRIED = (INTERNAL, TIMEOUT, CANCELLED, LOST)  # worth a second try; a cancel while the batch stops is not
NOT_STARTED = "not started: the batch was stopped"


class FolderError(ValueError):
    """The folder has no jobs to run: one line naming it and the problem."""


@dataclass
class PairJob:
    """One photo pair's fit. ``reflection`` and ``transmission`` are None for a name without its pair."""

    name: str
    reflection: Path | None
    transmission: Path | None
    state: str = PENDING
    attempts: int = 0                   # attempts started
    reason: str | None = None           # why it failed, was cancelled or is tried again
    wall_s: float | None = None         # the last attempt's time in the batch

    @property
    def finished(self) -> bool:
        return self.state in FINISHED

    def end(self, state: str, reason: str | None = None, wall_s: float | None = None) -> str:
        """Sets the state a job ended in (or was found in: failed, kept) and returns it."""
        if state not in (*FINISHED, PENDING):
            raise ValueError(f"unknown job state {state!r}")
        self.state, self.reason, self.wall_s = state, reason, wall_s
        return state


def no_pairs(folder: str | Path) -> FolderError:
    return FolderError(f"{folder}: no <name>_R.* / <name>_T.* photo pairs")


def folder_jobs(folder: str | Path, job_type: type[PairJob] = PairJob) -> list[PairJob]:
    """The jobs of ``folder`` (see the module docstring); FolderError when it is not a folder or holds
    no photo named as a pair. ``job_type``: an executor's PairJob with fields of its own."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FolderError(f"{folder}: not a folder")
    pairs, problems = find_pairs(folder)
    if not pairs and not problems:
        raise no_pairs(folder)
    reasons: dict[str, list[str]] = {}
    for problem in problems:
        reasons.setdefault(problem.name, []).append(problem.message)
    return ([job_type(pair.name, pair.reflection, pair.transmission) for pair in pairs]
            + [job_type(name, None, None, FAILED, reason="; ".join(messages)) for name, messages in reasons.items()])


class PairJobs:
    """The jobs of one batch: which starts next, what an attempt's end does to its job, the counts."""

    def __init__(self, jobs: list[PairJob], max_attempts: int = 1):
        self.jobs, self.max_attempts = list(jobs), max_attempts
        self.waiting: deque[PairJob] = deque(job for job in self.jobs if job.state == PENDING)
        self.stopping = False

    def start_next(self) -> PairJob | None:
        """The next waiting job, now running (its attempt counted); None when none waits."""
        if not self.waiting:
            return None
        job = self.waiting.popleft()
        job.state, job.attempts = RUNNING, job.attempts + 1
        return job

    def end(self, job: PairJob, outcome: str, reason: str | None = None, wall_s: float | None = None) -> str:
        """Applies the retry rule to an attempt's outcome; returns the job's new state (pending: tried again)."""
        if outcome not in OUTCOMES:
            raise ValueError(f"unknown outcome {outcome!r}")
        if outcome == DONE:
            return job.end(DONE, wall_s=wall_s)
        if self.stopping:
            return job.end(CANCELLED if outcome == CANCELLED else FAILED, reason, wall_s)
        if outcome in RETRIED and job.attempts < self.max_attempts:
            self.waiting.appendleft(job)
            return job.end(PENDING, reason, wall_s)
        return job.end(FAILED, reason, wall_s)

    def stop(self) -> list[PairJob]:
        """From now on every attempt's end is final; the waiting jobs are cancelled (and returned)."""
        self.stopping = True
        cancelled = list(self.waiting)
        self.waiting.clear()
        for job in cancelled:
            job.end(CANCELLED, NOT_STARTED)
        return cancelled

    @property
    def running(self) -> list[PairJob]:
        return [job for job in self.jobs if job.state == RUNNING]

    @property
    def finished(self) -> bool:
        return all(job.finished for job in self.jobs)

    def count(self, *states: str) -> int:
        return sum(job.state in states for job in self.jobs)

    def failures(self) -> list[PairJob]:
        return [job for job in self.jobs if job.state == FAILED]

    @property
    def exit_code(self) -> int:
        """The number of failed jobs, capped (core/protocol.py)."""
        return failed_exit_code(self.count(FAILED))
