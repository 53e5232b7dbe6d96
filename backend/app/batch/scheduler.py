"""The batch's driver loop: every pair a task, at most ``workers`` at a time, nothing lost or done twice.

:func:`plan` reads the photo folder and DIR before any engine starts (a bad folder fails in a
second, not after Ray's start); :func:`run` then hands one :class:`~.job.FitJob` per pair to an
:class:`Executor` (ray_executor.py's on Ray; the tests use a plain one) and, as each ends:

- ``done``: its files are written as ``DIR/<name>`` (output.py) and its row joins the catalogue;
- ``input`` (the photos are bad: the fit's exit code 2): failed at once; a second try would fail the same way;
- ``internal``, ``timeout``, ``cancelled`` by anyone but the batch, or a task the engine lost (its
  worker or machine died, an out-of-memory kill): reported with the reason and tried once more;
  failed after the second failure.

Pairs are submitted as workers free up, so a catalogue of thousands never has its photos in the
engine's memory at once. ``should_stop()`` (Ctrl+C) cancels the running fits, waits a little for
them to stop, keeps what finished and marks the rest cancelled. The catalogue is rewritten after
every finished pair.

The time left: ``(queued * m + sum over running fits of max(m - their time so far, 0)) / w``, with
m the mean wall time of this run's finished fits and w the fits that can run at once.
"""
from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from ...core.pairs import PhotoFiles, find_pairs
from ...core.protocol import Reporter
from . import catalogue, output
from .job import FitJob, FitOutcome

RETRIED = ("internal", "timeout", "cancelled", "lost")  # "cancelled" while the batch is not stopping
PROGRESS_EVERY_S = 5.0  # the progress line is also refreshed this often (its time left changes)
POLL_S = 0.5


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
    to_fit: list[PhotoFiles]
    rows: dict[str, dict]                    # every pair's catalogue row so far (kept, failed, pending)
    moved: list[Path] = field(default_factory=list)  # incomplete folders moved aside

    @property
    def total(self) -> int:
        return len(self.rows)


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
        return self.count("failed")


def plan(photos: str | Path, out: str | Path, resume: bool) -> BatchPlan:
    """The pairs of ``photos`` and what DIR already holds; raises BatchError or output.OutputError."""
    photos, out = Path(photos).resolve(), Path(out).resolve()
    if not photos.is_dir():
        raise BatchError(f"{photos}: not a folder")
    pairs, problems = find_pairs(photos)
    rows = {p.name: catalogue.row(p.name, "failed", reason=p.message) for p in problems}
    usable = []
    for pair in pairs:
        problem = output.name_problem(pair.name)
        if problem:
            rows[pair.name] = catalogue.row(pair.name, "failed", reflection=pair.reflection,
                                            transmission=pair.transmission, reason=problem)
        else:
            usable.append(pair)
    if not usable and not problems:
        raise BatchError(f"{photos}: no <name>_R.* / <name>_T.* photo pairs")
    kept, moved = output.prepare(out, [p.name for p in usable], resume)
    to_fit = []
    for pair in usable:
        files = {"reflection": pair.reflection, "transmission": pair.transmission}
        if pair.name in kept:
            try:
                rows[pair.name] = catalogue.fitted_row(pair.name, "kept", out / pair.name, out, **files)
                continue
            except catalogue.CatalogueError:  # complete by its files, unreadable by its contents: fit again
                moved.append(output.move_aside(out / pair.name))
        rows[pair.name] = catalogue.row(pair.name, "pending", **files)
        to_fit.append(pair)
    return BatchPlan(photos, out, to_fit, rows, moved)


def run(plan: BatchPlan, options: BatchOptions, executor: Executor | None, reporter: Reporter,
        should_stop: Callable[[], bool] = lambda: False) -> BatchSummary:
    """Fits every pair of the plan (``executor`` may be None when there is none to fit); never raises
    for a pair (see the module docstring)."""
    return _Run(plan, options, executor, reporter).loop(should_stop)


