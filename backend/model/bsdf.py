"""The two-layer woven-fabric BSDF with its diffuse term (spec 4.5), evaluated per sample.

Per layer k (0 front, 1 back), specular part f_k = f_s + f_m (see :mod:`backend.model.spongecake`),
attenuation att_k, and::

    reflection   = f0(wi, wo) + f1(wi, wo) att0(wo) att0(wi) + diffuse_r
    transmission = f0(wi, wo) att1(wo) + f1(wi, wo) att0(wi) + diffuse_t

    diffuse = ((1 - w) k_d |wo_z| + w k_d c) / pi,  0 where every layer is a gap
    reflection:   c = max(0, wo . n0) if layer 0 is a yarn, else max(0, wo . n1)
    transmission: c = product over the yarn layers k of max(0, -wo . nk)

A gap behaves as a layer of zero thickness: f = 0 and att = 1 fall out of the formulas, so gaps
need no branches. Per-yarn parameters are picked per sample with the warp/weft masks of
:mod:`backend.model.geometry` (a weighted sum, whose gradient is a cheap reduction). All values are
cosine-weighted (they include the light-side cosine); multiply by intensity / distance^2 for
radiance.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..core.options import RenderOptions
from . import sggx, spongecake
from .camera import LightSamples, SampleChunk
from .frames import dot
from .geometry import LayerGeometry, SampleGeometry
from .param_tensors import ParamTensors
from .spongecake import safe_cos
from .yarn import scale_height


def multiple_albedo(specular_albedo: torch.Tensor, multiple_weight: torch.Tensor) -> torch.Tensor:
    """k_m = k_s ** (1 / w_m) per channel; 0 stays 0, with a finite gradient near 0."""
    positive = specular_albedo > 0
    base = specular_albedo.clamp_min(1e-6)
    return torch.where(positive, torch.exp(torch.log(base) / multiple_weight), torch.zeros_like(base))


@dataclass
class LayerLobes:
    """What the composition needs from one layer, for one light."""

    single: torch.Tensor      # (S,) f_s / k_s
    multiple: torch.Tensor    # (S,) f_m / k_m
    att_out: torch.Tensor     # (S,) att(wo)
    cos_normal: torch.Tensor  # (S,) wo . n


@dataclass
class LayerState:
    """Per-sample parameters of one layer (differentiable), shared by both lights."""

    geometry: LayerGeometry
    alpha: torch.Tensor
    alpha_multiple: torch.Tensor
    thickness: torch.Tensor
    thickness_multiple: torch.Tensor
    normal: torch.Tensor            # (3, S) after height scaling
    fiber: torch.Tensor             # (3, S) after height scaling
    cos_in: torch.Tensor            # wi . o
    area_in: torch.Tensor           # sigma(wi) / wi_z with the single-scattering alpha
    att_in: torch.Tensor            # att(wi)


def layer_state(geo: LayerGeometry, fabric: ParamTensors, wi: torch.Tensor) -> LayerState:
    warp, weft = geo.warp, geo.weft
    gap = 1.0 - warp - weft

    def pick(values: torch.Tensor, fill: float = 0.0) -> torch.Tensor:
        return warp * values[0] + weft * values[1] + (gap * fill if fill else 0.0)

    alpha = pick(fabric.roughness, 1.0)
    beta = pick(fabric.height_scale, 1.0)
    if geo.height_offset is not None:
        beta = (beta + geo.height_offset).clamp_min(0.01)
    thickness = pick(fabric.thickness) * geo.thickness_scale
    normal, fiber = scale_height(geo.normal, geo.fiber, beta)
    cos_in = dot(wi, fiber)
    area_in = sggx.projected_area(cos_in, alpha) / safe_cos(wi[2])
    return LayerState(
        geometry=geo, alpha=alpha, alpha_multiple=pick(fabric.roughness_multiple, 1.0),
        thickness=thickness, thickness_multiple=pick(fabric.thickness_multiple) * geo.thickness_scale,
        normal=normal, fiber=fiber, cos_in=cos_in, area_in=area_in,
        att_in=spongecake.attenuation(thickness, area_in))


def layer_lobes(state: LayerState, wi: torch.Tensor, light: LightSamples, options: RenderOptions) -> LayerLobes:
    """f_s + f_m and att(wo) of one layer for one light (spec 4.2-4.4)."""
    wo, fiber = light.wo, state.fiber
    cos_out = dot(wo, fiber)
    cos_half = dot(light.half, fiber)
    cos2_half = cos_half * cos_half
    wo_z = safe_cos(wo[2])
    inv_wi_z = 1.0 / safe_cos(wi[2])
    area_out = sggx.projected_area(cos_out, state.alpha) / wo_z
    single = spongecake.single_scattering(cos2_half, state.area_in, area_out, state.alpha, state.thickness, inv_wi_z)
    if options.multiple_lobe == "asggx":
        multiple = spongecake.multiple_scattering_asggx(state.cos_in, cos_out, state.area_in, area_out,
                                                        state.alpha_multiple, state.thickness_multiple, inv_wi_z)
    else:
        multiple = spongecake.multiple_scattering_sggx(state.cos_in, cos_out, cos2_half, wo_z, state.alpha_multiple,
                                                       state.thickness_multiple, inv_wi_z)
    att_out = spongecake.attenuation(state.thickness, area_out)
    return LayerLobes(single, multiple, att_out, dot(wo, state.normal))


@dataclass
class ColourTerms:
    """Radiance as a sum of colour x scalar terms: ``radiance (3, S) = colours (3, K) @ weights (K, S)``.

    Every albedo is a per-yarn constant, so the renderer averages the K scalar weights over each
    pixel's samples first and mixes colours per pixel: far less work than (3, S) arithmetic.
    """

    colours: torch.Tensor   # (3, K)
    weights: torch.Tensor   # (K, S)

    def radiance(self) -> torch.Tensor:
        return self.colours @ self.weights


def _specular_terms(fabric_albedos, state: LayerState, lobes: LayerLobes, factor: torch.Tensor):
    """(colour, weight) pairs of one layer's specular lobes, scaled by `factor` (S,)."""
    geo = state.geometry
    if geo.albedo_scale is not None:
        factor = factor * geo.albedo_scale
    single, multiple = lobes.single * factor, lobes.multiple * factor
    specular, k_multiple = fabric_albedos
    return [(specular[0], geo.warp * single), (specular[1], geo.weft * single),
            (k_multiple[0], geo.warp * multiple), (k_multiple[1], geo.weft * multiple)]


