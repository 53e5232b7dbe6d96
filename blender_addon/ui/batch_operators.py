"""Batch fitting from the sidebar: pick a folder, its photo pairs are fitted in the background.

``fabric.batch_fit_folder`` asks for a folder, then runs core/batch_queue.BatchQueue as a modal
job (modal_job.py): one backend subprocess per pair, one after another, polled from a timer, so
Blender stays responsive. Each fitted pair becomes an asset material in this file
(scene/materials.py, as a single fit does), with the panel's rig, weave and fit settings. The
Batch panel shows a row per pair (waiting, a progress bar while it runs, its material, or why it
failed) and a Cancel button; ESC cancels too. Loading another file or disabling the add-on stops the running fit.
The headless batch (``blender --command fabric_fit``) is ui/batch.py.
"""
from __future__ import annotations

import bpy

from ..core import backend_bridge, batch_queue, rig_settings
from ..scene import materials
from . import modal_job, panels, preferences, properties

STATE_ICONS = {batch_queue.PENDING: "TIME", batch_queue.RUNNING: "PLAY", batch_queue.DONE: "CHECKMARK",
               batch_queue.FAILED: "ERROR", batch_queue.CANCELLED: "CANCEL"}

batch_job = modal_job.ActiveJob()  # the last batch of this session: its rows stay in the panel after it ends


def new_batch(context, folder: str) -> batch_queue.BatchQueue:
    """A batch of ``folder`` with the panel's rig and fit settings (not started)."""
    settings = context.scene.woven_fabric
    rig = rig_settings.rig_dict(properties.rig_values(settings.rig))
    width = settings.rig.width_cm or None

    def make_material(job, params, description, preview):
        return materials.new_fit_material(job.name, params, width, job.out_dir, description, preview).name

    options = batch_queue.BatchOptions(properties.fit_options(settings, preferences.selected_device(context)))
    return batch_queue.BatchQueue(bpy.path.abspath(folder), preferences.selected_backend(context),
                                  preferences.results_parent(context), rig, make_material, options)


class FABRIC_OT_batch_fit_folder(modal_job.ModalJobOperator, bpy.types.Operator):
    """Fit every <name>_R / <name>_T photo pair of a folder in the background; each becomes an asset
    material (ESC or Cancel stops)"""

    bl_idname = "fabric.batch_fit_folder"
    bl_label = "Fit Folder"

    directory: bpy.props.StringProperty(subtype="DIR_PATH", name="Photos")

    active = batch_job
    timer_interval_s = 0.2

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.scene is not None

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def start_job(self, context):
        try:
            return new_batch(context, self.directory).start()
        except (backend_bridge.BackendError, ValueError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return None

    def follow_job(self, context, queue) -> bool:
        return queue.poll()

    def started(self, context, queue):
        self.report({"INFO"}, f"Fitting {len(queue.jobs)} pair(s) from {queue.folder} in the background")

    def finish_job(self, context, queue) -> set:
        for job in queue.failures():
            self.report({"WARNING"}, f"{job.name}: {job.reason}")
        self.report({"INFO"}, f"Batch of {queue.folder}: {queue.summary()}")
        return {"FINISHED"} if not queue.cancelled else {"CANCELLED"}


class FABRIC_OT_cancel_batch(bpy.types.Operator):
    """Stop the batch: the running fit is cancelled, the waiting pairs are not fitted"""

    bl_idname = "fabric.cancel_batch"
    bl_label = "Cancel Batch"

    @classmethod
    def poll(cls, context):
        return batch_job.running()

    def execute(self, context):
        batch_job.cancel()
        return {"FINISHED"}


class VIEW3D_PT_woven_fabric_batch(panels.FabricSubPanel, bpy.types.Panel):
    bl_label = "Batch"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        queue = batch_job.job
        row = layout.row(align=True)
        row.operator("fabric.batch_fit_folder", icon="FILE_FOLDER")
        if batch_job.running():
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


CLASSES = (FABRIC_OT_batch_fit_folder, FABRIC_OT_cancel_batch, VIEW3D_PT_woven_fabric_batch)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
