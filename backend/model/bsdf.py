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
from typing import NamedTuple

import torch

from ..core.options import RenderOptions
from . import asggx, sggx
from .param_tensors import ParamTensors
from .projections import LayerProjections, LightFactors, SampleProjections, Split
from .spongecake import one_minus_exp_over


def multiple_albedo(specular_albedo: torch.Tensor, multiple_weight: torch.Tensor) -> torch.Tensor:
    """k_m = k_s ** (1 / w_m) per channel; 0 stays 0, with a finite gradient near 0."""
    positive = specular_albedo > 0
    base = specular_albedo.clamp_min(1e-6)
    return torch.where(positive, torch.exp(torch.log(base) / multiple_weight), torch.zeros_like(base))


@dataclass
class YarnConstants:
    """The per-yarn (2,) constants the lobes read, formed once per evaluation from the parameters
    (:meth:`of`); the hand-written gradient (:mod:`backend.model.bsdf_gradient`) differentiates the
    BSDF with respect to these."""

    flattening: torch.Tensor     # 1 - alpha^2
    ndf_shape: torch.Tensor      # 1 / alpha^2 - 1
    ndf_scale: torch.Tensor      # 1 / (pi alpha)
    ndf_shape_m: torch.Tensor    # the same of alpha_m
    ndf_scale_m: torch.Tensor
    thickness: torch.Tensor      # T
    thickness_m: torch.Tensor    # T_m
    height: torch.Tensor         # beta
    forward: torch.Tensor | None  # k (asggx.forward_peak); None: the paper's lobe
    flattening_m: torch.Tensor | None = None  # 1 - alpha_m^2, for the ablation's lobe only

    @classmethod
    def of(cls, fabric: ParamTensors, options: RenderOptions) -> "YarnConstants":
        alpha, alpha_m = fabric.roughness, fabric.roughness_multiple
        return cls(1.0 - alpha * alpha, 1.0 / (alpha * alpha) - 1.0, 1.0 / (torch.pi * alpha),
                   1.0 / (alpha_m * alpha_m) - 1.0, 1.0 / (torch.pi * alpha_m), fabric.thickness,
                   fabric.thickness_multiple, fabric.height_scale, forward_scattering(fabric, options),
                   None if options.multiple_lobe == "asggx" else 1.0 - alpha_m * alpha_m)


@dataclass
class LobeParts:
    """The intermediate values of one layer's lobes under one light that the hand-written gradient
    reads (:mod:`backend.model.bsdf_gradient`); the names follow :func:`layer_optics`."""

    cos_out: torch.Tensor       # co = wo . o
    cos_half: torch.Tensor      # ch = h . o
    sigma_out: torch.Tensor     # sigma(wo)
    area_out: torch.Tensor      # A_o = sigma(wo) / wo_z (signed)
    ndf: torch.Tensor           # D(h) = scale / denom^2
    denom: torch.Tensor         # 1 + shape ch^2
    half_sin2: torch.Tensor     # sin^2 th of the ASGGX lobe
    sin2_out: torch.Tensor      # 1 - co^2
    across2: torch.Tensor       # (1 - ci^2)(1 - co^2)
    cross: torch.Tensor         # its root
    ndf_m: torch.Tensor         # D_alpha_m(h'), before the forward scattering's peak
    denom_m: torch.Tensor
    cos_phi: torch.Tensor | None  # the forward scattering's azimuth (None: no peak)
    peak: torch.Tensor | None     # A_k
    phi: torch.Tensor           # phi(T E) of G, E = A_i + A_o (|A_i + A_o| across the layer)
    phi_m: torch.Tensor         # phi(T_m E)
    near: torch.Tensor | None   # across the layer: max(att(wi), att(wo)), exp(-T_m min(A_i, -A_o))
    near_m: torch.Tensor | None
    g: torch.Tensor
    g_m: torch.Tensor


@dataclass
class LayerLobes:
    """What the composition needs from one layer, for one light."""

    single: torch.Tensor      # (S,) f_s / k_s
    multiple: torch.Tensor    # (S,) f_m / k_m
    att_out: torch.Tensor     # (S,) att(wo)
    cos_normal: torch.Tensor  # (S,) wo . n
    parts: LobeParts | None = None  # the asggx lobe's intermediates


@dataclass
class LayerOptics:
    att_in: torch.Tensor      # (S,) att(wi)
    front: LayerLobes
    back: LayerLobes
    # per sample: the yarn's constants picked, and the intermediates of wi the gradient reads
    picked: dict[str, torch.Tensor] | None = None
    cos_in: torch.Tensor | None = None
    sin2_in: torch.Tensor | None = None
    sigma_in: torch.Tensor | None = None
    area_in: torch.Tensor | None = None
    inv_fiber: torch.Tensor | None = None
    inv_normal: torch.Tensor | None = None


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


