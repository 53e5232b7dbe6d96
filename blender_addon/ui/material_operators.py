"""Working with a fitted material: paint it, scale it, see which shader renders it, find it as an asset.

Operators (each reads the context, calls scene/ and reports):

- Add Colour Layer (``fabric.add_colour_layer``): a new neutral image wired into the active
  material's colour maps, multiplying or replacing the fitted colours, made the active paint slot
  (scene/colour_layer.py);
- Set Real-World Scale (``fabric.set_real_world_scale``): the weave at its photographed size on
  each selected mesh, from its surface and UV areas (scene/mesh_scale.py);
- Turn On OSL (``fabric.enable_osl``): the scene's Cycles "Open Shading Language" option, so that
  Cycles renders the fitted shader instead of the approximate fallback (core/shader_status.py);
- Register Asset Library (``fabric.register_asset_library``): a batch library's folder becomes a
  Blender asset library, so its fabrics appear in the Asset Browser.

Handlers keep what the node group relies on: the fallback's lookup images are restored when
changed (scene/fallback_atlases.repair_atlases: on a timer and before saving), and saving a file writes
the catalogs of its fitted fabrics beside it (scene/materials.write_catalogs).
"""
from __future__ import annotations

from pathlib import Path

import bpy

from ..core import colour_layer as colour_layer_rules
from ..core import shader_status
from ..scene import colour_layer, fallback_atlases, materials, mesh_scale, node_group
from . import panels
from .layout import wrapped_labels

REPAIR_INTERVAL_S = 2.0


def active_fabric_material(context):
    obj = context.object
    material = getattr(obj, "active_material", None) if obj is not None else None
    return material if materials.is_fabric_material(material) else None


def scene_shader_status(scene) -> shader_status.ShaderStatus:
    """Which shader renders a fabric material with ``scene``'s render settings."""
    cycles = getattr(scene, "cycles", None)
    backend = "NONE"
    addon = bpy.context.preferences.addons.get("cycles")
    if addon is not None:
        backend = addon.preferences.compute_device_type
    return shader_status.shader_status(scene.render.engine, bool(getattr(cycles, "shading_system", False)),
                                       getattr(cycles, "device", "CPU"), backend)


def _fabric_materials(obj) -> list:
    """The Woven Fabric materials in a mesh's slots (none for any other object)."""
    if obj.type != "MESH":
        return []
    return [slot.material for slot in obj.material_slots if materials.is_fabric_material(slot.material)]


class FABRIC_OT_add_colour_layer(bpy.types.Operator):
    """Add a white image to paint on the active fabric material: it multiplies (or, where painted,
    replaces) the fitted diffuse colours, and becomes the active paint slot"""

    bl_idname = "fabric.add_colour_layer"
    bl_label = "Add Colour Layer"
    bl_options = {"REGISTER", "UNDO"}

    mode: bpy.props.EnumProperty(
        name="Mode", default="MULTIPLY",
        items=(("MULTIPLY", "Multiply", "Painted colour multiplies the fitted colours (white leaves them)"),
               ("REPLACE", "Replace", "Painted colour replaces the fitted colours where painted")))
    size: bpy.props.IntProperty(name="Size", default=0, min=0, max=colour_layer_rules.MAX_SIZE,
                                description="Image side in pixels; 0: from the weave (a texel per repeat)")
    paint: bpy.props.BoolProperty(name="Start Painting", default=True,
                                  description="Switch the active object to Texture Paint mode")

    @classmethod
    def poll(cls, context):
        return active_fabric_material(context) is not None

    def execute(self, context):
        material = active_fabric_material(context)
        try:
            image = colour_layer.add_colour_layer(material, self.mode, self.size or None)
        except (ValueError, RuntimeError) as exc:
            self.report({"ERROR"}, f"{material.name}: {exc}")
            return {"CANCELLED"}
        obj = context.object
        if self.paint and obj.type == "MESH" and obj.mode != "TEXTURE_PAINT":
            bpy.ops.object.mode_set(mode="TEXTURE_PAINT")  # also refreshes the material's paint slots
        colour_layer.make_active_slot(material, image)
        self.report({"INFO"}, f"Colour layer {image.name} ({image.size[0]} px, {self.mode.lower()}) on "
                              f"{material.name}: paint away")
        return {"FINISHED"}


class FABRIC_OT_set_real_world_scale(bpy.types.Operator):
    """Give the fabric on each selected mesh its photographed size, from the mesh's surface and UV areas"""

    bl_idname = "fabric.set_real_world_scale"
    bl_label = "Set Real-World Scale"
    bl_options = {"REGISTER", "UNDO"}

    uv_map: bpy.props.StringProperty(name="UV Map", description="UV map to measure (and render the weave "
                                                                "with); empty: the one each mesh renders with")
    width_cm: bpy.props.FloatProperty(name="Photographed Width", default=0.0, min=0.0,
                                      description="Real width of the photographed square in cm; 0: the "
                                                  "width each fit recorded")

    @classmethod
    def poll(cls, context):
        if not any(_fabric_materials(obj) for obj in context.selected_objects):
            cls.poll_message_set("Select a mesh with a Woven Fabric material")
            return False
        return True

    def execute(self, context):
        done, problems = [], []
        for obj in (o for o in context.selected_objects if o.type == "MESH"):
            fabrics = _fabric_materials(obj)
            if not fabrics:
                problems.append(f"{obj.name}: no Woven Fabric material")
                continue
            try:
                scale = mesh_scale.set_real_world_scale(obj, fabrics[0], context.scene, self.uv_map,
                                                        self.width_cm or None)
            except ValueError as exc:
                problems.append(str(exc))
                continue
            done.append(f"{obj.name} x{scale:.3g}")
        for problem in problems:
            self.report({"WARNING"}, problem)
        if not done:
            self.report({"ERROR"}, "No mesh was scaled: " + "; ".join(problems))
            return {"CANCELLED"}
        self.report({"INFO"}, "Real-world scale (uv scale): " + ", ".join(done))
        return {"FINISHED"}


