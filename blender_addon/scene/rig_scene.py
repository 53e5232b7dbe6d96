"""The paper's capture rig as a Blender scene (bpy), for validating the Woven Fabric material.

Geometry (spec section 1, values from a ``CaptureRig.to_dict()``, defaults = the paper's rig):

- the fabric: a ``plane_size`` (10) units square at z = 0, x in [0, P], y in [-P, 0], normal +z,
  UV = (x / P, y / P + 1), so the material's ``tiles`` mean exactly what they mean in the backend;
- a pinhole camera at (V/2, -V/2, h) looking straight down (image up = +y) with full field of
  view ``fov_deg`` over a square film, so it sees x in [0, V], y in [-V, 0] with
  V = 2 h tan(fov / 2); box pixel filter of one pixel (the backend averages samples per pixel);
- the front (reflection) and back (transmission) point lights at the rig's positions, radius 0.

Light units. The backend's radiance is ``BSDF * intensity / distance^2``. A Cycles point light of
power P watts has radiant intensity P / (4 pi) W/sr, so a point light of ``P = 4 pi * intensity``
watts gives ``pixel = f_cos * intensity / distance^2``, exactly the backend's convention
(:data:`WATTS_PER_INTENSITY`; measured: a Lambertian closure renders to k cos / pi * I / d^2 to
within float precision, and ``tests/test_shader.py`` checks it).

:func:`render_linear` returns the linear RGBA film (alpha = coverage: 1 - alpha is the fraction of
the pixel that sees through the gaps, which is where the backend adds its out-of-focus glow);
:func:`display` applies the rig's output transform (clamp, 1 / gamma, vignette).
"""
from __future__ import annotations

import math
import os
import tempfile

import numpy as np

WATTS_PER_INTENSITY = 4.0 * math.pi

DEFAULT_RIG = {
    "film_size": 512, "plane_size": 10.0, "camera_height": 8.0, "fov_deg": 53.0,
    "front_light": [0.0, 8.0, 8.0], "back_light": [0.0, 0.0, -9.0],
    "front_intensity": 300.0, "back_intensity": 300.0, "vignette_sigma_px": 450.0,
    "glow_strength": 8.0, "glow_sigma_px": 20.0, "gamma": 2.2, "clamp": 1.0, "camera_blur_px": 0.0,
    "width_cm": None,
}

_ROLE = "woven_fabric_rig"  # custom property naming each object's role (names get .001 suffixes)
FABRIC = "Fabric"
CAMERA = "Rig camera"
LIGHTS = {"front": "Front light", "back": "Back light"}


def rig_values(rig: dict | None = None) -> dict:
    """The rig's settings with the defaults filled in."""
    out = dict(DEFAULT_RIG)
    out.update({k: v for k, v in (rig or {}).items() if v is not None or k == "width_cm"})
    return out


def view_size(rig: dict) -> float:
    return 2.0 * rig["camera_height"] * math.tan(math.radians(rig["fov_deg"]) / 2.0)


def oslquery_path() -> str:
    """Folder of Blender's bundled Python packages (holds ``oslquery``, which Cycles needs to
    compile script nodes; the pip ``bpy`` module does not put it on sys.path)."""
    import bpy

    return os.path.join(bpy.utils.resource_path("LOCAL"), "python", "lib",
                        f"python{os.sys.version_info.major}.{os.sys.version_info.minor}", "site-packages")


def ensure_oslquery() -> None:
    import sys

    path = oslquery_path()
    if os.path.isdir(path) and path not in sys.path:
        sys.path.append(path)


