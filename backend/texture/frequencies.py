"""Where a woven sample's tile lattice shows in the image's spectrum.

The camera looks straight down at a plane parallel to its film, so a weave is an exactly periodic
texture in the image. With ``tiles = (tu, tv)`` repeats over the plane of side P, the visible square
of side V holds ``a = tu V / P`` tiles across and ``b = tv V / P`` down (:func:`lattice_of`), and the
luminance spectrum concentrates on the harmonics ``(m a, n b)`` (integers m, n), in cycles per image.

A sample turned in the holder turns them: its warps by theta_1 and its wefts by theta_2 (the rig's
``yarn_angles_deg``: rotation +- skew / 2, counter-clockwise as the camera sees it), and the fabric
frequency (f1 across the warps, f2 across the wefts) shows at

    fx = f1 cos(theta_1) + f2 sin(theta_2),    fy = -f1 sin(theta_1) + f2 cos(theta_2)

(:func:`turned_frequencies`; fx to the right, fy down the image). The image's N pixels fold a
frequency beyond Nyquist back into [-N/2, N/2] (:func:`fold`).
"""
from __future__ import annotations

import math

import numpy as np

from ..core.rig import yarn_angles
from ..core.weave import PRESETS

UNTURNED = (1.0, 0.0, 0.0, 1.0)  # the factors of turn() for an unturned, unsheared sample


def lattice_of(tiles, rig) -> tuple[float, float]:
    """(a, b): tiles across and down the image of ``rig`` (a CaptureRig) for a ``tiles`` pair."""
    scale = rig.view_size / rig.plane_size
    return tiles[0] * scale, tiles[1] * scale


def yarns_in_view(pattern: str, tiles, rig) -> float | None:
    """Yarns across the image on the weave's denser axis (warps across, wefts down), or None when
    ``pattern`` is not a preset."""
    weave = PRESETS.get(pattern)
    if weave is None:
        return None
    a, b = lattice_of(tiles, rig)
    return max(weave.cols * a, weave.rows * b)


def turn(rotation_deg: float, skew_deg: float) -> tuple[float, float, float, float]:
    """(cos theta_1, sin theta_2, -sin theta_1, cos theta_2): the factors of :func:`turned_frequencies`;
    :data:`UNTURNED` (this very tuple) for an unturned sample."""
    if rotation_deg == 0 and skew_deg == 0:
        return UNTURNED
    t1, t2 = (math.radians(angle) for angle in yarn_angles(rotation_deg, skew_deg))
    return math.cos(t1), math.sin(t2), -math.sin(t1), math.cos(t2)


def turned_by(f1, f2, cos_1, sin_2, minus_sin_1, cos_2):
    """:func:`turned_frequencies` from the factors of :func:`turn` (numbers or arrays that broadcast)."""
    return cos_1 * f1 + sin_2 * f2, minus_sin_1 * f1 + cos_2 * f2


def turned_frequencies(f1, f2, rotation_deg: float, skew_deg: float = 0.0):
    """Image frequencies (fx, fy) of the fabric frequency (f1, f2) of a sample turned by
    ``rotation_deg`` and sheared by ``skew_deg`` (the module's formula). Arrays broadcast."""
    if rotation_deg == 0 and skew_deg == 0:
        return f1, f2
    return turned_by(f1, f2, *turn(rotation_deg, skew_deg))


def fabric_frequencies(fx, fy, rotation_deg: float, skew_deg: float = 0.0):
    """The inverse of :func:`turned_frequencies`: image frequencies -> (f1, f2) of the fabric,

        f1 = (fx cos(theta_2) - fy sin(theta_2)) / D,    f2 = (fx sin(theta_1) + fy cos(theta_1)) / D,

    D = cos(theta_1 - theta_2): f1 reads the frequency along the normal of the wefts, f2 along the
    normal of the warps."""
    if rotation_deg == 0 and skew_deg == 0:
        return fx, fy
    t1, t2 = (math.radians(angle) for angle in yarn_angles(rotation_deg, skew_deg))
    d = math.cos(t1 - t2)
    return (math.cos(t2) * fx - math.sin(t2) * fy) / d, (math.sin(t1) * fx + math.cos(t1) * fy) / d


def yarn_vector_angles(u, v) -> tuple[float, float]:
    """(theta_1, theta_2), degrees: the yarn angles of the image vectors u (the fabric's harmonic
    (1, 0)) and v (its (0, 1)), as :func:`turned_frequencies` places them:
    u = |u| (cos theta_1, -sin theta_1), v = |v| (sin theta_2, cos theta_2)."""
    return math.degrees(math.atan2(-u[1], u[0])), math.degrees(math.atan2(v[0], v[1]))


def fold(f: np.ndarray, size: int) -> np.ndarray:
    """Frequency (cycles per image) after sampling with ``size`` pixels: folded into [-size/2, size/2]."""
    return (f + size / 2) % size - size / 2
