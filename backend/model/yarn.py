"""Bent-cylinder yarn: surface normal n and fiber direction o (spec 3.2), height scaling (3.3).

In the segment's local frame (a warp's: x across to the right, y along up the image)::

    n = ( sin v,  sin u cos v,  cos u cos v )
    o = ( -cos v sin psi,
           cos u cos psi + sin u sin v sin psi,
          -sin u cos psi + cos u sin v sin psi )

Both are unit and orthogonal by construction. A weft's local frame is rotated to the world by
(x, y, z) -> (y, -x, z). Flat segments use n = o = (0, 0, 1); gaps n = (0, 0, 1), o = (0, 1, 0).

Height scaling by beta: n' = normalize(beta n_x, beta n_y, n_z), and o is kept perpendicular by
scaling its x, y by k = -(n'_z o_z) / (n'_x o_x + n'_y o_y). Because n . o = 0 before scaling,
that k equals 1 / beta whenever n_z o_z != 0 (and when it is 0, o' does not depend on k, or the spec's
k = 1 applies to a vector that needs no change), so o' = normalize(o_x, o_y, beta o_z): the same
vector without the 0/0 that the literal formula meets at segment centres. The literal formula
lives in :mod:`tests.oracles.reference`, and a test checks both agree.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from .frames import normalize
from .layers import GAP, WEFT, Layer


def local_frame(layer: Layer, twist_rad: tuple[float, float]) -> tuple[torch.Tensor, torch.Tensor]:
    """World-space (n, o), each (3, *batch), before height scaling.

    Each world component is picked once from the local frame's (a weft's swapped, flat segments'
    and gaps' constants) rather than by whole-vector selects: a new discrete state of a fit computes
    this for every sample of both layers, and its passes over memory are most of the state's cost."""
    angles = _Angles.of(layer)
    return _normal(angles), _fiber(angles, twist_rad)


def fiber_direction(layer: Layer, twist_rad: tuple[float, float]) -> torch.Tensor:
    """World-space o (3, *batch) before height scaling: :func:`local_frame`'s, with the same numbers
    (the only part of the frame a twist changes)."""
    return _fiber(_Angles.of(layer), twist_rad)


@dataclass
class _Angles:
    """A layer's sines and cosines of u and v, and the masks that pick a frame's components."""

    su: torch.Tensor
    cu: torch.Tensor
    sv: torch.Tensor
    cv: torch.Tensor
    is_weft: torch.Tensor
    gap: torch.Tensor
    flat: torch.Tensor
    either: torch.Tensor   # flat or gap

    @classmethod
    def of(cls, layer: Layer) -> "_Angles":
        u, v = layer.u, layer.v
        gap = layer.yarn == GAP
        flat = layer.flat & ~gap
        return cls(torch.sin(u), torch.cos(u), torch.sin(v), torch.cos(v), layer.yarn == WEFT, gap, flat, flat | gap)


def _normal(a: _Angles) -> torch.Tensor:
    n0, n1, n2 = a.sv, a.su * a.cv, a.cu * a.cv
    # a weft's local frame turns to the world as (x, y, z) -> (y, -x, z)
    return torch.stack((torch.where(a.either, 0.0, torch.where(a.is_weft, n1, n0)),
                        torch.where(a.either, 0.0, torch.where(a.is_weft, -n0, n1)),
                        torch.where(a.either, 1.0, n2)))


def _fiber(a: _Angles, twist_rad: tuple[float, float]) -> torch.Tensor:
    psi = torch.where(a.is_weft, twist_rad[1], twist_rad[0]).to(a.su.dtype)
    sp, cp = torch.sin(psi), torch.cos(psi)
    su, cu, sv, cv = a.su, a.cu, a.sv, a.cv
    o0, o1, o2 = -cv * sp, cu * cp + su * sv * sp, -su * cp + cu * sv * sp
    return torch.stack((torch.where(a.either, 0.0, torch.where(a.is_weft, o1, o0)),
                        torch.where(a.flat, 0.0, torch.where(a.gap, 1.0, torch.where(a.is_weft, -o0, o1))),
                        torch.where(a.flat, 1.0, torch.where(a.gap, 0.0, o2))))


def scale_height(n: torch.Tensor, o: torch.Tensor, beta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Height-field scaling (spec 3.3) with per-sample beta; differentiable in beta."""
    n_scaled = normalize(torch.stack((beta * n[0], beta * n[1], n[2])))
    o_scaled = normalize(torch.stack((o[0], o[1], beta * o[2])))
    return n_scaled, o_scaled
