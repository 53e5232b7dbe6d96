"""The one shape of a job that runs beside Blender: a fit, the sidebar batch, the GPU PyTorch install.

A *job* is a plain object from core/ (no bpy) with ``poll()`` (never blocks), ``done``,
``request_cancel()`` (returns at once) and ``cancel()`` (waits until it has stopped):
backend_bridge.FitProcess, batch_queue.BatchQueue, gpu_env.TorchInstall. An :class:`ActiveJob`
holds the one job of a kind that may run, so that its Cancel button, its panel and the handlers
reach it; loading another file or disabling the add-on cancels it, unless it survives the file
(the GPU install: it changes no scene).

:class:`ModalJobOperator` is the operator that runs one. ``execute`` starts the job
(:meth:`~ModalJobOperator.start_job`, the subclass's), then a window-manager timer follows it every
``timer_interval_s``: each tick polls it (:meth:`~ModalJobOperator.follow_job`) and passes every
other event on, so Blender stays responsive; ESC asks the job to stop; once it is done
:meth:`~ModalJobOperator.finish_job` (the subclass's) says what becomes of the result. Without an
event loop (background mode, a script without a window) execute follows the job until it ends
instead. :func:`draw_progress` and :func:`draw_error` draw the running job's progress bar with its
Cancel button and a failed job's message with the button that opens its log.
"""
from __future__ import annotations

import time
from pathlib import Path

import bpy

from . import layout


class ActiveJob:
    """The one job of a kind that may run at a time (the last one stays, for its panel)."""

    instances: list[ActiveJob] = []

    def __init__(self, survives_file: bool = False):
        self.job = None
        self.survives_file = survives_file
        ActiveJob.instances.append(self)

    def running(self) -> bool:
        return self.job is not None and not self.job.done

    @property
    def current(self):
        """The job while it runs, else None."""
        return self.job if self.running() else None

    def cancel(self, wait: bool = False) -> None:
        if self.running():
            self.job.cancel() if wait else self.job.request_cancel()


class ModalJobOperator:
    """A mix-in for a bpy.types.Operator that runs a job beside Blender (see the module docstring).

    A subclass sets ``active`` (its ActiveJob) and says what it starts (:meth:`start_job`) and what
    it does with the result (:meth:`finish_job`); :meth:`follow_job` and :meth:`started` are optional.
    """

    active: ActiveJob
    timer_interval_s = 0.1
    redraw_area = "VIEW_3D"
    _timer = None

    @classmethod
    def poll(cls, context):
        return not cls.active.running()

    # -- what a subclass says -----------------------------------------------------------------
    def start_job(self, context):
        """Starts the job and returns it, or reports why it cannot start and returns None."""
        raise NotImplementedError

    def follow_job(self, context, job) -> bool:
        """One tick: polls the job; True when what its panel shows has changed."""
        job.poll()
        return True

    def started(self, context, job) -> None:
        """Called once the job runs beside Blender (not when execute waits for it)."""

    def finish_job(self, context, job) -> set:
        """Makes something of the ended job (reports, a material) and returns the operator's result."""
        raise NotImplementedError

    # -- the operator -------------------------------------------------------------------------
    def execute(self, context):
        job = self.start_job(context)
        if job is None:
            return {"CANCELLED"}
        self.active.job = job
        if bpy.app.background or context.window is None:
            # No event loop runs timers here: follow the job until it ends.
            while not job.done:
                self.follow_job(context, job)
                if not job.done:
                    time.sleep(self.timer_interval_s)
            return self.finish_job(context, job)
        wm = context.window_manager
        self._timer = wm.event_timer_add(self.timer_interval_s, window=context.window)
        wm.modal_handler_add(self)
        self.started(context, job)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        job = self.active.job
        if job is None:
            return self._end(context, {"CANCELLED"})
        if event.type == "ESC" and event.value == "PRESS":
            job.request_cancel()
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self.follow_job(context, job):
            layout.redraw_areas(self.redraw_area)
        if not job.done:
            return {"PASS_THROUGH"}
        return self._end(context, self.finish_job(context, job))

    def cancel(self, context):
        # Blender ends modal operators without asking when a file is loaded or the window closes.
        self.active.cancel(wait=True)
        self._end(context, {"CANCELLED"})

    def _end(self, context, result: set) -> set:
        if self._timer is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None
        layout.redraw_areas(self.redraw_area)
        return result


def draw_progress(layout_, factor: float, text: str, cancel_operator: str):
    """A running job's progress bar with its Cancel button; returns the row."""
    row = layout_.row(align=True)
    row.progress(factor=factor, text=text, type="BAR")
    row.operator(cancel_operator, text="", icon="CANCEL")
    return row


def draw_error(layout_, message: str, context, log_path: Path | None = None):
    """A failed job's message, wrapped, and a button that opens its log when there is one."""
    layout.wrapped_labels(layout_, message, context, icon="ERROR")
    if log_path is not None and log_path.is_file():
        layout_.operator("fabric.open_fit_log", icon="TEXT").filepath = str(log_path)


@bpy.app.handlers.persistent
def _cancel_on_load(*_args):
    """A job that reads into the old file's scene is stopped before another file replaces that scene."""
    for active in ActiveJob.instances:
        if not active.survives_file:
            active.cancel(wait=True)


def register():
    bpy.app.handlers.load_pre.append(_cancel_on_load)


def unregister():
    """Stops every job: those of the file wait until they have ended, the others are asked to stop."""
    for active in ActiveJob.instances:
        active.cancel(wait=not active.survives_file)
    if _cancel_on_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_cancel_on_load)
