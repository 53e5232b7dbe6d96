"""The two-layer woven-fabric BSDF with its diffuse term (spec 4.5), evaluated per sample.

Per layer k (0 front, 1 back), specular part f_k = f_s + f_m (see :mod:`backend.model.spongecake`),
attenuation att_k, and::

    reflection   = f0(wi, wo) + f1(wi, wo) att0(wo) att0(wi) + diffuse_r
    transmission = f0(wi, wo) att1(wo) + f1(wi, wo) att0(wi) + diffuse_t

In transmission (the back light) each layer's multiple-scattering lobe carries the forward
scattering's azimuthal factor A_k (:mod:`backend.model.asggx`; k = 0 is the paper's lobe).

    diffuse = ((1 - w) k_d |wo_z| + w k_d c) / pi,  0 where every layer is a gap
    reflection:   c = max(0, wo . n0) if layer 0 is a yarn, else max(0, wo . n1)
    transmission: c = product over the yarn layers k of max(0, -wo . nk)

A gap behaves as a layer of zero thickness: f = 0 and att = 1 fall out of the formulas, so gaps
need no branches. All values are cosine-weighted (they include the light-side cosine); multiply by
intensity / distance^2 for radiance.

Evaluation works on :class:`backend.model.projections.SampleProjections`, the part of the inputs
that the optimised parameters do not change, so an iteration touches only per-sample scalars:
per-yarn constants (1 - alpha^2, 1 / alpha^2 - 1, 1 / (pi alpha), T, beta) are formed on the two
yarns' values and picked per sample by the weft mask (``lerp``, exact at 0 and 1). With the camera
and the front light above the fabric and the back light below it, A_i and A_o have the same sign
for the front light (G = T phi(T (A_i + A_o))) and opposite signs for the back light, where
exp(-T min(A_i, |A_o|)) = max(att(wi), att(wo)) is already at hand for the single lobe.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..core.options import RenderOptions
from . import asggx, sggx
from .camera import SampleChunk
from .geometry import SampleGeometry
from .param_tensors import ParamTensors
from .projections import LayerProjections, LightFactors, SampleProjections, Split, project
from .spongecake import slab_g_from


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
class LayerOptics:
    att_in: torch.Tensor      # (S,) att(wi)
    front: LayerLobes
    back: LayerLobes


@dataclass
class ColourTerms:
    """Radiance as a sum of colour x scalar terms: ``radiance (3, S) = colours (3, K) @ weights (K, S)``.

    Every albedo is a per-yarn constant, so the renderer averages the K scalar weights over each
    pixel's samples before multiplying by the colours: less work than (3, S) arithmetic. The terms
    are k_s warp, k_s weft, k_m warp, k_m weft, k_d (each gathering both layers).
    """

    colours: torch.Tensor   # (3, K)
    weights: torch.Tensor   # (K, S)

    def radiance(self) -> torch.Tensor:
        return self.colours @ self.weights


def _pick(per_yarn: torch.Tensor, weft: torch.Tensor) -> torch.Tensor:
    """(2,) warp/weft values -> (S,): the weft's where ``weft`` is 1, the warp's elsewhere."""
    return torch.lerp(per_yarn[0], per_yarn[1], weft)


def layer_optics(layer: LayerProjections, fabric: ParamTensors, samples: SampleProjections,
                 options: RenderOptions, forward: torch.Tensor | None = None) -> LayerOptics:
    """att(wi), and f_s, f_m, att(wo), wo . n for both lights, of one layer (spec 3.3, 4.1-4.4);
    ``forward``: the yarns' forward scattering k (2,), None for the paper's lobe."""
    weft = layer.weft
    alpha, alpha_m = fabric.roughness, fabric.roughness_multiple
    flattening = _pick(1.0 - alpha * alpha, weft)
    ndf_shape, ndf_scale = _pick(1.0 / (alpha * alpha) - 1.0, weft), _pick(1.0 / (torch.pi * alpha), weft)
    ndf_shape_m, ndf_scale_m = _pick(1.0 / (alpha_m * alpha_m) - 1.0, weft), _pick(1.0 / (torch.pi * alpha_m), weft)
    thickness = _pick(fabric.thickness, weft) * layer.thickness_scale
    thickness_m = _pick(fabric.thickness_multiple, weft) * layer.thickness_scale
    beta = _pick(fabric.height_scale, weft)
    if layer.height_offset is not None:
        beta = (beta + layer.height_offset).clamp_min(0.01)
    beta2 = beta * beta
    inv_fiber = torch.rsqrt(torch.addcmul(layer.fiber_plane2, beta2, layer.fiber_z2))
    inv_normal = torch.rsqrt(torch.addcmul(layer.normal_z2, beta2, layer.normal_plane2))

    def on_fiber(split: Split) -> torch.Tensor:
        return torch.addcmul(split.plane, beta, split.z) * inv_fiber

    cos_in = on_fiber(layer.wi)
    cos2_in = cos_in * cos_in
    area_in = sggx.projected_area_from(cos2_in, flattening) * samples.inv_wi_z
    att_in = torch.exp(-thickness * area_in)
    quarter_inv_wi_z = 0.25 * samples.inv_wi_z
    sin2_in = 1.0 - cos2_in
    if forward is not None:
        forward = _pick(forward, weft)

    def lobes(splits, light: LightFactors, same_side: bool) -> LayerLobes:
        cos_out = on_fiber(splits.out)
        cos_half = on_fiber(splits.half)
        cos2_out = cos_out * cos_out
        area_out = sggx.projected_area_from(cos2_out, flattening) * light.inv_wo_z
        att_out = torch.exp(-thickness * area_out.abs())
        ndf = sggx.ndf_from(cos_half * cos_half, ndf_shape, ndf_scale)
        if options.multiple_lobe == "asggx":
            ndf_m = sggx.ndf_from(asggx.half_sin2(cos_in, cos_out, sin2_in, 1.0 - cos2_out), ndf_shape_m, ndf_scale_m)
            area_in_m, area_out_m = area_in, area_out
        else:  # the ablation: the single-scattering lobe with alpha_m, T_m
            ndf_m = sggx.ndf_from(cos_half * cos_half, ndf_shape_m, ndf_scale_m)
            flattening_m = _pick(1.0 - alpha_m * alpha_m, weft)
            area_in_m = sggx.projected_area_from(cos2_in, flattening_m) * samples.inv_wi_z
            area_out_m = sggx.projected_area_from(cos2_out, flattening_m) * light.inv_wo_z
        if forward is not None and not same_side:  # light crossing the layer: asggx.forward_peak
            ndf_m = ndf_m * asggx.forward_peak(cos_in, cos_out, sin2_in, 1.0 - cos2_out, light.cos_in_out, forward)
        if same_side:  # A_i, A_o > 0: min(p, q) = 0, |q - p| = A_i + A_o
            g = slab_g_from(thickness, area_in + area_out)
            g_m = slab_g_from(thickness_m, area_in_m + area_out_m)
        else:  # A_o < 0 < A_i: min(p, q) = min(A_i, |A_o|), |q - p| = |A_i + A_o|
            g = slab_g_from(thickness, (area_in + area_out).abs(), torch.maximum(att_in, att_out))
            near_m = torch.minimum(area_in_m, -area_out_m)
            g_m = slab_g_from(thickness_m, (area_in_m + area_out_m).abs(), torch.exp(-thickness_m * near_m))
        lobe_factor = 2.0 if options.multiple_lobe == "asggx" else 1.0  # 1 / (2 |wi_z|) vs 1 / (4 |wi_z|)
        cos_normal = torch.addcmul(splits.normal.z, beta, splits.normal.plane) * inv_normal
        return LayerLobes(ndf * g * quarter_inv_wi_z, ndf_m * g_m * (lobe_factor * quarter_inv_wi_z),
                          att_out, cos_normal)

    return LayerOptics(att_in, lobes(layer.front, samples.front, True), lobes(layer.back, samples.back, False))


class _Slots:
    """Accumulates per-layer lobes into the k_s / k_m warp / weft weights of one light."""

    def __init__(self):
        self.weights: list[torch.Tensor | None] = [None] * 4  # k_s warp, k_s weft, k_m warp, k_m weft

    def add(self, layer: LayerProjections, lobes: LayerLobes, factor: torch.Tensor) -> None:
        if layer.albedo_scale is not None:
            factor = factor * layer.albedo_scale
        for slot, lobe in ((0, lobes.single), (2, lobes.multiple)):
            value = lobe * factor
            weft = layer.weft * value  # the weft mask is 0 or 1 and gaps give 0: the split is exact
            for index, part in ((slot, value - weft), (slot + 1, weft)):
                current = self.weights[index]
                self.weights[index] = part if current is None else current + part


def eval_projected(samples: SampleProjections, fabric: ParamTensors,
                   options: RenderOptions) -> tuple[ColourTerms, ColourTerms]:
    """Radiance terms of the front-lit (reflection) and back-lit (transmission) captures.

    Radiance = cosine-weighted BSDF * intensity / distance^2 (glow excluded: it is per pixel).
    """
    layers = samples.layers
    forward = forward_scattering(fabric, options)
    optics = [layer_optics(layer, fabric, samples, options, forward) for layer in layers]
    irr_front, irr_back = samples.front.irradiance, samples.back.irradiance
    reflection, transmission = _Slots(), _Slots()
    reflection.add(layers[0], optics[0].front, irr_front)
    if len(layers) == 2:
        att0_in = optics[0].att_in
        reflection.add(layers[1], optics[1].front, irr_front * optics[0].front.att_out * att0_in)
        transmission.add(layers[0], optics[0].back, irr_back * optics[1].back.att_out)
        transmission.add(layers[1], optics[1].back, irr_back * att0_in)
    else:
        transmission.add(layers[0], optics[0].back, irr_back)

    ks = fabric.specular_albedo
    km = multiple_albedo(ks, fabric.multiple_weight)
    colours = [ks[0], ks[1], km[0], km[1]]
    weights_r, weights_t = reflection.weights, transmission.weights
    if options.diffuse:
        c_front = optics[0].front.cos_normal.clamp_min(0)
        if len(layers) == 2:  # the back layer's normal where the front is a gap
            c_front = torch.lerp(optics[1].front.cos_normal.clamp_min(0), c_front, layers[0].yarn)
        else:
            c_front = c_front * layers[0].yarn
        c_back = None
        for layer, layer_optics_ in zip(layers, optics):
            factor = torch.lerp(torch.ones((), dtype=c_front.dtype, device=c_front.device),
                                (-layer_optics_.back.cos_normal).clamp_min(0), layer.yarn)
            c_back = factor if c_back is None else c_back * factor
        w = fabric.diffuse_normal_weight
        weights_r = weights_r + [diffuse_weight(w, samples.front, c_front)]
        weights_t = weights_t + [diffuse_weight(w, samples.back, c_back)]
        return (ColourTerms(torch.stack(colours + [fabric.diffuse_reflection], 1), torch.stack(weights_r)),
                ColourTerms(torch.stack(colours + [fabric.diffuse_transmission], 1), torch.stack(weights_t)))
    return ColourTerms(torch.stack(colours, 1), torch.stack(weights_r)), \
        ColourTerms(torch.stack(colours, 1), torch.stack(weights_t))


def forward_scattering(fabric: ParamTensors, options: RenderOptions) -> torch.Tensor | None:
    """The yarns' k of :func:`backend.model.asggx.forward_peak`, or None where the lobe is the paper's: the
    ASGGX lobe with k 0 and not fitted (every default render, which the term would only slow)."""
    k = fabric.forward_scattering
    active = k.requires_grad or any(fabric.host(("forward_scattering",))["forward_scattering"])
    return k if options.multiple_lobe == "asggx" and active else None


def diffuse_weight(weight: torch.Tensor, light: LightFactors, c: torch.Tensor) -> torch.Tensor:
    """((1 - w) |wo_z| + w c) / pi times the irradiance where some layer is a yarn; multiplies k_d."""
    return (1.0 - weight) * light.diffuse_flat + weight * (light.diffuse_normal * c)


def eval_pair(chunk: SampleChunk, geometry: SampleGeometry, fabric: ParamTensors,
              options: RenderOptions) -> tuple[ColourTerms, ColourTerms]:
    """:func:`eval_projected` from camera samples and geometry (projects them first)."""
    return eval_projected(project(chunk, geometry), fabric, options)
