"""The add-on's batch executor (no bpy): a folder's photo pairs fitted one after another in backend
subprocesses, advanced by :meth:`BatchQueue.poll` without ever blocking (from a timer in Blender,
in a loop by the headless batch, core/batch.py).

The jobs, their states and the rules are the backend's job model (core/pair_jobs.py, read through
declarations.pair_jobs): a pending job per ``<name>_R.* / <name>_T.*`` pair, a failed one per name
without its partner, one attempt each (the fit runs on this machine: what fails once fails again).
Each fit runs through captures.new_fit (a new result folder, the rig's ``rig.json``,
``backend.log``) as the panel's Fit does. When a fit succeeds the queue calls ``on_fitted(job,
params, description, preview)``, which makes the material and returns its name; an exception
there fails that pair only.

Each job (:class:`QueuedPair`) adds what the Batch panel shows: a progress fraction, a status line,
the material and the result folder. :meth:`BatchQueue.request_cancel` asks the running fit to stop
(the stop line, then SIGKILL, see backend_bridge) and cancels the pairs still waiting;
:meth:`BatchQueue.cancel` also waits until the fit has ended.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from . import backend_bridge, captures, declarations

_model = declarations.pair_jobs()
PENDING, RUNNING, DONE, FAILED, CANCELLED = (_model.PENDING, _model.RUNNING, _model.DONE, _model.FAILED,
                                             _model.CANCELLED)


@dataclass
class BatchOptions:
    """A batch's settings: ``fit``, every pair's fit options (backend_bridge.FitRequest's fields, checked
    by the backend's declaration before the first fit: :meth:`BatchQueue.start`), and the batch's own."""

    fit: dict = field(default_factory=dict)
    rig_json: Path | None = None     # the rig's settings for every pair (each fit gets its own rig.json)
    width_cm: float | None = None
    timeout_s: float | None = None
    overwrite: bool = False          # the library file's, not the fits'


@dataclass
class QueuedPair(_model.PairJob):
    """A pair's job with what the panel shows of it."""

    progress: float = 0.0
    status: str = "Waiting"
    material: str = ""
    out_dir: str = ""


def folder_pairs(folder: str | Path) -> list[QueuedPair]:
    """The jobs of ``folder`` (the job model's); ValueError when it is not a folder or holds no pairs."""
    jobs = _model.folder_jobs(folder, QueuedPair)
    for job in jobs:
        if job.state == FAILED:
            job.status = "Skipped"
    return jobs


def fitted_asset(job: QueuedPair, result: dict) -> tuple[dict, str, Path]:
    """(params, asset description, preview image) of a pair's successful fit (its ``result`` event)."""
    params = captures.read_fit_params(result)
    preview = Path((result.get("files") or {}).get("reflection") or job.reflection)
    description = (f"Woven fabric fitted from {job.reflection.name} and {job.transmission.name} "
                   f"({job.out_dir})")
    return params, description, preview


class BatchQueue:
    """Fits every pair of ``folder`` in turn; call :meth:`start`, then :meth:`poll` until ``done``.

    ``on_event(job, event)`` sees the running fit's protocol events, ``on_end(job, fit)`` each job
    that ended (``fit`` None when none started)."""

    def __init__(self, folder: str | Path, backend: backend_bridge.Backend, results_parent: str | Path, rig: dict,
                 on_fitted: Callable[[QueuedPair, dict, str, Path], str], options: BatchOptions | None = None, *,
                 jobs: list[QueuedPair] | None = None, on_event=None, on_end=None):
        self.folder = Path(folder)
        self.pairs = _model.PairJobs(folder_pairs(self.folder) if jobs is None else jobs)
        self.backend, self.results_parent, self.rig = backend, Path(results_parent), rig
        self.on_fitted, self.options = on_fitted, options or BatchOptions()
        self.on_event, self.on_end = on_event or (lambda job, event: None), on_end or (lambda job, fit: None)
        self.fit: backend_bridge.FitProcess | None = None
        self._current: QueuedPair | None = None
        self._started_at = 0.0

    # -- state --------------------------------------------------------------------------------
    @property
    def jobs(self) -> list[QueuedPair]:
        return self.pairs.jobs

    @property
    def cancelled(self) -> bool:
        return self.pairs.stopping

    @property
    def done(self) -> bool:
        return self.pairs.finished

    @property
    def progress(self) -> float:
        """Overall progress: finished pairs count 1, the running one its fraction."""
        fittable = [job for job in self.jobs if job.reflection is not None]
        if not fittable:
            return 1.0
        return sum(1.0 if job.finished else job.progress for job in fittable) / len(fittable)

    def failures(self) -> list[QueuedPair]:
        return self.pairs.failures()

    def summary(self) -> str:
        text = f"{self.pairs.count(DONE)} fitted, {self.pairs.count(FAILED)} failed"
        cancelled = self.pairs.count(CANCELLED)
        return text + (f", {cancelled} cancelled" if cancelled else "")

    # -- running ------------------------------------------------------------------------------
    def start(self) -> BatchQueue:
        """Starts the first fit; BackendError (the declaration's message) for fit options the backend
        would refuse, before any fit."""
        captures.check_fit_options(self.options.fit)
        self._next()
        return self

    def poll(self) -> bool:
        """Reads the running fit's progress, finishes it and starts the next; never blocks.
        Returns True when something the panel shows changed."""
        job, fit = self._current, self.fit
        if job is None or fit is None:
            return False
        before = (job.progress, job.status)
        limit = self.options.timeout_s
        if limit is not None and time.monotonic() - self._started_at > limit:
            fit.time_out(limit)
        for event in fit.poll():
            self.on_event(job, event)
        job.progress, job.status = fit.progress, fit.status
        if not fit.done:
            return (job.progress, job.status) != before
        self._finish(job, fit)
        self._next()
        return True

    def request_cancel(self) -> None:
        """Asks the running fit to stop and cancels the waiting pairs; returns at once."""
        for job in self.pairs.stop():
            job.status = "Cancelled"
        if self.fit is not None and not self.fit.done:
            self.fit.request_cancel()

    def cancel(self) -> None:
        """Cancels and waits until the running fit's process is gone."""
        self.request_cancel()
        if self.fit is not None and not self.fit.done:
            self.fit.cancel()
            self.poll()

    def _next(self) -> None:
        self._current, self.fit = None, None
        job = self.pairs.start_next()
        if job is None:
            return
        job.status = "Starting the backend"
        self._started_at = time.monotonic()
        try:
            fit = captures.new_fit(self.backend, job.reflection, job.transmission, self.results_parent, job.name,
                                   self.rig, **self.options.fit).start()
        except Exception as exc:  # one pair's trouble never stops the batch
            self._end(job, None, _model.INTERNAL, str(exc) or type(exc).__name__)
            self._next()
            return
        job.out_dir = str(fit.request.out_dir)
        if fit.done:  # could not even start
            self._end(job, fit, fit.outcome, fit.error)
            self._next()
            return
        self._current, self.fit = job, fit

    def _finish(self, job: QueuedPair, fit: backend_bridge.FitProcess) -> None:
        if fit.outcome != DONE:
            self._end(job, fit, fit.outcome, fit.error or f"fit {fit.state}")
            return
        try:
            params, description, preview = fitted_asset(job, fit.result)
            job.material = self.on_fitted(job, params, description, preview)
        except Exception as exc:  # the fit is on disk; this pair alone fails, with the reason
            job.end(FAILED, f"the fit finished in {job.out_dir} but could not become a material: {exc}")
            self._end(job, fit)
            return
        self._end(job, fit, DONE)

    def _end(self, job: QueuedPair, fit, outcome: str | None = None, reason: str | None = None) -> None:
        """Applies the job model's rule to an attempt's outcome (none: the job has ended already)."""
        if outcome is not None:
            self.pairs.end(job, outcome, reason or "unknown error")
        job.status = {DONE: f"Material {job.material}", CANCELLED: "Cancelled"}.get(job.state, "Failed")
        if job.state == DONE:
            job.progress = 1.0
        self.on_end(job, fit)
