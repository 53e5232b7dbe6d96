"""Batch fitting from the sidebar: pick a folder, its photo pairs are fitted in the background.

``fabric.batch_fit_folder`` asks for a folder, then runs core/batch_queue.BatchQueue: one backend
subprocess per pair, one after another, polled from a window-manager timer, so Blender stays
responsive. Each fitted pair becomes an asset material in this file (scene/materials.py, as a
single fit does), with the panel's rig, weave and fit settings. The Batch panel shows a row per
pair (waiting, a progress bar while it runs, its material, or why it failed) and a Cancel button;
ESC cancels too. Loading another file or disabling the add-on stops the running fit.
The headless batch (``blender --command fabric_fit``) is ui/batch.py.
"""
from __future__ import annotations

import time

import bpy

from ..core import backend_bridge, batch, batch_queue, rig_settings
from ..scene import materials
from . import panels, preferences, properties

TIMER_INTERVAL_S = 0.2
STATE_ICONS = {batch_queue.WAITING: "TIME", batch_queue.RUNNING: "PLAY", batch_queue.DONE: "CHECKMARK",
               batch_queue.FAILED: "ERROR", batch_queue.CANCELLED: "CANCEL"}


class ActiveBatch:
    """The last batch of this session: its rows stay in the panel after it ends."""

    queue: batch_queue.BatchQueue | None = None

    @classmethod
    def running(cls) -> bool:
        return cls.queue is not None and not cls.queue.done

    @classmethod
    def cancel(cls, wait: bool = False) -> None:
        if cls.running():
            cls.queue.cancel(wait=wait)


def new_batch(context, folder: str) -> batch_queue.BatchQueue:
    """A batch of ``folder`` with the panel's rig and fit settings (not started)."""
    settings = context.scene.woven_fabric
    rig = rig_settings.rig_dict(properties.rig_values(settings.rig))
    width = settings.rig.width_cm or None

    def make_material(job, params, description, preview):
        return materials.new_fit_material(job.name, params, width, job.out_dir, description, preview).name

    options = batch.BatchOptions(pattern=settings.pattern, iterations=settings.iterations or None,
                                 size=settings.size or None, device=preferences.selected_device(context))
    return batch_queue.BatchQueue(bpy.path.abspath(folder), preferences.selected_backend(context),
                                  preferences.results_parent(context), rig, make_material, options)


def _redraw(context):
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


class FABRIC_OT_batch_fit_folder(bpy.types.Operator):
    """Fit every <name>_R / <name>_T photo pair of a folder in the background; each becomes an asset
    material (ESC or Cancel stops)"""

    bl_idname = "fabric.batch_fit_folder"
    bl_label = "Fit Folder"

    directory: bpy.props.StringProperty(subtype="DIR_PATH", name="Photos")

    _timer = None

    @classmethod
    def poll(cls, context):
        return not ActiveBatch.running() and context.scene is not None

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        try:
            queue = new_batch(context, self.directory)
        except (backend_bridge.BackendError, ValueError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        ActiveBatch.queue = queue.start()
        if bpy.app.background or context.window is None:
            # No event loop runs timers here: wait (the headless command is the batch tool there).
            while not queue.done:
                queue.poll()
                time.sleep(TIMER_INTERVAL_S)
            return self._finish(queue)
        wm = context.window_manager
        self._timer = wm.event_timer_add(TIMER_INTERVAL_S, window=context.window)
        wm.modal_handler_add(self)
        self.report({"INFO"}, f"Fitting {len(queue.jobs)} pair(s) from {queue.folder} in the background")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        queue = ActiveBatch.queue
        if queue is None:
            return self._end(context, {"CANCELLED"})
        if event.type == "ESC" and event.value == "PRESS":
            queue.cancel()
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if queue.poll():
            _redraw(context)
        if not queue.done:
            return {"PASS_THROUGH"}
        return self._end(context, self._finish(queue))

    def _finish(self, queue) -> set:
        for job in queue.failures():
            self.report({"WARNING"}, f"{job.name}: {job.reason}")
        self.report({"INFO"}, f"Batch of {queue.folder}: {queue.summary()}")
        return {"FINISHED"} if not queue.cancelled else {"CANCELLED"}

    def _end(self, context, result):
        if self._timer is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None
        _redraw(context)
        return result

    def cancel(self, context):
        ActiveBatch.cancel(wait=True)
        self._end(context, {"CANCELLED"})


class FABRIC_OT_cancel_batch(bpy.types.Operator):
    """Stop the batch: the running fit is cancelled, the waiting pairs are not fitted"""

    bl_idname = "fabric.cancel_batch"
    bl_label = "Cancel Batch"

    @classmethod
    def poll(cls, context):
        return ActiveBatch.running()

    def execute(self, context):
        ActiveBatch.cancel()
        return {"FINISHED"}


class VIEW3D_PT_woven_fabric_batch(panels.FabricSubPanel, bpy.types.Panel):
    bl_label = "Batch"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        queue = ActiveBatch.queue
        row = layout.row(align=True)
        row.operator("fabric.batch_fit_folder", icon="FILE_FOLDER")
        if ActiveBatch.running():
            row.operator("fabric.cancel_batch", text="", icon="CANCEL")
        if queue is None:
            layout.label(text="Uses the rig, weave and fit settings above")
            return
        layout.progress(factor=queue.progress, text=queue.summary(), type="BAR")
        column = layout.column(align=True)
        for job in queue.jobs:
            row = column.row()
            row.label(text=job.name, icon=STATE_ICONS[job.state])
            if job.state == batch_queue.RUNNING:
                row.progress(factor=job.progress, text=job.status, type="BAR")
            else:
                row.label(text=job.status)
        failures = queue.failures()
        if failures:
            box = layout.box()
            box.label(text="Failed:", icon="ERROR")
            for job in failures:
                box.label(text=f"{job.name}: {job.reason}")


@bpy.app.handlers.persistent
def _cancel_on_load(*_args):
    ActiveBatch.cancel(wait=True)


CLASSES = (FABRIC_OT_batch_fit_folder, FABRIC_OT_cancel_batch, VIEW3D_PT_woven_fabric_batch)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.app.handlers.load_pre.append(_cancel_on_load)


def unregister():
    ActiveBatch.cancel(wait=True)
    if _cancel_on_load in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_cancel_on_load)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