def _fabric_mesh(bpy, plane: float):
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
    import bpy

    ensure_oslquery()
    rig = rig_values(rig)
    if scene is None:
        scene = bpy.data.scenes.new("Woven fabric rig")
    for child in list(scene.collection.children):  # e.g. the default cube, light and camera
        scene.collection.children.unlink(child)
    for obj in list(scene.collection.objects):
        scene.collection.objects.unlink(obj)
    plane = float(rig["plane_size"])
    V = view_size(rig)

    fabric = bpy.data.objects.new(FABRIC, _fabric_mesh(bpy, plane))
    fabric[_ROLE] = "fabric"
    scene.collection.objects.link(fabric)
    if material is not None:
        fabric.data.materials.append(material)

    cam = bpy.data.cameras.new(CAMERA)
    cam.type = "PERSP"
    cam.sensor_fit = "AUTO"
    cam.angle = math.radians(rig["fov_deg"])
    cam.clip_start, cam.clip_end = 0.01, 1000.0
    cam_obj = bpy.data.objects.new(CAMERA, cam)
    cam_obj.location = (V / 2.0, -V / 2.0, float(rig["camera_height"]))
    cam_obj.rotation_euler = (0.0, 0.0, 0.0)
    scene.collection.objects.link(cam_obj)
    scene.camera = cam_obj

    for which, name in LIGHTS.items():
        light = bpy.data.lights.new(name, "POINT")
        light.shadow_soft_size = 0.0
        if hasattr(light, "use_soft_falloff"):
            light.use_soft_falloff = False
        light.energy = WATTS_PER_INTENSITY * float(rig[f"{which}_intensity"])
        obj = bpy.data.objects.new(name, light)
        obj[_ROLE] = which
        dx, dy, z = rig[f"{which}_light"]
        obj.location = (V / 2.0 + dx, -V / 2.0 + dy, z)
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
    import bpy

    if which is not None:
        set_light(scene, which)
    with tempfile.TemporaryDirectory(prefix="wf_rig_") as tmp:
        path = os.path.join(tmp, "render.exr")
        scene.render.filepath = path
        window_scene = bpy.context.window.scene if bpy.context.window else None
        if bpy.context.window is not None:
            bpy.context.window.scene = scene
        try:
            bpy.ops.render.render(write_still=True, scene=scene.name)
        finally:
            if window_scene is not None:
                bpy.context.window.scene = window_scene
        image = bpy.data.images.load(path)
        try:
            w, h = image.size
            pixels = np.empty(w * h * 4, dtype=np.float32)
            image.pixels.foreach_get(pixels)
        finally:
            bpy.data.images.remove(image)
    return pixels.reshape(h, w, 4)[::-1].copy()


def falloff(size: int, sigma_px: float, film_size: int = 512) -> np.ndarray:
    """exp(-d^2 / sigma^2) at pixel centres, normalised to max 1; d in pixels of the rig's film."""
    centres = (np.arange(size, dtype=np.float64) + 0.5) * (film_size / size) - film_size / 2.0
    d2 = centres[:, None] ** 2 + centres[None, :] ** 2
    mask = np.exp(-d2 / (sigma_px * sigma_px))
    return mask / mask.max()


def gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur (mirrored borders) of an (N, N, C) image; sigma in pixels."""
    if sigma <= 1e-3:
        return image
    radius = max(1, min(int(math.ceil(3.0 * sigma)), image.shape[0] - 1))
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (x / sigma) ** 2)
    kernel /= kernel.sum()
    out = np.pad(image, ((radius, radius), (radius, radius), (0, 0)), mode="reflect")
    out = sum(w * out[i:i + image.shape[0]] for i, w in enumerate(kernel))
    return sum(w * out[:, i:i + image.shape[1]] for i, w in enumerate(kernel))


def display(radiance: np.ndarray, rig: dict | None = None, coverage: np.ndarray | None = None,
            glow: bool = False) -> np.ndarray:
    """The rig's output transform of a linear (N, N, 3) image: (+ glow where the pixel sees no
    yarn, transmission only), the camera blur, clamp, 1 / gamma, vignette."""
    rig = rig_values(rig)
    n = radiance.shape[0]
    rad = radiance[..., :3].astype(np.float64)
    if glow and coverage is not None and rig["glow_strength"] > 0:
        open_fraction = 1.0 - np.clip(coverage, 0.0, 1.0)
        rad = rad + (falloff(n, rig["glow_sigma_px"], rig["film_size"]) * rig["glow_strength"]
                     * open_fraction)[..., None]
    rad = gaussian_blur(rad, rig.get("camera_blur_px", 0.0) * n / rig["film_size"])
    out = np.clip(rad, 0.0, rig["clamp"]) ** (1.0 / rig["gamma"])
    return out * falloff(n, rig["vignette_sigma_px"], rig["film_size"])[..., None]


def render_pair(scene, rig: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(reflection, transmission) displayed images of the scene's fabric, (N, N, 3) in [0, 1]."""
    front = render_linear(scene, "front")
    back = render_linear(scene, "back")
    set_light(scene, None)
    return (display(front, rig), display(back, rig, coverage=back[..., 3], glow=True))
