"""What the BSDF needs per sample that no optimised parameter changes: the camera and light
directions projected on each layer's yarn frame, computed once per geometry state and cached with it.

Height scaling by beta (spec 3.3, :mod:`backend.model.yarn`) maps the fiber o to
normalize(o_x, o_y, beta o_z) and the normal n to normalize(beta n_x, beta n_y, n_z), so for any
direction d::

    d . o' = (d_xy.o_xy + beta d_z o_z) / sqrt(|o_xy|^2 + beta^2 o_z^2)
    d . n' = (beta d_xy.n_xy + d_z n_z) / sqrt(beta^2 |n_xy|^2 + n_z^2)

Every term but beta is fixed by the camera samples and the weave geometry: :class:`Split` keeps the
in-plane and normal parts of d . v for wi, each light's wo and half vector, and the squared norms,
so an iteration evaluates a cosine with two multiply-adds and no 3-vector. The in-plane sums are
formed in float64 and stored in the render dtype; the z products are formed in the render dtype,
which gives the same numbers (the product of two floats is exact in float64, so rounding it once is
the float product: tests/test_render.py) with a third of the memory traffic. The lights' factors
(1 / wo_z, irradiance, the diffuse cosine) are folded here too.

The rig puts the camera and the front light above the fabric and the back light below it
(:class:`backend.core.rig.CaptureRig` refuses anything else), so wi_z > 0, wo_z > 0 for the front
light and wo_z < 0 for the back light at every sample; :func:`project` checks it, and
:mod:`backend.model.bsdf` uses the signs to pick the branch-free form of the slab's G.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import NamedTuple

import torch

from .camera import LightSamples, SampleChunk
from .geometry import LayerGeometry, SampleGeometry
from .spongecake import safe_cos


@dataclass
class Split:
    """d . v = ``plane`` + ``z`` before height scaling: d_x v_x + d_y v_y and d_z v_z, (S,) each."""

    plane: torch.Tensor
    z: torch.Tensor


@dataclass
class LightSplits:
    """One light's directions projected on one layer: wo and the half vector on the fiber, wo on the normal."""

    out: Split
    half: Split
    normal: Split


@dataclass
class LayerProjections:
    """One layer at every sample. Gaps have thickness 0 (no lobes, attenuation 1)."""

    weft: torch.Tensor              # (S,) 1 where the layer is a weft yarn: picks the weft's parameters
    yarn: torch.Tensor              # (S,) 1 where it is a yarn (warp or weft)
    thickness_scale: torch.Tensor   # (S,) tension factor, 0 on gaps
    albedo_scale: torch.Tensor | None
    height_offset: torch.Tensor | None
    fiber_plane2: torch.Tensor      # |o_xy|^2
    fiber_z2: torch.Tensor          # o_z^2
    normal_plane2: torch.Tensor     # |n_xy|^2
    normal_z2: torch.Tensor         # n_z^2
    wi: Split                       # wi on the fiber
    front: LightSplits
    back: LightSplits


@dataclass
class LightFactors:
    """Per-sample factors of one light that multiply the BSDF."""

    inv_wo_z: torch.Tensor          # 1 / wo_z (signed; a zero cosine counts as 1, spec 4.2)
    irradiance: torch.Tensor        # intensity / distance^2
    diffuse_flat: torch.Tensor      # |wo_z| irradiance / pi where some layer is a yarn, else 0 (times the
                                    # brightness of the yarn seen, with a yarn variation)
    diffuse_normal: torch.Tensor    # irradiance / pi where some layer is a yarn, else 0 (the same)
    cos_in_out: torch.Tensor        # wi . wo (the forward scattering's azimuth, backend.model.asggx)


@dataclass
class SampleProjections:
    layers: list[LayerProjections]  # front, then back (one layer in the single-layer variant)
    inv_wi_z: torch.Tensor          # 1 / wi_z
    front: LightFactors
    back: LightFactors
    no_yarn: torch.Tensor           # (S,) 1 where every layer is a gap (the glow shows through)

    def between(self, start: int, stop: int) -> "SampleProjections":
        """Samples [start, stop) (views, no copy)."""
        return _sliced(self, start, stop)


def _sliced(value, start: int, stop: int):
    if value is None:
        return None
    if isinstance(value, torch.Tensor):
        return value[start:stop]
    if isinstance(value, list):
        return [_sliced(v, start, stop) for v in value]
    return type(value)(**{f.name: _sliced(getattr(value, f.name), start, stop) for f in fields(value)})


class _Parts(NamedTuple):
    """A (3, S) direction as its in-plane part in float64 (2, S) and its z in the render dtype (S,)."""

    xy: torch.Tensor
    z: torch.Tensor


def _parts(vector: torch.Tensor, xy: torch.Tensor | None = None) -> _Parts:
    """``vector`` (3, S, render dtype) as :class:`_Parts` (``xy``: its x and y in float64, where known)."""
    return _Parts(vector[:2].to(torch.float64) if xy is None else xy, vector[2])


