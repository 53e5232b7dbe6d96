"""The paper's capture rig as a Blender scene (bpy), for validating the Woven Fabric material.

Geometry (spec section 1): the backend's ``CaptureRig`` built from a rig dict (missing settings:
the spec's rig), so the scene's camera and lights stand where the backend's renderer puts them:

- the fabric: a ``plane_size`` (10) units square at z = 0, x in [0, P], y in [-P, 0], normal +z,
  UV = (x / P, y / P + 1), so the material's ``tiles`` mean exactly what they mean in the backend;
- a pinhole camera at ``CaptureRig.camera_position()`` (V/2, -V/2, h) looking straight down
  (image up = +y) with full field of view ``fov_deg`` over a square film, so it sees x in [0, V],
  y in [-V, 0] with V = 2 h tan(fov / 2); box pixel filter of one pixel (the backend averages
  samples per pixel);
- the front (reflection) and back (transmission) point lights at ``CaptureRig.light_position``,
  radius 0.

Light units. The backend's radiance is ``BSDF * intensity / distance^2``. A Cycles point light of
power P watts has radiant intensity P / (4 pi) W/sr, so a point light of ``P = 4 pi * intensity``
watts gives ``pixel = f_cos * intensity / distance^2``, exactly the backend's convention
(:data:`WATTS_PER_INTENSITY`; measured: a Lambertian closure renders to k cos / pi * I / d^2 to
within float precision, and ``tests/test_shader.py`` checks it).

:func:`render_linear` returns the linear RGBA film (alpha = coverage: 1 - alpha is the fraction of
the pixel that sees through the gaps, which is where the backend adds its out-of-focus glow);
:func:`render_pair` applies the rig's output transform (``core/rig_display.py``) to both.
"""
from __future__ import annotations

import math
import os
import tempfile

import bpy
import numpy as np

from ..core import rig_display, rig_settings
from . import cycles_osl

WATTS_PER_INTENSITY = 4.0 * math.pi

_ROLE = "woven_fabric_rig"  # custom property naming each object's role (names get .001 suffixes)
FABRIC = "Fabric"
CAMERA = "Rig camera"
LIGHTS = {"front": "Front light", "back": "Back light"}


def _fabric_mesh(plane: float):
    mesh = bpy.data.meshes.new(FABRIC)
    mesh.from_pydata([(0.0, -plane, 0.0), (plane, -plane, 0.0), (plane, 0.0, 0.0), (0.0, 0.0, 0.0)], [],
                     [(0, 1, 2, 3)])
    uv = mesh.uv_layers.new(name="UVMap")
    for loop in mesh.loops:
        x, y, _ = mesh.vertices[loop.vertex_index].co
        uv.data[loop.index].uv = (x / plane, y / plane + 1.0)
    mesh.update()
    return mesh


def build_scene(material=None, rig: dict | None = None, size: int = 256, samples: int = 64, osl: bool = True,
                seed: int = 0, threads: int = 0, scene=None):
    """Sets up (a fresh or the given) scene as the rig; returns it. The fabric gets `material`."""
    cycles_osl.ensure_oslquery()
    capture = rig_settings.capture_rig(rig)
    if scene is None:
        scene = bpy.data.scenes.new("Woven fabric rig")
    for child in list(scene.collection.children):  # e.g. the default cube, light and camera
        scene.collection.children.unlink(child)
    for obj in list(scene.collection.objects):
        scene.collection.objects.unlink(obj)
    fabric = bpy.data.objects.new(FABRIC, _fabric_mesh(float(capture.plane_size)))
    fabric[_ROLE] = "fabric"
    scene.collection.objects.link(fabric)
    if material is not None:
        fabric.data.materials.append(material)

    cam = bpy.data.cameras.new(CAMERA)
    cam.type = "PERSP"
    cam.sensor_fit = "AUTO"
    cam.angle = math.radians(capture.fov_deg)
    cam.clip_start, cam.clip_end = 0.01, 1000.0
    cam_obj = bpy.data.objects.new(CAMERA, cam)
    cam_obj.location = capture.camera_position()
    cam_obj.rotation_euler = (0.0, 0.0, 0.0)
    scene.collection.objects.link(cam_obj)
    scene.camera = cam_obj

    for which, name in LIGHTS.items():
        light = bpy.data.lights.new(name, "POINT")
        light.shadow_soft_size = 0.0
        if hasattr(light, "use_soft_falloff"):
            light.use_soft_falloff = False
        light.energy = WATTS_PER_INTENSITY * float(capture.intensity(which))
        obj = bpy.data.objects.new(name, light)
        obj[_ROLE] = which
        obj.location = capture.light_position(which)
        scene.collection.objects.link(obj)

    if scene.world is None:
        scene.world = bpy.data.worlds.new("Rig world")
    scene.world.color = (0.0, 0.0, 0.0)
    if scene.world.node_tree is not None:
        for node in scene.world.node_tree.nodes:
            if node.type == "BACKGROUND":
                node.inputs["Strength"].default_value = 0.0

    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x = r.resolution_y = int(size)
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.film_transparent = True
    r.use_persistent_data = False
    if threads:
        r.threads_mode, r.threads = "FIXED", int(threads)
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    r.image_settings.color_mode = "RGBA"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0

    c = scene.cycles
    c.device = "CPU"
    c.shading_system = bool(osl)
    c.samples = int(samples)
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.pixel_filter_type = "BOX"
    c.filter_width = 1.0
    c.seed = int(seed)
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.max_bounces = 4
    c.transparent_max_bounces = 8
    c.caustics_reflective = c.caustics_refractive = True
    return scene


