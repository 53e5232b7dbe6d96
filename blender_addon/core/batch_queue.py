"""The batch fit without blocking (no bpy): a folder's photo pairs fitted one after another in
backend subprocesses, advanced by :meth:`BatchQueue.poll` from a timer.

The pairs come from the backend's one ``<name>_R.* / <name>_T.*`` rule (declarations.find_pairs);
a pair with a missing partner is listed as failed at once, with the reason. Each fit runs through
captures.new_fit (a new result folder, the rig's ``rig.json``, ``backend.log``) exactly as the
headless batch (core/batch.py) and the panel's Fit do. When a fit succeeds the queue calls
``on_fitted(job, params, description, preview)``, which makes the material (the bpy layer) and
returns its name; an exception there fails that pair only.

Each pair is a :class:`PairJob` with a state (waiting, running, done, failed, cancelled), a
progress fraction, a status line and, for a failure, the reason: the rows the panel shows.
:meth:`BatchQueue.cancel` stops the running fit (SIGTERM, then SIGKILL, see backend_bridge) and
marks the pairs still waiting as cancelled.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from . import backend_bridge, batch, captures, declarations

WAITING, RUNNING, DONE, FAILED, CANCELLED = "waiting", "running", "done", "failed", "cancelled"


@dataclass
class PairJob:
    name: str
    reflection: Path | None
    transmission: Path | None
    state: str = WAITING
    progress: float = 0.0
    status: str = "Waiting"
    reason: str = ""
    material: str = ""
    out_dir: str = ""


class BatchQueue:
    """Fits every pair of ``folder`` in turn; call :meth:`start`, then :meth:`poll` until ``done``."""

    def __init__(self, folder: str | Path, backend: backend_bridge.Backend, results_parent: str | Path, rig: dict,
                 on_fitted: Callable[[PairJob, dict, str, Path], str],
                 options: batch.BatchOptions | None = None):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise ValueError(f"{folder}: not a folder")
        self.backend, self.results_parent, self.rig = backend, Path(results_parent), rig
        self.on_fitted, self.options = on_fitted, options or batch.BatchOptions()
        pairs, problems = declarations.find_pairs(self.folder)
        if not pairs and not problems:
            raise ValueError(f"{self.folder}: no <name>_R.* / <name>_T.* photo pairs")
        self._pairs = {pair.name: pair for pair in pairs}
        self.jobs = [PairJob(pair.name, pair.reflection, pair.transmission) for pair in pairs]
        self.jobs += [PairJob(problem.name, None, None, FAILED, 0.0, "Skipped", problem.message)
                      for problem in problems]
        self.fit: backend_bridge.FitProcess | None = None
        self._current: PairJob | None = None
        self.cancelled = False

    # -- state --------------------------------------------------------------------------------
    @property
    def done(self) -> bool:
        return self._current is None and not any(job.state == WAITING for job in self.jobs)

    @property
    def progress(self) -> float:
        """Overall progress: finished pairs count 1, the running one its fraction."""
        fittable = [job for job in self.jobs if job.reflection is not None]
        if not fittable:
            return 1.0
        return sum(1.0 if job.state in (DONE, FAILED, CANCELLED) else job.progress for job in fittable) / len(fittable)

    def failures(self) -> list[PairJob]:
        return [job for job in self.jobs if job.state == FAILED]

    def summary(self) -> str:
        counts = {state: sum(job.state == state for job in self.jobs) for state in (DONE, FAILED, CANCELLED)}
        text = f"{counts[DONE]} fitted, {counts[FAILED]} failed"
        return text + (f", {counts[CANCELLED]} cancelled" if counts[CANCELLED] else "")

    # -- running ------------------------------------------------------------------------------
    def start(self) -> "BatchQueue":
        self._next()
        return self

    def poll(self) -> bool:
        """Reads the running fit's progress, finishes it and starts the next; never blocks.
        Returns True when something the panel shows changed."""
        job, fit = self._current, self.fit
        if job is None or fit is None:
            return False
        before = (job.progress, job.status)
        fit.poll()
        job.progress, job.status = fit.progress, fit.status
        if not fit.done:
            return (job.progress, job.status) != before
        self._finish(job, fit)
        self._next()
        return True

    def cancel(self, wait: bool = False) -> None:
        """Stops the running fit and cancels the waiting pairs (``wait``: until the process is gone)."""
        self.cancelled = True
        for job in self.jobs:
            if job.state == WAITING:
                job.state, job.status = CANCELLED, "Cancelled"
        if self.fit is not None and not self.fit.done:
            self.fit.cancel() if wait else self.fit.request_cancel()
            if wait:
                self.poll()

    def _next(self) -> None:
        self._current, self.fit = None, None
        if self.cancelled:
            return
        job = next((job for job in self.jobs if job.state == WAITING), None)
        if job is None:
            return
        job.state, job.status = RUNNING, "Starting the backend"
        try:
            fit = captures.new_fit(self.backend, job.reflection, job.transmission, self.results_parent, job.name,
                                   self.rig, pattern=self.options.pattern, iterations=self.options.iterations,
                                   size=self.options.size, device=self.options.device,
                                   output_spp=self.options.output_spp).start()
        except (backend_bridge.BackendError, OSError, ValueError) as exc:
            self._fail(job, str(exc))
            self._next()
            return
        job.out_dir = str(fit.request.out_dir)
        if fit.done:  # could not even start
            self._fail(job, fit.error)
            self._next()
            return
        self._current, self.fit = job, fit

    def _finish(self, job: PairJob, fit: backend_bridge.FitProcess) -> None:
        if fit.state == backend_bridge.CANCELLED:
            job.state, job.status = CANCELLED, "Cancelled"
            return
        if fit.state != backend_bridge.SUCCEEDED:
            self._fail(job, fit.error or f"fit {fit.state}")
            return
        try:
            params, description, preview = batch.fitted_asset(self._pairs[job.name], fit.result, Path(job.out_dir))
            job.material = self.on_fitted(job, params, description, preview)
        except Exception as exc:  # the fit is on disk; this pair alone fails, with the reason
            self._fail(job, f"the fit finished in {job.out_dir} but could not become a material: {exc}")
            return
        job.state, job.progress, job.status = DONE, 1.0, f"Material {job.material}"

    @staticmethod
    def _fail(job: PairJob, reason: str) -> None:
        job.state, job.status, job.reason = FAILED, "Failed", reason or "unknown error"