def layer_optics(layer: LayerProjections, yarns: YarnConstants, samples: SampleProjections,
                 options: RenderOptions) -> LayerOptics:
    """att(wi), and f_s, f_m, att(wo), wo . n for both lights, of one layer (spec 3.3, 4.1-4.4)."""
    weft = layer.weft
    flattening = _pick(yarns.flattening, weft)
    ndf_shape, ndf_scale = _pick(yarns.ndf_shape, weft), _pick(yarns.ndf_scale, weft)
    ndf_shape_m, ndf_scale_m = _pick(yarns.ndf_shape_m, weft), _pick(yarns.ndf_scale_m, weft)
    thickness = _pick(yarns.thickness, weft) * layer.thickness_scale
    thickness_m = _pick(yarns.thickness_m, weft) * layer.thickness_scale
    beta = _pick(yarns.height, weft)
    if layer.height_offset is not None:
        beta = (beta + layer.height_offset).clamp_min(0.01)
    beta2 = beta * beta
    inv_fiber = torch.rsqrt(torch.addcmul(layer.fiber_plane2, beta2, layer.fiber_z2))
    inv_normal = torch.rsqrt(torch.addcmul(layer.normal_z2, beta2, layer.normal_plane2))

    def on_fiber(split: Split) -> torch.Tensor:
        return torch.addcmul(split.plane, beta, split.z) * inv_fiber

    cos_in = on_fiber(layer.wi)
    cos2_in = cos_in * cos_in
    sigma_in = sggx.projected_area_from(cos2_in, flattening)
    area_in = sigma_in * samples.inv_wi_z
    att_in = torch.exp(-thickness * area_in)
    quarter_inv_wi_z = 0.25 * samples.inv_wi_z
    sin2_in = 1.0 - cos2_in
    forward = None if yarns.forward is None else _pick(yarns.forward, weft)
    asggx_lobe = options.multiple_lobe == "asggx"

    def lobes(splits, light: LightFactors, same_side: bool) -> LayerLobes:
        cos_out = on_fiber(splits.out)
        cos_half = on_fiber(splits.half)
        cos2_out = cos_out * cos_out
        sigma_out = sggx.projected_area_from(cos2_out, flattening)
        area_out = sigma_out * light.inv_wo_z
        att_out = torch.exp(-thickness * area_out.abs())
        denom = 1.0 + ndf_shape * (cos_half * cos_half)
        ndf = ndf_scale / (denom * denom)
        cos_phi = peak = near = near_m = None
        if asggx_lobe:
            sin2_out = 1.0 - cos2_out
            across2 = sin2_in * sin2_out
            half_sin2, cross = asggx.half_sin2_with_cross(cos_in, cos_out, across2)
            denom_m = 1.0 + ndf_shape_m * half_sin2
            ndf_m = ndf_scale_m / (denom_m * denom_m)
            area_in_m, area_out_m = area_in, area_out
            lobe_m = ndf_m
            if forward is not None and not same_side:  # light crossing the layer: asggx.forward_peak
                cos_phi = asggx.forward_azimuth(cos_in, cos_out, across2, light.cos_in_out)
                peak = asggx.peak_at(cos_phi, forward)
                lobe_m = ndf_m * peak
        else:  # the ablation: the single-scattering lobe with alpha_m, T_m
            lobe_m = sggx.ndf_from(cos_half * cos_half, ndf_shape_m, ndf_scale_m)
            flattening_m = _pick(yarns.flattening_m, weft)
            area_in_m = sggx.projected_area_from(cos2_in, flattening_m) * samples.inv_wi_z
            area_out_m = sggx.projected_area_from(cos2_out, flattening_m) * light.inv_wo_z
        if same_side:  # A_i, A_o > 0: min(p, q) = 0, |q - p| = A_i + A_o
            spread, spread_m = area_in + area_out, area_in_m + area_out_m
        else:  # A_o < 0 < A_i: min(p, q) = min(A_i, |A_o|), |q - p| = |A_i + A_o|
            spread, spread_m = (area_in + area_out).abs(), (area_in_m + area_out_m).abs()
            near = torch.maximum(att_in, att_out)
            near_m = torch.exp(-thickness_m * torch.minimum(area_in_m, -area_out_m))
        phi = one_minus_exp_over(thickness * spread)
        phi_m = one_minus_exp_over(thickness_m * spread_m)
        g, g_m = thickness * phi, thickness_m * phi_m
        if near is not None:
            g, g_m = g * near, g_m * near_m
        lobe_factor = 2.0 if asggx_lobe else 1.0  # 1 / (2 |wi_z|) vs 1 / (4 |wi_z|)
        cos_normal = torch.addcmul(splits.normal.z, beta, splits.normal.plane) * inv_normal
        parts = LobeParts(cos_out, cos_half, sigma_out, area_out, ndf, denom, half_sin2, sin2_out, across2, cross,
                          ndf_m, denom_m, cos_phi, peak, phi, phi_m, near, near_m, g, g_m) if asggx_lobe else None
        return LayerLobes(ndf * g * quarter_inv_wi_z, lobe_m * g_m * (lobe_factor * quarter_inv_wi_z),
                          att_out, cos_normal, parts)

    picked = {"flattening": flattening, "ndf_shape": ndf_shape, "ndf_shape_m": ndf_shape_m,
              "thickness": thickness, "thickness_m": thickness_m, "height": beta, "forward": forward}
    return LayerOptics(att_in, lobes(layer.front, samples.front, True), lobes(layer.back, samples.back, False),
                       picked, cos_in, sin2_in, sigma_in, area_in, inv_fiber, inv_normal)


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
    yarns = YarnConstants.of(fabric, options)
    optics = [layer_optics(layer, yarns, samples, options) for layer in samples.layers]
    weights_r, weights_t = weights(samples, optics, fabric.diffuse_normal_weight, options)
    return colour_terms(fabric, options, weights_r, weights_t)


