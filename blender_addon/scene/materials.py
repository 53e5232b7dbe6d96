"""Materials from fits: always a new material (or a new version of it), never an overwrite.

The node group itself is built by node_group.py; this module decides names, keeps fitted
materials alive (a new material has no user and Blender would drop it on save, so it gets a fake
user), records where a fit came from, marks materials as assets with a cheap preview (the fit's
own rendering of the reflection photo, no render job), and writes the batch's materials into a
library .blend (:class:`AssetLibrary`).
"""
from __future__ import annotations

from pathlib import Path

import bpy

from . import node_group

FIT_FOLDER_KEY = "woven_fabric_fit_folder"
WIDTH_KEY = node_group.WIDTH_KEY
PREVIEW_SIZE = 128


def free_material_name(name: str) -> str:
    """``name`` if no material has it, else the next free ``name.001``, ``name.002``, ..."""
    if name not in bpy.data.materials:
        return name
    for number in range(1, 10000):
        candidate = f"{name}.{number:03d}"
        if candidate not in bpy.data.materials:
            return candidate
    raise RuntimeError(f"no free material name for {name!r}")


def fit_width_cm(params: dict, width_cm: float | None = None) -> float | None:
    """The photographed width: the one given, else the one the fit's rig recorded, else unknown."""
    if width_cm:
        return float(width_cm)
    rig = params.get("rig") if isinstance(params.get("rig"), dict) else {}
    return float(rig["width_cm"]) if rig.get("width_cm") else None


def material_width_cm(material) -> float | None:
    return float(material[WIDTH_KEY]) if material.get(WIDTH_KEY) else None


def new_fit_material(name: str, params: dict, width_cm: float | None = None, fit_folder: str | Path = ""):
    """A new material (a new version when the name is taken) holding the fitted parameters."""
    width_cm = fit_width_cm(params, width_cm)
    material = node_group.create_material(free_material_name(name), params, width_cm=width_cm)
    material.use_fake_user = True
    _record(material, width_cm, fit_folder)
    return material


def update_fit_material(material, params: dict, width_cm: float | None = None, fit_folder: str | Path = ""):
    """Writes a fit into an existing Woven Fabric material (only when the user asked for it)."""
    width_cm = fit_width_cm(params, width_cm)
    node_group.apply_params(material, params, width_cm=width_cm)
    _record(material, width_cm, fit_folder)
    return material


def _record(material, width_cm, fit_folder):
    material[WIDTH_KEY] = float(width_cm or 0.0)
    material[FIT_FOLDER_KEY] = str(fit_folder)


def is_fabric_material(material) -> bool:
    """True when the material contains the Woven Fabric node group."""
    if material is None or material.node_tree is None:
        return False
    name = node_group.NODE_GROUP_NAME
    return any(node.type == "GROUP" and node.node_tree and node.node_tree.name.split(".")[0] == name
               for node in material.node_tree.nodes)


def assign(material, meshes) -> None:
    """Gives each mesh object ``material`` in a new slot covering all its faces (existing slots stay)."""
    for obj in meshes:
        obj.data.materials.append(material)
        obj.active_material_index = len(obj.material_slots) - 1
        for polygon in obj.data.polygons:
            polygon.material_index = obj.active_material_index


def mark_as_asset(material, params: dict, description: str, preview_image: str | Path | None = None):
    """Marks the material as an asset with a description, tags and, when possible, a preview."""
    material.asset_mark()
    data = material.asset_data
    data.description = description
    for tag in ("fabric", "woven", str(params.get("pattern", ""))):
        if tag and tag not in data.tags:
            data.tags.new(tag)
    if preview_image is not None:
        set_preview_from_image(material, preview_image)


def set_preview_from_image(block, path: str | Path, size: int = PREVIEW_SIZE) -> bool:
    """Uses an image file as the data-block's preview; False when the image cannot be read."""
    try:
        image = bpy.data.images.load(str(path), check_existing=False)
    except RuntimeError:
        return False
    try:
        image.scale(size, size)
        pixels = [0.0] * (size * size * 4)
        image.pixels.foreach_get(pixels)
        preview = block.preview_ensure()
        preview.image_size = (size, size)
        preview.image_pixels_float.foreach_set(pixels)
        return True
    except (RuntimeError, ValueError):
        return False
    finally:
        bpy.data.images.remove(image)


class AssetLibrary:
    """The batch's materials (core/batch.py adds one per fitted pair), written into one .blend.

    ``bpy.data.libraries.write`` stores only these materials and what they use, so the running
    session is never saved over.
    """

    def __init__(self):
        self.materials = []

    def add(self, name: str, params: dict, width_cm: float | None, fit_folder: Path, description: str,
            preview: str | Path | None) -> str:
        """A new asset material for a fit; returns its name."""
        material = new_fit_material(name, params, width_cm, fit_folder)
        mark_as_asset(material, params, description, preview)
        self.materials.append(material)
        return material.name

    def write(self, path: Path) -> None:
        """Writes the materials into ``path``; raises OSError or RuntimeError when it cannot."""
        path.parent.mkdir(parents=True, exist_ok=True)
        bpy.data.libraries.write(str(path), set(self.materials), fake_user=True, path_remap="ABSOLUTE")