def eval_pair(chunk: SampleChunk, geometry: SampleGeometry, fabric: ParamTensors,
              options: RenderOptions) -> tuple[ColourTerms, ColourTerms]:
    """Radiance terms of the front-lit (reflection) and back-lit (transmission) captures.

    Radiance = cosine-weighted BSDF * intensity / distance^2 (glow excluded: it is per pixel).
    """
    wi = chunk.wi
    albedos = (fabric.specular_albedo, multiple_albedo(fabric.specular_albedo, fabric.multiple_weight))
    states = [layer_state(geo, fabric, wi) for geo in geometry.layers]
    lobes_front = [layer_lobes(s, wi, chunk.front, options) for s in states]
    lobes_back = [layer_lobes(s, wi, chunk.back, options) for s in states]
    irr_front, irr_back = chunk.front.irradiance, chunk.back.irradiance

    terms_r = _specular_terms(albedos, states[0], lobes_front[0], irr_front)
    terms_t = []
    if len(states) == 2:
        att0_in = states[0].att_in
        terms_r += _specular_terms(albedos, states[1], lobes_front[1], irr_front * lobes_front[0].att_out * att0_in)
        terms_t += _specular_terms(albedos, states[0], lobes_back[0], irr_back * lobes_back[1].att_out)
        terms_t += _specular_terms(albedos, states[1], lobes_back[1], irr_back * att0_in)
    else:
        terms_t += _specular_terms(albedos, states[0], lobes_back[0], irr_back)

    if options.diffuse:
        any_yarn = 1.0 - geometry.no_yarn
        front_yarn = geometry.layers[0].is_yarn
        c_front = front_yarn * lobes_front[0].cos_normal.clamp_min(0)
        if len(states) == 2:
            c_front = c_front + (1.0 - front_yarn) * lobes_front[1].cos_normal.clamp_min(0)
        c_back = torch.ones_like(c_front)
        for state, lobes in zip(states, lobes_back):
            yarn = state.geometry.is_yarn
            c_back = c_back * (yarn * (-lobes.cos_normal).clamp_min(0) + (1.0 - yarn))
        w = fabric.diffuse_normal_weight
        terms_r.append((fabric.diffuse_reflection,
                        diffuse_weight(w, chunk.front.wo[2], c_front, any_yarn) * irr_front))
        terms_t.append((fabric.diffuse_transmission,
                        diffuse_weight(w, chunk.back.wo[2], c_back, any_yarn) * irr_back))
    return _pack(terms_r), _pack(terms_t)


def diffuse_weight(weight: torch.Tensor, wo_z: torch.Tensor, c: torch.Tensor, any_yarn: torch.Tensor) -> torch.Tensor:
    """((1 - w) |wo_z| + w c) / pi where some layer is a yarn; multiplies k_d."""
    return ((1.0 - weight) * wo_z.abs() + weight * c) * any_yarn * (1.0 / math.pi)


def _pack(terms) -> ColourTerms:
    return ColourTerms(torch.stack([c for c, _ in terms], 1), torch.stack([w for _, w in terms]))
