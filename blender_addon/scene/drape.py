"""The draped-cloth preview: a new scene with a cloth-simulated square of fabric over a sphere.

Everything is created new (a scene, its objects, a copy of the material scaled to the cloth), so
the user's scenes and materials are never touched. The scene holds, in metres:

- a ground plane and a sphere of radius 0.3 resting on it, both colliders;
- the cloth: a ``cloth_size_cm`` square grid with UVs spanning it once, started just above the
  sphere and simulated for ``frames`` frames; by default the draped shape is then frozen into the
  mesh (the cloth modifier removed) so that any frame renders the same in Cycles and EEVEE;
- a camera looking down at the drape, a key and a rim area light (the rim shows transmission);
- Cycles set to Open Shading Language, so a CPU render uses the OSL shader.

The material is a copy of the fitted one whose scale is set for the cloth (node_group.apply_params
with ``cloth_size_cm``), so the weave appears at its real size when the fit knew the photographed
width.
"""
from __future__ import annotations

import math

import bmesh
import bpy
from mathutils import Vector

from . import materials, node_group

SPHERE_RADIUS_M = 0.3


def add_drape_preview(material, *, cloth_size_cm: float = 100.0, resolution: int = 48, frames: int = 40,
                      freeze: bool = True, engine: str | None = None, name: str = "Fabric Preview"):
    """Builds the preview scene and returns it (the caller decides whether to show it)."""
    scene = bpy.data.scenes.new(name)
    if engine:
        scene.render.engine = engine
    if hasattr(scene, "cycles"):
        # The OSL shader is the reference on the CPU; GPU devices without OSL use the fallback nodes.
        scene.cycles.shading_system = True
    scene.unit_settings.system = "METRIC"
    scene.frame_start, scene.frame_end = 1, max(frames, 1)

    size_m = cloth_size_cm / 100.0
    ground = _add_ground(scene, size_m)
    sphere = _add_sphere(scene)
    cloth = _add_cloth(scene, size_m, resolution)
    cloth.data.materials.append(_preview_material(material, cloth_size_cm))
    _add_camera(scene, size_m)
    _add_lights(scene, size_m)
    _add_world(scene)

    _simulate(scene, frames)
    if freeze:
        _freeze(scene, cloth)
    cloth["woven_fabric_preview"] = True
    for obj in (ground, sphere):
        obj.hide_select = True
    return scene


def _link(scene, name, data):
    obj = bpy.data.objects.new(name, data)
    scene.collection.objects.link(obj)
    return obj


def _mesh_from(name, build):
    bm = bmesh.new()
    build(bm)
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    return mesh


def _plain_material(name, colour):
    material = bpy.data.materials.new(name)
    material.diffuse_color = (*colour, 1.0)
    material.use_fake_user = False
    # New materials in Blender 5 already have a Principled BSDF; set its colour when it is there.
    tree = material.node_tree
    bsdf = next((n for n in tree.nodes if n.type == "BSDF_PRINCIPLED"), None) if tree else None
    if bsdf is not None:
        bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
        bsdf.inputs["Roughness"].default_value = 0.8
    return material


def _add_ground(scene, size_m):
    half = max(size_m * 5.0, 5.0)
    mesh = _mesh_from("Preview Ground", lambda bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=half))
    mesh.materials.append(_plain_material("Preview Ground", (0.18, 0.18, 0.18)))
    ground = _link(scene, "Preview Ground", mesh)
    ground.modifiers.new("Collision", "COLLISION")
    return ground


def _add_sphere(scene):
    mesh = _mesh_from("Preview Collider", lambda bm: bmesh.ops.create_uvsphere(
        bm, u_segments=32, v_segments=16, radius=SPHERE_RADIUS_M))
    for polygon in mesh.polygons:
        polygon.use_smooth = True
    mesh.materials.append(_plain_material("Preview Collider", (0.2, 0.2, 0.22)))
    sphere = _link(scene, "Preview Collider", mesh)
    sphere.location.z = SPHERE_RADIUS_M
    collision = sphere.modifiers.new("Collision", "COLLISION")
    collision.settings.thickness_outer = 0.01
    return sphere