def weights(samples: SampleProjections, optics: list[LayerOptics], diffuse_normal_weight: torch.Tensor,
            options: RenderOptions, cosines: "DiffuseCosines | None" = None) -> tuple[torch.Tensor, torch.Tensor]:
    """The layers' lobes composed into the (K, S) weights of :class:`ColourTerms`, reflection and
    transmission (the module docstring's formulas); ``cosines``: the diffuse term's, where the caller
    has them (:func:`diffuse_cosines`)."""
    layers = samples.layers
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
    weights_r, weights_t = reflection.weights, transmission.weights
    if options.diffuse:
        cosines = cosines or diffuse_cosines(layers, optics)
        weights_r = weights_r + [diffuse_weight(diffuse_normal_weight, samples.front, cosines.front)]
        weights_t = weights_t + [diffuse_weight(diffuse_normal_weight, samples.back, cosines.back)]
    return torch.stack(weights_r), torch.stack(weights_t)


class DiffuseCosines(NamedTuple):
    """The diffuse term's c of the front light and of the back light (the module docstring), and the
    back light's factor of each layer (c_back is their product)."""

    front: torch.Tensor
    back: torch.Tensor
    back_factors: list[torch.Tensor]


def diffuse_cosines(layers: list[LayerProjections], optics: list[LayerOptics]) -> DiffuseCosines:
    """:class:`DiffuseCosines` of the layers' normals."""
    c_front = optics[0].front.cos_normal.clamp_min(0)
    if len(layers) == 2:  # the back layer's normal where the front is a gap
        c_front = torch.lerp(optics[1].front.cos_normal.clamp_min(0), c_front, layers[0].yarn)
    else:
        c_front = c_front * layers[0].yarn
    c_back, factors = None, []
    for layer, layer_optics_ in zip(layers, optics):
        factor = torch.lerp(torch.ones((), dtype=c_front.dtype, device=c_front.device),
                            (-layer_optics_.back.cos_normal).clamp_min(0), layer.yarn)
        c_back = factor if c_back is None else c_back * factor
        factors.append(factor)
    return DiffuseCosines(c_front, c_back, factors)


def colour_terms(fabric: ParamTensors, options: RenderOptions, weights_r: torch.Tensor,
                 weights_t: torch.Tensor) -> tuple[ColourTerms, ColourTerms]:
    """The (reflection, transmission) :class:`ColourTerms` of the weights: the albedos as colours."""
    ks = fabric.specular_albedo
    km = multiple_albedo(ks, fabric.multiple_weight)
    colours = [ks[0], ks[1], km[0], km[1]]
    if options.diffuse:
        return (ColourTerms(torch.stack(colours + [fabric.diffuse_reflection], 1), weights_r),
                ColourTerms(torch.stack(colours + [fabric.diffuse_transmission], 1), weights_t))
    return ColourTerms(torch.stack(colours, 1), weights_r), ColourTerms(torch.stack(colours, 1), weights_t)


def forward_scattering(fabric: ParamTensors, options: RenderOptions) -> torch.Tensor | None:
    """The yarns' k of :func:`backend.model.asggx.forward_peak`, or None where the lobe is the paper's: the
    ASGGX lobe with k 0 and not fitted (every default render, which the term would only slow)."""
    k = fabric.forward_scattering
    active = k.requires_grad or any(fabric.host(("forward_scattering",))["forward_scattering"])
    return k if options.multiple_lobe == "asggx" and active else None


def diffuse_weight(weight: torch.Tensor, light: LightFactors, c: torch.Tensor) -> torch.Tensor:
    """((1 - w) |wo_z| + w c) / pi times the irradiance where some layer is a yarn; multiplies k_d."""
    return (1.0 - weight) * light.diffuse_flat + weight * (light.diffuse_normal * c)
