"""The weave at its photographed size on any mesh: the uv scale of a mesh (numpy, no bpy).

The material's ``tiles`` count pattern repeats per UV unit of the rig plane, one UV unit being
``uv_unit_cm(width_cm)`` centimetres of fabric (shader_params). On a mesh whose UV unit square
covers ``s`` centimetres of surface, the weave has its real size when the tiles are multiplied by

    uv scale = s / (plane_size * width_cm / V)                    (shader_params.uv_scale)

and, for a mesh whose UV layout stretches evenly, ``s`` follows from areas:

    s = 100 * scale_length * sqrt(surface area / UV area)         (centimetres)

with the surface area in scene units (object transform applied), ``scale_length`` the metres per
scene unit and the UV area in UV units squared, both summed over the faces that use the fabric.
A layout whose parts are stretched differently gets their area-weighted mean scale.
"""
from __future__ import annotations

import numpy as np


def triangle_areas(corners: np.ndarray) -> np.ndarray:
    """Areas of triangles given as (T, 3, D) corner coordinates (D = 2 or 3)."""
    corners = np.asarray(corners, dtype=np.float64)
    a, b = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    if corners.shape[-1] == 2:
        return 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    return 0.5 * np.linalg.norm(np.cross(a, b), axis=1)


def uv_unit_cm(surface_triangles: np.ndarray, uv_triangles: np.ndarray, scale_length: float = 1.0) -> float:
    """Centimetres of surface covered by one UV unit: ``100 * scale_length * sqrt(area / UV area)``.

    ``surface_triangles``: (T, 3, 3) corners in scene units; ``uv_triangles``: (T, 3, 2) their UVs.
    Raises ValueError when the faces have no UV area (no unwrap, or every UV at one point).
    """
    area = float(triangle_areas(surface_triangles).sum())
    uv_area = float(triangle_areas(uv_triangles).sum())
    if not len(surface_triangles) or area <= 0.0:
        raise ValueError("the faces have no surface area")
    if uv_area <= 1e-12 * max(area, 1.0):
        raise ValueError("the UV map has no area on these faces: unwrap the mesh first")
    return 100.0 * float(scale_length) * (area / uv_area) ** 0.5
