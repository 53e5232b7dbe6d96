"""The Fabric tab of the 3D Viewport's sidebar: capture setup, rig, fit with progress, result.

Photo previews come from a ``bpy.utils.previews`` collection (loaded from the file, keyed by path
and modification time), so looking at a photo adds no image to the user's file.
"""
from __future__ import annotations

import os

import bpy
import bpy.utils.previews

from ..core import backend_bridge, declarations, rig_settings
from . import modal_job, operators, preferences
from .layout import wrapped_labels

_previews = None


def photo_icon(path: str) -> int:
    """Icon id of a photo's preview, 0 when there is none (missing file, RAW photo)."""
    if _previews is None or not path:
        return 0
    filepath = bpy.path.abspath(path)
    if not os.path.isfile(filepath) or declarations.is_raw(os.path.splitext(filepath)[1]):
        return 0
    key = f"{filepath}:{os.path.getmtime(filepath)}"
    if key not in _previews:
        _previews.load(key, filepath, "IMAGE")
    return _previews[key].icon_id


def _property_style(layout):
    """Labels left of the values, no animation decorators: how the sidebar shows settings."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    return layout


class FabricPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Fabric"


class FabricSubPanel(FabricPanel):
    bl_parent_id = "VIEW3D_PT_woven_fabric"


class VIEW3D_PT_woven_fabric(FabricPanel, bpy.types.Panel):
    bl_label = "Woven Fabric"

    def draw(self, context):
        settings = context.scene.woven_fabric
        layout = _property_style(self.layout)
        for prop in ("reflection_path", "transmission_path"):
            layout.prop(settings, prop)
            icon = photo_icon(getattr(settings, prop))
            if icon:
                layout.template_icon(icon_value=icon, scale=5.0)
        layout.prop(settings.rig, "width_cm")
        layout.prop(settings, "pattern")


class VIEW3D_PT_woven_fabric_rig(FabricSubPanel, bpy.types.Panel):
    bl_label = "Capture Rig"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        rig = context.scene.woven_fabric.rig
        layout = _property_style(self.layout)
        for field in rig_settings.rig_fields():
            if field.name != "width_cm":
                layout.prop(rig, field.name)
        layout.operator("fabric.reset_rig", icon="LOOP_BACK")


class VIEW3D_PT_woven_fabric_fit(FabricSubPanel, bpy.types.Panel):
    bl_label = "Fit"

    def draw(self, context):
        settings = context.scene.woven_fabric
        layout = self.layout
        fit = operators.fit_job.current
        column = _property_style(layout.column())
        column.enabled = fit is None
        for prop in ("iterations", "size", "material_name", "update_active_material", "refuse_swapped"):
            column.prop(settings, prop)
        if fit is not None:
            modal_job.draw_progress(layout, settings.fit_progress, settings.fit_status, "fabric.cancel_fit")
            layout.label(text="ESC or the button cancels", icon="INFO")
            _draw_warnings(layout, fit.warnings, context)
            return
        layout.operator("fabric.fit", icon="PLAY")
        wrapped_labels(layout, f"Fits go to {preferences.results_parent(context)}", context, icon="FILE_FOLDER")
        last = operators.fit_job.job
        if last is not None and last.refused_swapped:
            _draw_swapped(layout.box(), settings, last.error, context)
        elif last is not None and last.state == backend_bridge.FAILED:
            modal_job.draw_error(layout.box(), last.error, context, last.log_path)
        elif settings.fit_status:
            wrapped_labels(layout, settings.fit_status, context)
        if last is not None:
            _draw_warnings(layout, last.warnings, context)


def _draw_swapped(box, settings, message: str, context):
    """Photos refused as swapped: the message, both photos side by side, and what to do."""
    wrapped_labels(box, message, context, icon="ERROR")
    row = box.row()
    for prop, question in (("reflection_path", "Reflection: lit from the front?"),
                           ("transmission_path", "Transmission: lit from behind?")):
        column = row.column()
        column.label(text=question)
        icon = photo_icon(getattr(settings, prop))
        if icon:
            column.template_icon(icon_value=icon, scale=5.0)
        column.label(text=os.path.basename(bpy.path.abspath(getattr(settings, prop))))
    row = box.row(align=True)
    row.operator("fabric.swap_photos", icon="ARROW_LEFTRIGHT")
    row.operator("fabric.fit", text="Fit As Given", icon="PLAY").as_given = True


def _draw_warnings(layout, warnings: list[str], context):
    """The fit's warnings (its backend.log holds them too), each wrapped."""
    if warnings:
        box = layout.box()
        for warning in warnings:
            wrapped_labels(box, warning, context, icon="ERROR")


class VIEW3D_PT_woven_fabric_result(FabricSubPanel, bpy.types.Panel):
    bl_label = "Result"

    def draw(self, context):
        settings = context.scene.woven_fabric
        layout = self.layout
        material = bpy.data.materials.get(settings.last_material)
        if material is not None:
            layout.label(text=material.name, icon="MATERIAL")
        else:
            layout.label(text="No fitted material yet")
        layout.operator("fabric.assign_material", icon="MATERIAL_DATA")
        layout.operator("fabric.add_drape_preview", icon="MOD_CLOTH")
        row = layout.row(align=True)
        row.operator("fabric.open_results", icon="FILE_FOLDER")
        row.operator("fabric.load_fit", icon="IMPORT")


CLASSES = (VIEW3D_PT_woven_fabric, VIEW3D_PT_woven_fabric_rig, VIEW3D_PT_woven_fabric_fit,
           VIEW3D_PT_woven_fabric_result)


def register():
    global _previews
    _previews = bpy.utils.previews.new()
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    global _previews
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
    if _previews is not None:
        bpy.utils.previews.remove(_previews)
        _previews = None