def _add_cloth(scene, size_m, resolution):
    def grid_with_uvs(bm):
        bm.loops.layers.uv.new("UVMap")  # calc_uvs fills an existing UV layer, it makes none
        bmesh.ops.create_grid(bm, x_segments=resolution, y_segments=resolution, size=size_m / 2.0, calc_uvs=True)

    mesh = _mesh_from("Fabric Cloth", grid_with_uvs)
    for polygon in mesh.polygons:
        polygon.use_smooth = True
    cloth = _link(scene, "Fabric Cloth", mesh)
    cloth.location.z = 2 * SPHERE_RADIUS_M + 0.02
    # A small turn so that the folds do not line up with the camera.
    cloth.rotation_euler.z = math.radians(20.0)
    modifier = cloth.modifiers.new("Cloth", "CLOTH")
    settings = modifier.settings
    settings.quality = 5
    settings.mass = 0.15            # kg per vertex area: a light cotton
    settings.tension_stiffness = 15.0
    settings.compression_stiffness = 15.0
    settings.bending_stiffness = 0.5
    modifier.collision_settings.distance_min = 0.005
    modifier.point_cache.frame_end = scene.frame_end
    return cloth


def _preview_material(material, cloth_size_cm):
    """A copy of the fitted material scaled for the cloth; the original stays as it is."""
    copy = material.copy()
    copy.name = materials.free_material_name(f"{material.name} Drape")
    copy.use_fake_user = False
    node_group.apply_params(copy, node_group.read_params(copy), width_cm=materials.material_width_cm(material),
                            cloth_size_cm=cloth_size_cm)
    return copy


def _look_at(obj, target):
    direction = Vector(target) - obj.location
    obj.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()


def _add_camera(scene, size_m):
    camera_data = bpy.data.cameras.new("Preview Camera")
    camera_data.lens = 50.0
    camera = _link(scene, "Preview Camera", camera_data)
    distance = 1.9 * max(size_m, 0.8)
    camera.location = (0.0, -distance, 0.7 * distance)
    _look_at(camera, (0.0, 0.0, SPHERE_RADIUS_M * 0.8))
    scene.camera = camera
    return camera


def _add_lights(scene, size_m):
    reach = max(size_m, 0.8)
    for name, location, energy, size in (("Preview Key", (1.6 * reach, -1.6 * reach, 2.2 * reach), 150.0, 1.0),
                                         ("Preview Rim", (-0.8 * reach, 1.8 * reach, 1.0 * reach), 120.0, 0.6)):
        data = bpy.data.lights.new(name, "AREA")
        data.energy = energy * reach * reach
        data.size = size * reach
        light = _link(scene, name, data)
        light.location = location
        _look_at(light, (0.0, 0.0, SPHERE_RADIUS_M))


def _add_world(scene):
    world = bpy.data.worlds.new("Preview World")
    world.color = (0.05, 0.05, 0.05)
    if world.node_tree is not None:
        background = next((n for n in world.node_tree.nodes if n.type == "BACKGROUND"), None)
        if background is not None:
            background.inputs["Color"].default_value = (0.05, 0.05, 0.06, 1.0)
    scene.world = world


def _simulate(scene, frames):
    """Steps through the frames so that the cloth cache fills in order (a jump would not simulate)."""
    for frame in range(scene.frame_start, scene.frame_start + frames):
        scene.frame_set(frame)


def _freeze(scene, cloth):
    """Keeps the draped shape as the mesh itself and drops the simulation."""
    depsgraph = scene.view_layers[0].depsgraph
    evaluated = cloth.evaluated_get(depsgraph)
    draped = bpy.data.meshes.new_from_object(evaluated)
    old = cloth.data
    cloth.modifiers.remove(cloth.modifiers["Cloth"])
    cloth.data = draped
    draped.name = "Fabric Cloth"
    bpy.data.meshes.remove(old)
    cloth.modifiers.new("Smooth", "SUBSURF").levels = 1
    solidify = cloth.modifiers.new("Thickness", "SOLIDIFY")
    solidify.thickness = 0.002