def _split(direction: _Parts, vector: _Parts, dtype) -> Split:
    d, v = direction.xy, vector.xy
    return Split((d[0] * v[0] + d[1] * v[1]).to(dtype), direction.z * vector.z)


def _directions(chunk: SampleChunk) -> tuple[_Parts, ...]:
    """wi, the front light's wo and half vector, the back light's, as :class:`_Parts`."""
    return tuple(_parts(v, xy) for v, xy in zip((chunk.wi, chunk.front.wo, chunk.front.half, chunk.back.wo,
                                                  chunk.back.half), chunk.wide))


def _plane2(v: _Parts, dtype) -> torch.Tensor:
    return (v.xy[0] * v.xy[0] + v.xy[1] * v.xy[1]).to(dtype)


def _on_fiber(fiber: _Parts, directions: tuple[_Parts, ...], dtype) -> dict:
    """The fields of :class:`LayerProjections` that the fiber direction sets (the lights' as (out, half))."""
    wi, front_wo, front_half, back_wo, back_half = directions
    return {"fiber_plane2": _plane2(fiber, dtype), "fiber_z2": fiber.z * fiber.z, "wi": _split(wi, fiber, dtype),
            "front": (_split(front_wo, fiber, dtype), _split(front_half, fiber, dtype)),
            "back": (_split(back_wo, fiber, dtype), _split(back_half, fiber, dtype))}


def _layer(geo: LayerGeometry, directions: tuple[_Parts, ...], dtype) -> LayerProjections:
    normal = _parts(geo.normal)
    on_fiber = _on_fiber(_parts(geo.fiber), directions, dtype)
    front_wo, back_wo = directions[1], directions[3]
    yarn = geo.is_yarn
    return LayerProjections(
        weft=geo.weft, yarn=yarn, thickness_scale=geo.thickness_scale * yarn, albedo_scale=geo.albedo_scale,
        height_offset=geo.height_offset, fiber_plane2=on_fiber["fiber_plane2"], fiber_z2=on_fiber["fiber_z2"],
        normal_plane2=_plane2(normal, dtype), normal_z2=normal.z * normal.z, wi=on_fiber["wi"],
        front=LightSplits(*on_fiber["front"], _split(front_wo, normal, dtype)),
        back=LightSplits(*on_fiber["back"], _split(back_wo, normal, dtype)))


def _light(samples: LightSamples, wi: torch.Tensor, any_yarn: torch.Tensor) -> LightFactors:
    wo_z = safe_cos(samples.wo[2])
    diffuse = samples.irradiance * any_yarn * (1.0 / math.pi)
    return LightFactors(1.0 / wo_z, samples.irradiance, wo_z.abs() * diffuse, diffuse, (wi * samples.wo).sum(0))


def project(chunk: SampleChunk, geometry: SampleGeometry) -> SampleProjections:
    """The fixed part of the BSDF inputs of one chunk in one geometry state (no gradients)."""
    if not ((chunk.wi[2] > 0).all() and (chunk.front.wo[2] > 0).all() and (chunk.back.wo[2] < 0).all()):
        raise ValueError("the camera and the front light must be above the fabric, the back light below it")
    dtype = chunk.wi.dtype
    any_yarn = 1.0 - geometry.no_yarn
    if geometry.diffuse_scale is not None:  # the yarn variation's brightness of the yarn seen
        any_yarn = any_yarn * geometry.diffuse_scale
    directions = _directions(chunk)
    return SampleProjections(layers=[_layer(geo, directions, dtype) for geo in geometry.layers],
                             inv_wi_z=1.0 / chunk.wi[2], front=_light(chunk.front, chunk.wi, any_yarn),
                             back=_light(chunk.back, chunk.wi, any_yarn), no_yarn=geometry.no_yarn)


def retwisted(projections: SampleProjections, chunk: SampleChunk, fibers: list[torch.Tensor]) -> SampleProjections:
    """The projections of the same state at another twist: ``projections`` with each layer's fiber
    directions replaced by ``fibers`` ((3, S) each, :func:`backend.model.geometry.twisted_fibers`), the
    numbers :func:`project` gives that state. Only the fiber's fields are computed again, for a
    discrete search's twist steps."""
    directions, dtype = _directions(chunk), chunk.wi.dtype
    layers = []
    for layer, fiber in zip(projections.layers, fibers, strict=True):
        on_fiber = _on_fiber(_parts(fiber), directions, dtype)
        layers.append(replace(layer, fiber_plane2=on_fiber["fiber_plane2"], fiber_z2=on_fiber["fiber_z2"],
                              wi=on_fiber["wi"], front=LightSplits(*on_fiber["front"], layer.front.normal),
                              back=LightSplits(*on_fiber["back"], layer.back.normal)))
    return replace(projections, layers=layers)
