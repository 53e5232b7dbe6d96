"""The batch's driver loop on an engine: every pair a task, at most ``workers`` at a time, nothing lost or done twice.

:func:`plan` reads the photo folder and DIR before any engine starts (a bad folder fails in a
second, not after Ray's start); :func:`run` then hands one :class:`~.job.FitJob` per pair to an
:class:`Executor` (ray_executor.py's on Ray; the tests use a plain one). The jobs, their states
and the retry rule are the shared job model's (backend/core/pair_jobs.py; two attempts here: a
worker or a machine may die); here each finished attempt becomes files: a done job's results are
written as ``DIR/<name>`` (output.py) and its row joins the catalogue, rewritten after every
finished pair; a failed attempt's log goes to ``DIR/logs``.

Pairs are submitted as workers free up, so a catalogue of thousands never has its photos in the
engine's memory at once. ``should_stop()`` (Ctrl+C) cancels the running fits, waits a little for
them to stop, keeps what finished and marks the rest cancelled.

The time left: ``(queued * m + sum over running fits of max(m - their time so far, 0)) / w``, with
m the mean wall time of this run's finished fits and w the fits that can run at once.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from ...core import pair_jobs
from ...core.pair_jobs import CANCELLED, DONE, FAILED, KEPT, PENDING, PairJob, PairJobs
from ...core.protocol import Reporter
from . import catalogue, output
from .job import FitJob, FitOutcome

ATTEMPTS = 2  # fits of a pair at most: a second try after a failure it may not repeat (pair_jobs.RETRIED)
PROGRESS_EVERY_S = 5.0  # the progress line is also refreshed this often (its time left changes)
POLL_S = 0.5  # how long the driver waits for a finished fit before it looks at Ctrl+C again


class BatchError(ValueError):
    """The batch cannot start: one line naming the folder and the problem."""


class TaskLost(Exception):
    """The engine lost a task (its worker or machine died, it ran out of memory); the message says how."""


class Executor(Protocol):
    def submit(self, job: FitJob) -> Any: ...

    def wait(self, handles: list, timeout: float) -> list: ...  # the handles that have finished

    def outcome(self, handle) -> FitOutcome: ...  # raises TaskLost

    def cancel(self, handle) -> None: ...


@dataclass
class BatchPlan:
    photos: Path
    out: Path
    jobs: list[PairJob]                      # every pair's job (kept and failed ones included)
    fitted: dict[str, dict]                  # the catalogue values of each kept (later also done) pair
    moved: list[Path] = field(default_factory=list)  # incomplete folders moved aside

    @property
    def to_fit(self) -> list[PairJob]:
        return [job for job in self.jobs if job.state == PENDING]

    @property
    def rows(self) -> dict[str, dict]:
        """Every pair's catalogue row so far (kept, failed, pending, ...)."""
        return {job.name: catalogue.row(job, self.fitted.get(job.name)) for job in self.jobs}

    @property
    def total(self) -> int:
        return len(self.jobs)


@dataclass
class BatchOptions:
    workers: int
    fit_options: dict = field(default_factory=dict)  # the fit command's option values (dest -> value)
    rig_text: str | None = None                      # a RIG.json's text, shipped to every task
    threads: int = 1                                 # torch and OpenCV threads of each fit
    timeout_s: float | None = None
    cancel_grace_s: float = 30.0
    settings: dict = field(default_factory=dict)     # recorded in catalogue.json


@dataclass
class BatchSummary:
    rows: dict[str, dict]
    catalogue: Path
    csv: Path
    cancelled: bool = False

    def count(self, *statuses: str) -> int:
        return sum(r["status"] in statuses for r in self.rows.values())

    @property
    def failed(self) -> int:
        return self.count(FAILED)


def plan(photos: str | Path, out: str | Path, resume: bool) -> BatchPlan:
    """The jobs of ``photos`` and what DIR already holds; raises BatchError or output.OutputError."""
    photos, out = Path(photos).resolve(), Path(out).resolve()
    try:
        jobs = pair_jobs.folder_jobs(photos)
    except pair_jobs.FolderError as exc:
        raise BatchError(str(exc)) from None
    for job in jobs:
        problem = output.name_problem(job.name) if job.state == PENDING else None
        if problem:
            job.end(FAILED, problem)
    usable = [job for job in jobs if job.state == PENDING]
    if not usable and all(job.reflection is not None for job in jobs):  # only names DIR cannot take
        raise BatchError(str(pair_jobs.no_pairs(photos)))
    kept, moved = output.prepare(out, [job.name for job in usable], resume)
    fitted = {}
    for job in usable:
        if job.name in kept:
            try:
                fitted[job.name] = catalogue.fitted_values(out / job.name, out)
                job.end(KEPT)
            except catalogue.CatalogueError:  # complete by its files, unreadable by its contents: fit again
                moved.append(output.move_aside(out / job.name))
    return BatchPlan(photos, out, jobs, fitted, moved)


def run(plan: BatchPlan, options: BatchOptions, executor: Executor | None, reporter: Reporter,
        should_stop: Callable[[], bool] = lambda: False) -> BatchSummary:
    """Fits every pair of the plan (``executor`` may be None when there is none to fit); never raises
    for a pair (see the module docstring)."""
    return _Run(plan, options, executor, reporter).loop(should_stop)


