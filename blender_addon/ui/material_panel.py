"""The sidebar's Colour & Pattern panel: recolour a fitted fabric, or weave it yarn-dyed (bpy).

- Recolour: the group node's hue shift, saturation and value inputs, drawn as sliders; the fabric's
  base colour beside them (core/dye.py; painting it with a Replace colour layer changes nothing);
- Pattern: the warp and weft setts as text (core/sett.py), on the material
  (``material.woven_fabric_pattern``), written into the node group's stripes as they are typed
  (scene/colour_layer.apply_sett; a text that cannot be read is shown with its problem and changes
  nothing), and the presets (``fabric.sett_preset``: gingham, tartan, pinstripe, none).
"""
from __future__ import annotations

import bpy

from ..core import sett, shader_params
from ..scene import colour_layer, group_interface, node_group
from . import material_operators, panels

_LABELS = dict(zip(shader_params.RECOLOUR, ("Hue Shift", "Saturation", "Value")))


def _apply(pattern, _context):
    material = pattern.id_data
    try:
        colour_layer.apply_sett(material, pattern.warp, pattern.weft)
    except ValueError as exc:  # a sett text that cannot be read (sett.SettError), or no fabric group
        pattern.problem = str(exc)
    else:
        pattern.problem = ""


def _base_colour(pattern):
    try:
        return colour_layer.base_colour(pattern.id_data)
    except (ValueError, KeyError):  # not (or no longer) a Woven Fabric material
        return (0.0, 0.0, 0.0)


class WovenFabricPattern(bpy.types.PropertyGroup):
    warp: bpy.props.StringProperty(
        name="Warp", update=_apply,
        description="The warp's colour sequence, e.g. W8 R8 or B/24 K4 G/24 (symmetric): colour codes K W N R G B Y "
                    "O P A T C, F the fitted colour, #rrggbb, each with its thread count; empty: plain")
    weft: bpy.props.StringProperty(name="Weft", update=_apply,
                                   description="The weft's colour sequence; empty: the same as the warp")
    problem: bpy.props.StringProperty(name="Problem", description="Why the last sett text was not applied")
    base_colour: bpy.props.FloatVectorProperty(
        name="Fitted Colour", subtype="COLOR", size=3, get=_base_colour,
        description="The fabric's base colour (from its albedos): dyeing to it changes nothing")


class FABRIC_OT_sett_preset(bpy.types.Operator):
    """Weave the active fabric yarn-dyed with a preset sett (the texts stay editable)"""

    bl_idname = "fabric.sett_preset"
    bl_label = "Yarn-Dyed Preset"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.EnumProperty(
        name="Preset", items=[(key, label, f"{label}: warp {warp}" + (f", weft {weft}" if weft else ""))
                              for key, (label, warp, weft) in sett.PRESETS.items()]
        + [("NONE", "None", "No stripes: the fabric's own colour")])

    @classmethod
    def poll(cls, context):
        return material_operators.active_fabric_material(context) is not None

    def execute(self, context):
        material = material_operators.active_fabric_material(context)
        _, warp, weft = sett.PRESETS.get(self.preset, ("", "", ""))
        pattern = material.woven_fabric_pattern
        pattern.weft = weft
        pattern.warp = warp  # both written: each text's update writes the stripes
        if pattern.problem:
            self.report({"ERROR"}, f"{material.name}: {pattern.problem}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"{material.name}: {self.preset.lower()} sett")
        return {"FINISHED"}


class VIEW3D_PT_woven_fabric_colour(panels.FabricSubPanel, bpy.types.Panel):
    bl_label = "Colour & Pattern"

    def draw(self, context):
        layout = self.layout
        material = material_operators.active_fabric_material(context)
        if material is None:
            layout.label(text="Select an object with a Woven Fabric material", icon="INFO")
            return
        inputs = group_interface.input_sockets(node_group.group_node(material))
        pattern = material.woven_fabric_pattern
        column = layout.column(align=True)
        column.prop(pattern, "base_colour")
        for name in shader_params.RECOLOUR:
            column.prop(inputs[name], "default_value", text=_LABELS[name], slider=True)
        layout.label(text="Yarn-dyed pattern:")
        row = layout.row(align=True)
        for key, (label, _, _) in sett.PRESETS.items():
            row.operator("fabric.sett_preset", text=label).preset = key
        row.operator("fabric.sett_preset", text="", icon="X").preset = "NONE"
        layout.prop(pattern, "warp")
        layout.prop(pattern, "weft")
        if pattern.problem:
            layout.label(text=pattern.problem, icon="ERROR")


CLASSES = (WovenFabricPattern, FABRIC_OT_sett_preset, VIEW3D_PT_woven_fabric_colour)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Material.woven_fabric_pattern = bpy.props.PointerProperty(type=WovenFabricPattern)


def unregister():
    del bpy.types.Material.woven_fabric_pattern
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
