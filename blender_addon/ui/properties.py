"""Scene settings of a capture (``scene.woven_fabric``): the photos, the rig, the fit and its state.

The rig's properties are generated from ``CaptureRig`` in backend/core/rig.py (captures.rig_fields),
so the panel shows the spec's defaults and follows any new rig setting.
"""
from __future__ import annotations

import bpy

from ..core import backend_bridge, captures

PATTERN_ITEMS = (
    ("auto", "Automatic", "Let the fit choose the weave"),
    ("plain", "Plain", "Plain weave"),
    ("twill0", "Twill 0", "Twill weave, first variant"),
    ("twill1", "Twill 1", "Twill weave, second variant"),
    ("satin0", "Satin 0", "Satin weave, first variant"),
    ("satin1", "Satin 1", "Satin weave, second variant"),
)
assert tuple(item[0] for item in PATTERN_ITEMS) == backend_bridge.PATTERNS


def _rig_property(field: captures.RigField):
    common = {"name": field.label, "description": field.description, "default": field.default}
    if field.kind == "vector":
        return bpy.props.FloatVectorProperty(size=3, subtype="XYZ", **common)
    if field.kind == "int":
        return bpy.props.IntProperty(min=16, soft_max=4096, **common)
    lower = {"glow_strength": 0.0, "width_cm": 0.0}.get(field.name, 1e-4)
    return bpy.props.FloatProperty(min=lower, **common)


def _rig_settings_class():
    annotations = {field.name: _rig_property(field) for field in captures.rig_fields()}
    return type("WovenFabricRigSettings", (bpy.types.PropertyGroup,), {
        "__annotations__": annotations,
        "__doc__": "The capture rig (spec section 1); the defaults are the paper's rig.",
    })


WovenFabricRigSettings = _rig_settings_class()


def rig_values(rig) -> dict:
    """The rig settings as plain values (tuples for vectors)."""
    return {field.name: (tuple(getattr(rig, field.name)) if field.kind == "vector" else getattr(rig, field.name))
            for field in captures.rig_fields()}


def _photos_changed(self, context):
    # The previews are keyed by path; nothing to do but redraw the sidebar.
    for area in getattr(context.screen, "areas", ()):
        if area.type == "VIEW_3D":
            area.tag_redraw()


class WovenFabricSettings(bpy.types.PropertyGroup):
    reflection_path: bpy.props.StringProperty(
        name="Reflection", subtype="FILE_PATH", update=_photos_changed,
        description="Photo of the fabric lit from the front (<name>_R)")
    transmission_path: bpy.props.StringProperty(
        name="Transmission", subtype="FILE_PATH", update=_photos_changed,
        description="Photo of the fabric lit from behind (<name>_T)")
    rig: bpy.props.PointerProperty(type=WovenFabricRigSettings)
    pattern: bpy.props.EnumProperty(name="Weave", items=PATTERN_ITEMS, default="auto")
    iterations: bpy.props.IntProperty(
        name="Iterations", default=0, min=0, soft_max=2000,
        description="Optimiser iterations; 0 uses the backend's default")
    size: bpy.props.IntProperty(
        name="Working Size", default=0, min=0, soft_max=1024,
        description="Side in pixels of the working images; 0 uses the backend's default")
    material_name: bpy.props.StringProperty(
        name="Material", description="Name of the new material; empty: the photo's name")
    update_active_material: bpy.props.BoolProperty(
        name="Update Active Material", default=False,
        description="Write the fit into the active object's Woven Fabric material instead of creating "
                    "a new material")

    # State of the last fit, for the panel (whether one runs now is operators.active_fit()).
    fit_progress: bpy.props.FloatProperty(name="Progress", subtype="FACTOR", min=0.0, max=1.0)
    fit_status: bpy.props.StringProperty(name="Status")
    last_result_folder: bpy.props.StringProperty(name="Last Result", subtype="DIR_PATH")
    last_material: bpy.props.StringProperty(name="Last Material")


CLASSES = (WovenFabricRigSettings, WovenFabricSettings)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.woven_fabric = bpy.props.PointerProperty(type=WovenFabricSettings)


def unregister():
    del bpy.types.Scene.woven_fabric
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