class _Run:
    def __init__(self, plan: BatchPlan, options: BatchOptions, executor: Executor, reporter: Reporter):
        self.plan, self.options, self.executor, self.reporter = plan, options, executor, reporter
        self.jobs = PairJobs(plan.jobs, max_attempts=ATTEMPTS)
        self.running: dict[Any, tuple[PairJob, float]] = {}  # handle -> (job, started)
        self.fit_walls: list[float] = []
        self.header = {"photos": str(plan.photos), "out": str(plan.out), "settings": options.settings}
        self.catalogue_paths = self._write_catalogue()
        self._shown, self._shown_at = None, 0.0

    def loop(self, should_stop) -> BatchSummary:
        for job in sorted(self.plan.jobs, key=lambda j: j.name):
            if job.state in (KEPT, FAILED):
                self.reporter.pair(job.name, job.state, reason=job.reason,
                                   out_dir=str(self.plan.out / job.name) if job.state == KEPT else None)
        self._progress(force=True)
        cancelled = False
        while self.jobs.waiting or self.running:
            if should_stop():
                cancelled = True
                self._cancel()
                break
            self._fill()
            for handle in self.executor.wait(list(self.running), POLL_S):
                self._finish(handle)
            self._progress()
        output.remove_staging(self.plan.out)
        self._progress(force=True)
        return BatchSummary(self.plan.rows, *self.catalogue_paths, cancelled=cancelled)

    # -- submitting and finishing ------------------------------------------------------------------

    def _fill(self):
        while self.jobs.waiting and len(self.running) < self.options.workers:
            job = self.jobs.start_next()
            try:
                fit_job = FitJob.of(job, self.plan.out / job.name, self.options.fit_options, self.options.rig_text,
                                    self.options.threads, self.options.timeout_s)
            except OSError as exc:
                self._final(job, FAILED, f"{exc.filename}: cannot read ({exc.strerror or exc})")
                continue
            self.running[self.executor.submit(fit_job)] = (job, time.monotonic())
            self.reporter.pair(job.name, "started", job.attempts)

    def _finish(self, handle):
        job, started = self.running.pop(handle)
        try:
            outcome = self.executor.outcome(handle)
        except TaskLost as exc:
            outcome = FitOutcome(job.name, pair_jobs.LOST, reason=str(exc))
        wall = time.monotonic() - started
        if outcome.log:
            output.write_log(self.plan.out, job.name, job.attempts, outcome.log)
        if outcome.status == DONE:
            try:
                folder = output.write_result(self.plan.out, job.name, outcome.files)
                self.plan.fitted[job.name] = catalogue.fitted_values(folder, self.plan.out)
            except (OSError, catalogue.CatalogueError) as exc:
                self._final(job, FAILED, f"results not saved: {exc}", wall)
                return
            self.fit_walls.append(wall)
        attempt = job.attempts
        if self.jobs.end(job, outcome.status, outcome.reason, wall) == PENDING:
            self.reporter.pair(job.name, "retrying", attempt, reason=outcome.reason, wall_s=wall)
        else:
            self._reported(job)

    def _final(self, job: PairJob, state: str, reason: str | None = None, wall_s: float | None = None):
        job.end(state, reason, wall_s)
        self._reported(job)

    def _reported(self, job: PairJob):
        """Says how a job ended and rewrites the catalogue."""
        out_dir = str(self.plan.out / job.name) if job.state == DONE else None
        self.reporter.pair(job.name, job.state, job.attempts, reason=job.reason, out_dir=out_dir, wall_s=job.wall_s)
        self.catalogue_paths = self._write_catalogue()

    def _cancel(self):
        """Stops the running fits; those that finish within the grace time are kept."""
        not_started = self.jobs.stop()
        for handle in self.running:
            self.executor.cancel(handle)
        deadline = time.monotonic() + self.options.cancel_grace_s
        while self.running and time.monotonic() < deadline:
            for handle in self.executor.wait(list(self.running), POLL_S):
                self._finish(handle)
        for job, started in self.running.values():
            self._final(job, CANCELLED, "still running when the batch was stopped", time.monotonic() - started)
        self.running.clear()
        for job in not_started:
            self._reported(job)

    # -- reporting ---------------------------------------------------------------------------------

    def _write_catalogue(self) -> tuple[Path, Path]:
        return catalogue.write(self.plan.out, list(self.plan.rows.values()), self.header)

    def counts(self) -> dict:
        return {"total": self.plan.total, "done": self.jobs.count(DONE, KEPT), "running": len(self.running),
                "failed": self.jobs.count(FAILED), "queued": len(self.jobs.waiting)}

    def eta_s(self) -> float | None:
        if not self.fit_walls:
            return None
        mean = sum(self.fit_walls) / len(self.fit_walls)
        now = time.monotonic()
        left = len(self.jobs.waiting) * mean + sum(max(mean - (now - started), 0.0) for _, started in
                                                   self.running.values())
        return left / max(1, min(self.options.workers, len(self.jobs.waiting) + len(self.running)))

    def _progress(self, force: bool = False):
        counts = self.counts()
        now = time.monotonic()
        if force or counts != self._shown or now - self._shown_at >= PROGRESS_EVERY_S:
            self.reporter.batch(**counts, eta_s=self.eta_s())
            self._shown, self._shown_at = counts, now