ENGINES = ("osl", "fallback", "eevee")


def set_engine(scene, engine: str, samples: int | None = None) -> None:
    """Renders with ``osl`` (Cycles CPU with OSL: the fitted OSL shader), ``fallback`` (Cycles without
    OSL, as on a GPU: the standard-node fallback) or ``eevee`` (EEVEE: the fallback)."""
    if engine not in ENGINES:
        raise ValueError(f"engine: expected one of {', '.join(ENGINES)}, got {engine!r}")
    if engine == "eevee":
        scene.render.engine = "BLENDER_EEVEE"
        eevee = scene.eevee
        if samples:
            eevee.taa_render_samples = int(samples)
        eevee.use_shadows = True
        # The backend averages samples over the pixel (a box). EEVEE's film filter is a Gaussian of sigma
        # 0.284 filter_size pixels; the default 1.5 blurs the yarns (2 to 4 pixels a tile here) and halved
        # the spectrum correlation; 0.5 keeps it highest.
        scene.render.filter_size = 0.5
        # The rig's lights are points of radius 0 with exact inverse-square falloff (see build_scene).
        if hasattr(eevee, "light_threshold"):
            eevee.light_threshold = 1e-6
    else:
        scene.render.engine = "CYCLES"
        scene.cycles.shading_system = engine == "osl"
        if samples:
            scene.cycles.samples = int(samples)


def rig_object(scene, role: str):
    """The scene's 'fabric', 'front' or 'back' light object."""
    for obj in scene.objects:
        if obj.get(_ROLE) == role:
            return obj
    raise KeyError(f"scene {scene.name!r} has no rig object {role!r}")


def set_light(scene, which: str | None) -> None:
    """Only the 'front' or 'back' light renders (None: both)."""
    for key in LIGHTS:
        rig_object(scene, key).hide_render = which is not None and key != which


def render_linear(scene, which: str | None = None) -> np.ndarray:
    """Renders with one light and returns the linear film, (size, size, 4) float32, row 0 = top."""
    if which is not None:
        set_light(scene, which)
    return render_film(scene)


def render_film(scene, file_format: str = "OPEN_EXR") -> np.ndarray:
    """Renders ``scene`` (its own render settings) and returns the film, (h, w, 4) float32, row 0 =
    top: linear for OPEN_EXR, display values (the scene's view transform) for PNG."""
    with tempfile.TemporaryDirectory(prefix="wf_render_") as tmp:
        path = os.path.join(tmp, "render.exr" if file_format == "OPEN_EXR" else "render.png")
        settings = scene.render.image_settings
        saved = (settings.file_format, settings.color_depth, settings.color_mode)
        if file_format != settings.file_format:
            settings.file_format = file_format
            settings.color_mode = "RGBA"
            settings.color_depth = "16"
        scene.render.filepath = path
        window_scene = bpy.context.window.scene if bpy.context.window else None
        if bpy.context.window is not None:
            bpy.context.window.scene = scene
        try:
            bpy.ops.render.render(write_still=True, scene=scene.name)
        finally:
            if window_scene is not None:
                bpy.context.window.scene = window_scene
            settings.file_format, settings.color_depth, settings.color_mode = saved
        image = bpy.data.images.load(path)
        try:
            w, h = image.size
            pixels = np.empty(w * h * 4, dtype=np.float32)
            image.pixels.foreach_get(pixels)
        finally:
            bpy.data.images.remove(image)
    return pixels.reshape(h, w, 4)[::-1].copy()


def render_pair(scene, rig: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(reflection, transmission) displayed images of the scene's fabric, (N, N, 3) in [0, 1]."""
    front = render_linear(scene, "front")
    back = render_linear(scene, "back")
    set_light(scene, None)
    return (rig_display.display(front, rig),
            rig_display.display(back, rig, coverage=back[..., 3], glow=True))
