"""Materials from fits: always a new material (or a new version of it), never an overwrite.

The node group itself is built by node_group.py; this module decides names, keeps fitted
materials alive (a new material has no user and Blender would drop it on save, so it gets a fake
user), records where a fit came from, and makes every fit an asset: a rendered preview
(scene/preview.py), the tags fabric, woven, the weave and a colour name, and the catalog
``Fabrics/<weave>`` (core/asset_catalogs.py), whose definition file is written beside the .blend
(:func:`write_catalogs`: when the batch writes its library, and when a file with fitted fabrics is
saved). The batch's materials go into a library .blend (:class:`AssetLibrary`).
"""
from __future__ import annotations

from pathlib import Path

import bpy

from ..core import asset_catalogs, shader_params
from . import node_group, preview

FIT_FOLDER_KEY = "woven_fabric_fit_folder"
WIDTH_KEY = node_group.WIDTH_KEY
# cm of fabric per UV unit of the fit's rig plane (shader_params.uv_unit_cm with the fit's rig):
# what Set Real-World Scale divides a mesh's own cm per UV unit by.
UV_UNIT_KEY = "woven_fabric_rig_uv_unit_cm"
CATALOG_KEY = "woven_fabric_catalog"   # the catalog path a fit's asset belongs to
TAGS_KEY = "woven_fabric_tags"         # the tags the fit gave it (the user's own are kept)


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


def material_uv_unit_cm(material) -> float | None:
    """cm of fabric per UV unit of the fit's rig plane; None while the photographed width is unknown."""
    if material.get(UV_UNIT_KEY):
        return float(material[UV_UNIT_KEY])
    width = material_width_cm(material)
    return shader_params.uv_unit_cm(width) if width else None


def new_fit_material(name: str, params: dict, width_cm: float | None = None, fit_folder: str | Path = "",
                     description: str = "", preview_image: str | Path | None = None):
    """A new material (a new version when the name is taken) holding the fitted parameters, marked
    as an asset (see :func:`mark_as_asset`)."""
    width_cm = fit_width_cm(params, width_cm)
    material = node_group.create_material(free_material_name(name), params, width_cm=width_cm)
    material.use_fake_user = True
    _record(material, params, width_cm, fit_folder)
    mark_as_asset(material, params, description or f"Woven fabric fitted in {fit_folder}", preview_image)
    return material


def update_fit_material(material, params: dict, width_cm: float | None = None, fit_folder: str | Path = ""):
    """Writes a fit into an existing Woven Fabric material (only when the user asked for it)."""
    width_cm = fit_width_cm(params, width_cm)
    node_group.apply_params(material, params, width_cm=width_cm)
    _record(material, params, width_cm, fit_folder)
    if material.asset_data is not None:
        mark_as_asset(material, params, material.asset_data.description)
    return material


def _record(material, params, width_cm, fit_folder):
    material[WIDTH_KEY] = float(width_cm or 0.0)
    material[FIT_FOLDER_KEY] = str(fit_folder)
    rig = params.get("rig") if isinstance(params.get("rig"), dict) else None
    material[UV_UNIT_KEY] = shader_params.uv_unit_cm(width_cm, rig) if width_cm else 0.0


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


def mark_as_asset(material, params: dict, description: str, preview_image: str | Path | None = None) -> None:
    """Marks the material as an asset: description, tags (fabric, woven, the weave, its colour),
    catalog ``Fabrics/<weave>`` and a rendered preview (the image file ``preview_image`` where Cycles
    cannot render)."""
    if material.asset_data is None:
        material.asset_mark()
    data = material.asset_data
    data.description = description
    wanted = asset_catalogs.tags(params)
    for tag in list(data.tags):  # the tags an earlier fit gave it go; the user's own stay
        if tag.name in _fit_tags(material) and tag.name not in wanted:
            data.tags.remove(tag)
    for tag in wanted:
        if tag not in data.tags:
            data.tags.new(tag)
    material[TAGS_KEY] = ",".join(wanted)
    path = asset_catalogs.catalog_path(str(params.get("pattern", "")))
    data.catalog_id = asset_catalogs.catalog_id(path)
    material[CATALOG_KEY] = path
    preview.preview_from_render(material, preview_image)


def _fit_tags(material) -> list[str]:
    return str(material.get(TAGS_KEY, "")).split(",")


def fabric_assets(materials=None) -> list:
    """The fitted fabrics marked as assets (among ``materials``, default: the file's)."""
    return [m for m in (materials if materials is not None else bpy.data.materials)
            if m.asset_data is not None and m.get(CATALOG_KEY)]


def write_catalogs(folder: str | Path, materials=None) -> None:
    """Writes the catalogs of the fitted fabrics into ``folder``'s catalog file and gives each
    material the UUID the file uses for its catalog. Raises OSError when the folder is not writable."""
    assets = fabric_assets(materials)
    if not assets:
        return
    ids = asset_catalogs.ensure_catalogs(folder, {m[CATALOG_KEY] for m in assets})
    for material in assets:
        material.asset_data.catalog_id = ids[material[CATALOG_KEY]]


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
        material = new_fit_material(name, params, width_cm, fit_folder, description, preview)
        self.materials.append(material)
        return material.name

    def write(self, path: Path) -> None:
        """Writes the materials into ``path`` and their catalogs into the catalog file beside it;
        raises OSError or RuntimeError when it cannot."""
        path.parent.mkdir(parents=True, exist_ok=True)
        write_catalogs(path.parent, self.materials)
        bpy.data.libraries.write(str(path), set(self.materials), fake_user=True, path_remap="ABSOLUTE")
