"""Set Real-World Scale: the weave at its photographed size on a mesh object (bpy).

core/mesh_scale.py gives the rule: the mesh's centimetres per UV unit from its surface and UV
areas (the faces that use the fabric, object transform and scene unit scale applied), divided by
the material's centimetres per UV unit of the rig plane (scene/materials.material_uv_unit_cm),
is the uv scale. It is stored on the object (shader_params.OBJECT_UV_SCALE), where the node group
reads it in place of the material's uv scale: one material keeps the right weave size on every
object, whatever each one's UV layout. The material is not changed, nor the mesh, except that a UV
map chosen for the measure becomes the one the mesh renders with (the weave must use it too).
"""
from __future__ import annotations

import numpy as np

from ..core import mesh_scale, shader_params
from . import materials


def mesh_uv_unit_cm(obj, scene, uv_map: str = "", material=None) -> float:
    """Centimetres of the object's surface per UV unit of ``uv_map`` (default: the one the weave
    uses, the render-active map), over the faces that use ``material`` (default: every face)."""
    mesh = obj.data
    if not mesh.uv_layers:
        raise ValueError(f"{obj.name}: the mesh has no UV map; unwrap it first")
    layer = mesh.uv_layers.get(uv_map) if uv_map else next((uv for uv in mesh.uv_layers if uv.active_render),
                                                          mesh.uv_layers[0])
    if layer is None:
        raise ValueError(f"{obj.name}: no UV map named {uv_map!r}")
    mesh.calc_loop_triangles()
    count = len(mesh.loop_triangles)
    vertices = np.empty(count * 3, dtype=np.int64)
    loops = np.empty(count * 3, dtype=np.int64)
    slots = np.empty(count, dtype=np.int64)
    mesh.loop_triangles.foreach_get("vertices", vertices)
    mesh.loop_triangles.foreach_get("loops", loops)
    mesh.loop_triangles.foreach_get("material_index", slots)
    points = np.empty(len(mesh.vertices) * 3, dtype=np.float64)
    mesh.vertices.foreach_get("co", points)
    points = points.reshape(-1, 3)
    matrix = np.array(obj.matrix_world, dtype=np.float64)
    points = points @ matrix[:3, :3].T + matrix[:3, 3]
    uvs = np.empty(len(mesh.loops) * 2, dtype=np.float64)
    layer.data.foreach_get("uv", uvs)
    uvs = uvs.reshape(-1, 2)
    keep = np.ones(count, dtype=bool)
    if material is not None:
        indices = [i for i, slot in enumerate(obj.material_slots) if slot.material == material]
        keep = np.isin(slots, indices)
        if not keep.any():
            raise ValueError(f"{obj.name}: no face uses the material {material.name}")
    corners, uv_corners = points[vertices.reshape(-1, 3)[keep]], uvs[loops.reshape(-1, 3)[keep]]
    try:
        return mesh_scale.uv_unit_cm(corners, uv_corners, scene.unit_settings.scale_length or 1.0)
    except ValueError as exc:
        raise ValueError(f"{obj.name}: {exc}") from None


def set_real_world_scale(obj, material, scene, uv_map: str = "", width_cm: float | None = None) -> float:
    """Stores on ``obj`` the uv scale that gives ``material``'s weave its photographed size; returns it.

    ``width_cm``: the photographed width to use (default: the one the fit recorded). Raises
    ValueError (naming the object or material) when the width is unknown or the mesh has no usable
    UV map.
    """
    rig_unit = shader_params.uv_unit_cm(width_cm) if width_cm else materials.material_uv_unit_cm(material)
    if not rig_unit:
        raise ValueError(f"{material.name}: the photographed width is unknown; give the Photographed Width")
    value = mesh_uv_unit_cm(obj, scene, uv_map, material) / rig_unit
    obj[shader_params.OBJECT_UV_SCALE] = value
    if uv_map:
        obj.data.uv_layers[uv_map].active_render = True  # the map the weave (and this scale) uses
    return value
