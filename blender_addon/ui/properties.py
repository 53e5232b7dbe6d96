"""Scene settings of a capture (``scene.woven_fabric``): the photos, the rig, the fit and its state.

The rig's properties are generated from ``CaptureRig`` in backend/core/rig.py (rig_settings.rig_fields)
and the weave choices from the patterns the backend's fit accepts (declarations.fit_patterns), so
the panel shows the spec's defaults and follows any new rig setting or pattern.
"""
from __future__ import annotations

import re

import bpy
import numpy

from ..core import declarations, rig_settings

MIRRORED = declarations.mirrored_of()  # mirrored preset -> the paper's preset it mirrors


def _pattern_item(name: str) -> tuple[str, str, str]:
    """(identifier, label, tooltip) of a weave pattern: twill1 -> "Twill 1", "Twill weave, variant 1";
    twill1m -> "Twill 1 mirrored", "..., mirrored left-right (its diagonal runs the other way)"."""
    if name == declarations.AUTO_PATTERN:
        return name, "Automatic", "Let the fit choose the weave"
    mirror = name in MIRRORED
    family, variant = re.fullmatch(r"(.*?)(\d*)", MIRRORED.get(name, name)).groups()
    label = f"{family.capitalize()} {variant}".strip() + (" mirrored" if mirror else "")
    tooltip = f"{family.capitalize()} weave" + (f", variant {variant}" if variant else "")
    return name, label, tooltip + (", mirrored left-right (its diagonal runs the other way)" if mirror else "")


PATTERN_ITEMS = tuple(_pattern_item(name) for name in declarations.fit_patterns())
_MIN_SIZE = declarations.fit_options().MIN_WORKING_SIZE
_FILM_SIZE = declarations.rig().DEFAULT_RIG.film_size


def _rig_property(field: rig_settings.RigField):
    common = {"name": field.label, "description": field.description, "default": field.default}
    if field.kind == "vector":
        return bpy.props.FloatVectorProperty(size=3, subtype="XYZ", **common)
    if field.kind == "int":
        rig = declarations.rig()  # the only int setting is the film size: its range is the backend's
        return bpy.props.IntProperty(min=rig.MIN_FILM_SIZE, max=rig.MAX_FILM_SIZE, **common)
    lower = {"glow_strength": 0.0, "width_cm": 0.0}.get(field.name, 1e-4)
    return bpy.props.FloatProperty(min=lower, **common)


def _rig_settings_class():
    annotations = {field.name: _rig_property(field) for field in rig_settings.rig_fields()}
    return type("WovenFabricRigSettings", (bpy.types.PropertyGroup,), {
        "__annotations__": annotations,
        "__doc__": "The capture rig (spec section 1); the defaults are the paper's rig.",
    })


WovenFabricRigSettings = _rig_settings_class()


def rig_values(rig) -> dict:
    """The rig settings as plain values (tuples for vectors), each float the shortest decimal that its
    single-precision property holds: the 2.2 a property stores as 2.2000000476837 is 2.2 again, so
    that the rig.json of an unchanged panel is the backend's own rig and the fit the command line's."""
    def plain(value):
        return float(str(numpy.float32(value))) if isinstance(value, float) else value

    return {field.name: (tuple(map(plain, getattr(rig, field.name))) if field.kind == "vector"
                         else plain(getattr(rig, field.name)))
            for field in rig_settings.rig_fields()}


def fit_options(settings, device: str | None, strict: bool | None = None) -> dict:
    """The panel's fit settings as a fit's options (backend_bridge.FitRequest's fields; 0: the backend's
    default), for a single fit and the sidebar batch alike; ``strict`` None: the panel's choice."""
    return {"pattern": settings.pattern, "iterations": settings.iterations or None, "size": settings.size or None,
            "device": device, "strict": settings.refuse_swapped if strict is None else strict}


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
    pattern: bpy.props.EnumProperty(name="Weave", items=PATTERN_ITEMS, default=declarations.AUTO_PATTERN)
    iterations: bpy.props.IntProperty(
        name="Iterations", default=0, min=0, soft_max=2000,
        description="Optimiser iterations; 0 uses the backend's default")
    size: bpy.props.IntProperty(
        name="Working Size", default=0, min=0, soft_max=_FILM_SIZE,
        description=f"Side in pixels of the working images, {_MIN_SIZE} to {_FILM_SIZE}; 0 uses the backend's "
                    "default")
    refuse_swapped: bpy.props.BoolProperty(
        name="Refuse Swapped Photos", default=True,
        description="Stop before fitting when the photos' lighting reads the other way round (the reflection "
                    "photo lit from behind): the panel then shows both photos to swap them or fit them as given")
    material_name: bpy.props.StringProperty(
        name="Material", description="Name of the new material; empty: the photo's name")
    update_active_material: bpy.props.BoolProperty(
        name="Update Active Material", default=False,
        description="Write the fit into the active object's Woven Fabric material instead of creating "
                    "a new material")

    # State of the last fit, for the panel (whether one runs now is operators.fit_job.running()).
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
