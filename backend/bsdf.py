"""The two-layer woven-fabric BSDF with its diffuse term (spec 4.5), evaluated per sample.

Per layer k (0 front, 1 back), specular part f_k = f_s + f_m (see :mod:`backend.spongecake`),
attenuation att_k, and::

    reflection   = f0(wi, wo) + f1(wi, wo) att0(wo) att0(wi) + diffuse_r
    transmission = f0(wi, wo) att1(wo) + f1(wi, wo) att0(wi) + diffuse_t

    diffuse = ((1 - w) k_d |wo_z| + w k_d c) / pi,  0 where every layer is a gap
    reflection:   c = max(0, wo . n0) if layer 0 is a yarn, else max(0, wo . n1)
    transmission: c = product over the yarn layers k of max(0, -wo . nk)

A gap behaves as a layer of zero thickness: f = 0 and att = 1 fall out of the formulas, so gaps
need no branches. Per-yarn parameters are picked per sample with the warp/weft masks of
:mod:`backend.geometry` (a weighted sum, whose gradient is a cheap reduction). All values are
cosine-weighted (they include the light-side cosine); multiply by intensity / distance^2 for
radiance.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from . import asggx, sggx
from .camera import LightSamples, SampleChunk
from .frames import dot
from .geometry import LayerGeometry, SampleGeometry
from .options import RenderOptions
from .param_tensors import ParamTensors
from .spongecake import attenuation, safe_cos, slab_g
from .yarn import scale_height


def multiple_albedo(specular_albedo: torch.Tensor, multiple_weight: torch.Tensor) -> torch.Tensor:
    """k_m = k_s ** (1 / w_m) per channel; 0 stays 0, with a finite gradient near 0."""
    positive = specular_albedo > 0
    base = specular_albedo.clamp_min(1e-6)
    return torch.where(positive, torch.exp(torch.log(base) / multiple_weight), torch.zeros_like(base))


@dataclass
class LayerLobes:
    """What the composition needs from one layer, for one light."""

    specular: torch.Tensor    # (3, S) f_s + f_m
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
    specular_albedo: torch.Tensor   # (3, S)
    multiple_albedo: torch.Tensor   # (3, S)
    normal: torch.Tensor            # (3, S) after height scaling
    fiber: torch.Tensor             # (3, S) after height scaling
    cos_in: torch.Tensor            # wi . o
    area_in: torch.Tensor           # sigma(wi) / wi_z with the single-scattering alpha
    att_in: torch.Tensor            # att(wi)


def layer_state(geo: LayerGeometry, fabric: ParamTensors, k_multiple: torch.Tensor, wi: torch.Tensor) -> LayerState:
    warp, weft = geo.warp, geo.weft
    gap = 1.0 - warp - weft

    def pick(values: torch.Tensor, fill: float = 0.0) -> torch.Tensor:
        return warp * values[0] + weft * values[1] + (gap * fill if fill else 0.0)

    def pick_rgb(values: torch.Tensor) -> torch.Tensor:
        out = warp[None] * values[0][:, None] + weft[None] * values[1][:, None]
        return out * geo.albedo_scale[None] if geo.albedo_scale is not None else out

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
        specular_albedo=pick_rgb(fabric.specular_albedo), multiple_albedo=pick_rgb(k_multiple),
        normal=normal, fiber=fiber, cos_in=cos_in, area_in=area_in,
        att_in=torch.exp(-thickness * area_in))


def layer_lobes(state: LayerState, wi: torch.Tensor, light: LightSamples, options: RenderOptions) -> LayerLobes:
    """f_s + f_m and att(wo) of one layer for one light (spec 4.2-4.4)."""
    wo, fiber = light.wo, state.fiber
    cos_out = dot(wo, fiber)
    cos_half = dot(light.half, fiber)
    wo_z = safe_cos(wo[2])
    inv_wi_z = 1.0 / safe_cos(wi[2])
    area_out = sggx.projected_area(cos_out, state.alpha) / wo_z
    single = sggx.ndf(cos_half * cos_half, state.alpha) * slab_g(state.thickness, state.area_in, area_out) * 0.25
    if options.multiple_lobe == "asggx":
        g_multiple = slab_g(state.thickness_multiple, state.area_in, area_out)
        multiple = asggx.lobe(state.cos_in, cos_out, state.alpha_multiple) * g_multiple * 0.5
    else:  # the ablation: plain SGGX with alpha_m, T_m, k_m (spec 4.3, last paragraph)
        area_in_m = sggx.projected_area(state.cos_in, state.alpha_multiple) * inv_wi_z
        area_out_m = sggx.projected_area(cos_out, state.alpha_multiple) / wo_z
        g_multiple = slab_g(state.thickness_multiple, area_in_m, area_out_m)
        multiple = sggx.ndf(cos_half * cos_half, state.alpha_multiple) * g_multiple * 0.25
    specular = (state.specular_albedo * (single * inv_wi_z)[None]
                + state.multiple_albedo * (multiple * inv_wi_z)[None])
    att_out = torch.exp(-state.thickness * area_out.abs())
    return LayerLobes(specular, att_out, dot(wo, state.normal))


def diffuse(fabric_albedo: torch.Tensor, weight: torch.Tensor, wo_z: torch.Tensor, c: torch.Tensor,
            any_yarn: torch.Tensor) -> torch.Tensor:
    """((1 - w) k_d |wo_z| + w k_d c) / pi where some layer is a yarn; (3, S)."""
    mix = ((1.0 - weight) * wo_z.abs() + weight * c) * any_yarn * (1.0 / math.pi)
    return fabric_albedo[:, None] * mix[None]


def eval_pair(chunk: SampleChunk, geometry: SampleGeometry, fabric: ParamTensors,
              options: RenderOptions) -> tuple[torch.Tensor, torch.Tensor]:
    """Cosine-weighted BSDF values (3, S) for the front light (reflection) and back light (transmission)."""
    wi = chunk.wi
    k_multiple = multiple_albedo(fabric.specular_albedo, fabric.multiple_weight)
    states = [layer_state(geo, fabric, k_multiple, wi) for geo in geometry.layers]
    any_yarn = 1.0 - geometry.no_yarn
    front_light = [layer_lobes(s, wi, chunk.front, options) for s in states]
    back_light = [layer_lobes(s, wi, chunk.back, options) for s in states]

    reflection = front_light[0].specular
    transmission = back_light[0].specular
    if len(states) == 2:
        att0_in = states[0].att_in
        reflection = reflection + front_light[1].specular * (front_light[0].att_out * att0_in)[None]
        transmission = (transmission * back_light[1].att_out[None]
                        + back_light[1].specular * att0_in[None])

    if options.diffuse:
        w = fabric.diffuse_normal_weight
        front_yarn = geometry.layers[0].is_yarn
        c_front = front_yarn * front_light[0].cos_normal.clamp_min(0)
        if len(states) == 2:
            c_front = c_front + (1.0 - front_yarn) * front_light[1].cos_normal.clamp_min(0)
        c_trans = torch.ones_like(c_front)
        for state, lobes in zip(states, back_light):
            yarn = state.geometry.is_yarn
            c_trans = c_trans * (yarn * (-lobes.cos_normal).clamp_min(0) + (1.0 - yarn))
        reflection = reflection + diffuse(fabric.diffuse_reflection, w, chunk.front.wo[2], c_front, any_yarn)
        transmission = transmission + diffuse(fabric.diffuse_transmission, w, chunk.back.wo[2], c_trans, any_yarn)
    return reflection, transmission