class _Run:
    def __init__(self, plan: BatchPlan, options: BatchOptions, executor: Executor, reporter: Reporter):
        self.plan, self.options, self.executor, self.reporter = plan, options, executor, reporter
        self.queue: deque[tuple[PhotoFiles, int]] = deque((pair, 1) for pair in plan.to_fit)
        self.running: dict[Any, tuple[PhotoFiles, int, float]] = {}  # handle -> (pair, attempt, started)
        self.fit_walls: list[float] = []
        self.header = {"photos": str(plan.photos), "out": str(plan.out), "settings": options.settings}
        self.catalogue_paths = self._write_catalogue()
        self._shown, self._shown_at = None, 0.0
        self.stopping = False

    def loop(self, should_stop) -> BatchSummary:
        for name, row in sorted(self.plan.rows.items()):
            if row["status"] in ("kept", "failed"):
                self.reporter.pair(name, row["status"], reason=row["reason"],
                                   out_dir=str(self.plan.out / name) if row["status"] == "kept" else None)
        self._progress(force=True)
        cancelled = False
        while self.queue or self.running:
            if should_stop():
                cancelled = self.stopping = True
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
        while self.queue and len(self.running) < self.options.workers:
            pair, attempt = self.queue.popleft()
            try:
                job = FitJob.of(pair, self.plan.out / pair.name, self.options.fit_options, self.options.rig_text,
                                self.options.threads, self.options.timeout_s)
            except OSError as exc:
                self._final(pair, "failed", attempt, reason=f"{exc.filename}: cannot read ({exc.strerror or exc})")
                continue
            self.running[self.executor.submit(job)] = (pair, attempt, time.monotonic())
            self.reporter.pair(pair.name, "started", attempt)

    def _finish(self, handle):
        pair, attempt, started = self.running.pop(handle)
        try:
            outcome = self.executor.outcome(handle)
        except TaskLost as exc:
            outcome = FitOutcome(pair.name, "lost", reason=str(exc))
        wall = time.monotonic() - started
        if outcome.log:
            output.write_log(self.plan.out, pair.name, attempt, outcome.log)
        if outcome.status == "done":
            try:
                folder = output.write_result(self.plan.out, pair.name, outcome.files)
                row = catalogue.fitted_row(pair.name, "done", folder, self.plan.out, reflection=pair.reflection,
                                           transmission=pair.transmission, attempts=attempt, wall_s=wall)
            except (OSError, catalogue.CatalogueError) as exc:
                self._final(pair, "failed", attempt, reason=f"results not saved: {exc}", wall_s=wall)
                return
            self.fit_walls.append(wall)
            self._final(pair, "done", attempt, row=row, wall_s=wall)
        elif self.stopping:
            self._final(pair, "cancelled" if outcome.status == "cancelled" else "failed", attempt,
                        reason=outcome.reason, wall_s=wall)
        elif outcome.status in RETRIED and attempt == 1:
            self.reporter.pair(pair.name, "retrying", attempt, reason=outcome.reason, wall_s=wall)
            self.queue.appendleft((pair, attempt + 1))
        else:
            self._final(pair, "failed", attempt, reason=outcome.reason, wall_s=wall)

    def _final(self, pair: PhotoFiles, status: str, attempt: int, reason: str | None = None,
               wall_s: float | None = None, row: dict | None = None):
        self.plan.rows[pair.name] = row or catalogue.row(pair.name, status, reflection=pair.reflection,
                                                         transmission=pair.transmission, attempts=attempt,
                                                         reason=reason, wall_s=wall_s)
        out_dir = str(self.plan.out / pair.name) if status == "done" else None
        self.reporter.pair(pair.name, status, attempt, reason=reason, out_dir=out_dir, wall_s=wall_s)
        self.catalogue_paths = self._write_catalogue()

    def _cancel(self):
        """Stops the running fits; those that finish within the grace time are kept."""
        for handle in self.running:
            self.executor.cancel(handle)
        deadline = time.monotonic() + self.options.cancel_grace_s
        while self.running and time.monotonic() < deadline:
            for handle in self.executor.wait(list(self.running), POLL_S):
                self._finish(handle)
        for pair, attempt, started in self.running.values():
            self._final(pair, "cancelled", attempt, reason="still running when the batch was stopped",
                        wall_s=time.monotonic() - started)
        self.running.clear()
        while self.queue:
            pair, attempt = self.queue.popleft()
            self._final(pair, "cancelled", attempt - 1, reason="not started: the batch was stopped")

    # -- reporting ---------------------------------------------------------------------------------

    def _write_catalogue(self) -> tuple[Path, Path]:
        return catalogue.write(self.plan.out, list(self.plan.rows.values()), self.header)

    def counts(self) -> dict:
        rows = self.plan.rows.values()
        return {"total": len(self.plan.rows), "done": sum(r["status"] in ("done", "kept") for r in rows),
                "running": len(self.running), "failed": sum(r["status"] == "failed" for r in rows),
                "queued": len(self.queue)}

    def eta_s(self) -> float | None:
        if not self.fit_walls:
            return None
        mean = sum(self.fit_walls) / len(self.fit_walls)
        now = time.monotonic()
        left = len(self.queue) * mean + sum(max(mean - (now - started), 0.0) for _, _, started in
                                            self.running.values())
        return left / max(1, min(self.options.workers, len(self.queue) + len(self.running)))

    def _progress(self, force: bool = False):
        counts = self.counts()
        now = time.monotonic()
        if force or counts != self._shown or now - self._shown_at >= PROGRESS_EVERY_S:
            self.reporter.batch(**counts, eta_s=self.eta_s())
            self._shown, self._shown_at = counts, now
