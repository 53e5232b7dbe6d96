"""A rendered preview of a fabric material: what the Asset Browser shows for a fit.

In Blender's interface Blender's own preview job renders it (without holding the interface). Without
an interface (the batch, scripts), a small Cycles render (CPU, Open Shading Language: the fitted
shader) in a temporary scene that is removed afterwards, so the user's scenes are untouched: a
square of the fabric, tilted towards the camera, lit by a key light in front and a rim light behind
(which shows what the fabric lets through), in front of a dark backdrop. The square's own uv scale
(the object property that overrides the material's, shader_params.OBJECT_UV_SCALE) shows about
:data:`REPEATS` weave repeats across it, whatever the material's scale, so the weave is readable at
icon size.
"""
from __future__ import annotations

import math
from pathlib import Path

import bpy
import numpy as np

from ..core import shader_params
from . import node_group, rig_scene

REPEATS = 6.0
SIZE = 96


def render_preview(material, size: int = SIZE, samples: int = 8) -> np.ndarray:
    """The preview as (size, size, 4) display RGBA in [0, 1], row 0 = top."""
    scene = bpy.data.scenes.new(".Woven Fabric preview")
    made = []
    try:
        mesh = bpy.data.meshes.new(".Woven Fabric preview")
        mesh.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [(0, 1, 2, 3)])
        uv = mesh.uv_layers.new(name="UVMap")
        for loop, (u, v) in zip(mesh.loops, ((0, 0), (1, 0), (1, 1), (0, 1))):
            uv.data[loop.index].uv = (u, v)
        mesh.materials.append(material)
        made.append(mesh)
        cloth = _link(scene, made, ".Woven Fabric preview", mesh)
        cloth.rotation_euler = (math.radians(-35.0), 0.0, math.radians(15.0))
        tiles = node_group.read_params(material)["tiles"]
        cloth[shader_params.OBJECT_UV_SCALE] = REPEATS / max(max(tiles), 1e-3)

        camera_data = bpy.data.cameras.new(".Woven Fabric preview")
        camera_data.type = "ORTHO"
        camera_data.ortho_scale = 2.3
        made.append(camera_data)
        camera = _link(scene, made, ".Woven Fabric preview camera", camera_data)
        camera.location = (0.0, 0.0, 4.0)
        scene.camera = camera
        for name, location, energy in (("key", (1.5, -2.0, 3.0), 400.0), ("rim", (-0.5, 2.5, -2.0), 300.0)):
            light_data = bpy.data.lights.new(f".Woven Fabric preview {name}", "POINT")
            light_data.energy = energy
            light_data.shadow_soft_size = 0.3
            made.append(light_data)
            _link(scene, made, f".Woven Fabric preview {name}", light_data).location = location
        world = bpy.data.worlds.new(".Woven Fabric preview")
        world.color = (0.02, 0.02, 0.025)
        made.append(world)
        scene.world = world

        render = scene.render
        render.engine = "CYCLES"
        render.resolution_x = render.resolution_y = int(size)
        render.resolution_percentage = 100
        render.film_transparent = False
        scene.view_settings.view_transform = "Standard"
        scene.cycles.device = "CPU"
        scene.cycles.shading_system = True
        scene.cycles.samples = int(samples)
        scene.cycles.use_denoising = False
        scene.cycles.use_adaptive_sampling = False
        return rig_scene.render_film(scene, file_format="PNG")
    finally:
        _remove(made + [scene])


_COLLECTIONS = {bpy.types.Object: "objects", bpy.types.Mesh: "meshes", bpy.types.Camera: "cameras",
                bpy.types.World: "worlds", bpy.types.Scene: "scenes"}


def _remove(blocks) -> None:
    """Removes the temporary data-blocks, objects first (removing a scene may take its objects along)."""
    for block in blocks:
        name = "lights" if isinstance(block, bpy.types.Light) else _COLLECTIONS.get(type(block))
        try:
            getattr(bpy.data, name).remove(block)
        except ReferenceError:  # already gone with its user
            pass


def _link(scene, made, name, data):
    obj = bpy.data.objects.new(name, data)
    scene.collection.objects.link(obj)
    made.insert(0, obj)  # objects go before their data
    return obj


def set_preview(block, pixels: np.ndarray) -> None:
    """Stores (n, n, 4) display RGBA (row 0 = top) as the data-block's preview image."""
    h, w = pixels.shape[:2]
    preview = block.preview_ensure()
    preview.image_size = (w, h)
    preview.image_pixels_float.foreach_set(np.ascontiguousarray(pixels[::-1], dtype=np.float32).ravel())


def preview_from_render(material, fallback_image: str | Path | None = None) -> str:
    """Gives ``material`` a rendered preview. Returns what was used:

    - ``"job"`` in Blender's interface: Blender's own preview renderer, as a background job (a Cycles
      render here would hold the interface for seconds);
    - ``"render"`` without an interface (batch, scripts): :func:`render_preview`;
    - ``"image"`` where that cannot render: the image file ``fallback_image`` (the fit's re-render
      of the photo); ``""``: no preview.
    """
    if not bpy.app.background:
        material.asset_generate_preview()
        return "job"
    try:
        set_preview(material, render_preview(material))
        return "render"
    except (RuntimeError, OSError, ValueError) as exc:
        print(f"Woven Fabric: the preview of {material.name} could not be rendered ({exc})")
    if fallback_image is not None and _preview_from_file(material, fallback_image):
        return "image"
    return ""


def _preview_from_file(block, path: str | Path, size: int = SIZE) -> bool:
    try:
        image = bpy.data.images.load(str(path), check_existing=False)
    except RuntimeError:
        return False
    try:
        image.scale(size, size)
        pixels = np.empty(size * size * 4, dtype=np.float32)
        image.pixels.foreach_get(pixels)
        set_preview(block, pixels.reshape(size, size, 4)[::-1])
        return True
    except (RuntimeError, ValueError):
        return False
    finally:
        bpy.data.images.remove(image)