class FABRIC_OT_enable_osl(bpy.types.Operator):
    """Turn on Open Shading Language for Cycles, so Cycles renders the fitted OSL shader (CPU, OptiX)
    instead of the approximate fallback"""

    bl_idname = "fabric.enable_osl"
    bl_label = "Turn On OSL"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.scene is not None and hasattr(context.scene, "cycles")

    def execute(self, context):
        context.scene.cycles.shading_system = True
        self.report({"INFO"}, scene_shader_status(context.scene).text)
        return {"FINISHED"}


class FABRIC_OT_register_asset_library(bpy.types.Operator):
    """Register the folder of a fabric library (.blend) as an asset library, so its fabrics appear in
    the Asset Browser"""

    bl_idname = "fabric.register_asset_library"
    bl_label = "Register Asset Library"

    filepath: bpy.props.StringProperty(subtype="FILE_PATH", name="Library")
    filter_glob: bpy.props.StringProperty(default="*.blend", options={"HIDDEN"})

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        path = Path(bpy.path.abspath(self.filepath)) if self.filepath else Path()
        if not path.is_file() or path.suffix != ".blend":
            self.report({"ERROR"}, f"{self.filepath or '(no file)'}: choose a fabric library .blend")
            return {"CANCELLED"}
        folder = path.resolve().parent
        libraries = context.preferences.filepaths.asset_libraries
        for library in libraries:
            if library.path and Path(bpy.path.abspath(library.path)).resolve() == folder:
                self.report({"INFO"}, f"{folder} is already the asset library {library.name}")
                return {"FINISHED"}
        library = libraries.new(name=folder.name, directory=str(folder))
        context.preferences.is_dirty = True  # saved with the preferences
        self.report({"INFO"}, f"Asset library {library.name}: {folder} (see the Asset Browser)")
        return {"FINISHED"}


class VIEW3D_PT_woven_fabric_material(panels.FabricSubPanel, bpy.types.Panel):
    bl_label = "Material"

    def draw(self, context):
        layout = self.layout
        status = scene_shader_status(context.scene)
        wrapped_labels(layout, status.text, context, icon="SHADING_RENDERED" if status.osl else "INFO")
        if status.can_enable_osl:
            layout.operator("fabric.enable_osl", icon="SCRIPT")
        material = active_fabric_material(context)
        wrapped_labels(layout, material.name if material else "Select an object with a Woven Fabric material",
                       context, icon="MATERIAL" if material else "BLANK1")
        row = layout.row(align=True)
        row.operator("fabric.add_colour_layer", text="Colour Layer: Multiply", icon="BRUSH_DATA").mode = "MULTIPLY"
        row.operator("fabric.add_colour_layer", text="Replace").mode = "REPLACE"
        layout.operator("fabric.set_real_world_scale", icon="FULLSCREEN_ENTER")
        layout.operator("fabric.register_asset_library", icon="ASSET_MANAGER")


# -- keeping the node group's lookup images and the catalogs --------------------------------------

def _repair_atlases() -> float:
    if bpy.data.node_groups.get(node_group.NODE_GROUP_NAME) is not None:
        restored = fallback_atlases.repair_atlases()
        if restored:
            print(f"Woven Fabric: restored the weave lookup image(s) {', '.join(restored)} (they are not "
                  "textures to paint on; use Add Colour Layer)")
    return REPAIR_INTERVAL_S


@bpy.app.handlers.persistent
def _before_save(*_args):
    _repair_atlases()


@bpy.app.handlers.persistent
def _after_save(*_args):
    if bpy.data.filepath:
        try:
            materials.write_catalogs(Path(bpy.data.filepath).parent)
        except OSError as exc:
            print(f"Woven Fabric: could not write the fabric catalogs beside {bpy.data.filepath}: {exc}")


CLASSES = (FABRIC_OT_add_colour_layer, FABRIC_OT_set_real_world_scale, FABRIC_OT_enable_osl,
           FABRIC_OT_register_asset_library, VIEW3D_PT_woven_fabric_material)
_HANDLERS = ((bpy.app.handlers.save_pre, _before_save), (bpy.app.handlers.save_post, _after_save))


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    for handlers, handler in _HANDLERS:
        handlers.append(handler)
    bpy.app.timers.register(_repair_atlases, first_interval=REPAIR_INTERVAL_S, persistent=True)


def unregister():
    if bpy.app.timers.is_registered(_repair_atlases):
        bpy.app.timers.unregister(_repair_atlases)
    for handlers, handler in _HANDLERS:
        if handler in handlers:
            handlers.remove(handler)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
