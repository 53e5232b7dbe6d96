"""The BSDF's weights with a hand-written backward pass: the eager renderer's gradient.

Autograd differentiates :func:`backend.model.bsdf.eval_projected` one operation at a time: it keeps
every intermediate, and its backward pass runs about two operations per forward one, each reading
and writing whole (S,) tensors, and reduces a gradient to the per-yarn constants at every use of
one. Here the forward pass is the same code (:func:`backend.model.bsdf.layer_optics` and
:func:`backend.model.bsdf.weights`, so the values are bit-identical), and the backward pass walks
the formulas once by hand, per sample, and reduces each per-yarn constant's gradient once, by the
weft mask::

    dL/dp_warp = sum_s g_s (1 - weft_s),  dL/dp_weft = sum_s g_s weft_s      (p picked per sample)

The derivatives, per layer and light (names as in :mod:`backend.model.bsdf`; u = 1 / |o'|,
v = 1 / |n'|, c_x = (plane_x + beta z_x) u the cosines with the height-scaled fiber):

    single = D G q,  multiple = D_m A_k G_m 2 q                     q = 1 / (4 |wi_z|)
    D = c / d^2, d = 1 + s ch^2:        dD/dc = D / c, dD/dd = -2 D / d, dd/ds = ch^2, dd/dch = 2 s ch
    sigma = sqrt(1 - F c^2):            dsigma/dF = -c^2 / (2 sigma), dsigma/dc = -F c / sigma
    sin^2 th = (1 + ci co - X) / 2, X = sqrt((1 - ci^2)(1 - co^2)):
                                        d/dci = (co + ci (1 - co^2) / X) / 2 (and ci <-> co)
    G = T phi(T E) [near]:              dG/dT = (phi + y phi'(y)) [near], dG/dE = T^2 phi'(y) [near]
    att = exp(-T |A|):                  datt/dT = -|A| att, datt/dA = -T att sign(A)
    A_k = (1 - k^2) / den, den = 1 + k^2 - 2 k cos phi:
                                        dA_k/dk = -2 (k + A_k (k - cos phi)) / den, dA_k/dcos phi = 2 k A_k / den
    cos phi = n r, n = ci co - wi.wo, r = X^-1:
                                        d/dci = co r + cos phi ci (1 - co^2) r^2 (and ci <-> co)
    dc_x/dbeta = z_x u - c_x beta |o_z|^2 u^2,   dcos_n/dbeta = plane_n v - cos_n beta |n_xy|^2 v^2

The clamps and the minimum / maximum pass the gradient as autograd does (to the side taken, none
where a clamp holds); a tie of max(att(wi), att(wo)) happens on gaps only, where the thickness is 0
and both sides' gradients vanish. ``tests/test_bsdf_gradient.py`` checks the gradients against
autograd's, on the plain and the varied model, with and without forward scattering.

Where it applies: the full model (the ASGGX lobe, two layers, the diffuse term), which every fit
renders; the ablations and the compiled path (which fuses autograd's own graph) take autograd.
"""
from __future__ import annotations

import torch

from ..core.options import RenderOptions
from .bsdf import (
    ColourTerms,
    DiffuseCosines,
    LayerLobes,
    LayerOptics,
    YarnConstants,
    colour_terms,
    diffuse_cosines,
    eval_projected,
    layer_optics,
    weights,
)
from .param_tensors import ParamTensors
from .projections import LayerProjections, SampleProjections, Split
from .spongecake import one_minus_exp_over_slope

# The per-yarn constants whose gradient the backward pass returns, in YarnConstants' order.
_CONSTANTS = ("flattening", "ndf_shape", "ndf_scale", "ndf_shape_m", "ndf_scale_m", "thickness", "thickness_m",
              "height", "forward")


def supported(options: RenderOptions) -> bool:
    """Whether the hand-written gradient covers the model ``options`` render (the module docstring)."""
    return options.multiple_lobe == "asggx" and options.layers == 2 and options.diffuse


def eval_with_hand_gradient(samples: SampleProjections, fabric: ParamTensors,
                            options: RenderOptions) -> tuple[ColourTerms, ColourTerms]:
    """:func:`backend.model.bsdf.eval_projected`, differentiated by hand where it is supported and a
    gradient is wanted (else by autograd, or none)."""
    if not (supported(options) and torch.is_grad_enabled()
            and any(v.requires_grad for v in fabric.values.values())):
        return eval_projected(samples, fabric, options)
    yarns = YarnConstants.of(fabric, options)
    constants = [getattr(yarns, name) for name in _CONSTANTS]
    weights_r, weights_t = _HandGradient.apply(samples, options, fabric.diffuse_normal_weight, *constants)
    return colour_terms(fabric, options, weights_r, weights_t)


class _HandGradient(torch.autograd.Function):
    """(weights_r, weights_t) of :func:`backend.model.bsdf.weights` from the diffuse normal weight and
    the per-yarn constants (``_CONSTANTS``; forward scattering may be None)."""

    @staticmethod
    def forward(ctx, samples: SampleProjections, options: RenderOptions, diffuse_normal_weight, *constants):
        yarns = YarnConstants(**dict(zip(_CONSTANTS, constants)))
        optics = [layer_optics(layer, yarns, samples, options) for layer in samples.layers]
        cosines = diffuse_cosines(samples.layers, optics)
        weights_r, weights_t = weights(samples, optics, diffuse_normal_weight, options, cosines)
        ctx.samples, ctx.optics, ctx.yarns, ctx.cosines = samples, optics, yarns, cosines
        ctx.save_for_backward(diffuse_normal_weight)
        return weights_r, weights_t

    @staticmethod
    def backward(ctx, grad_r, grad_t):
        (w,) = ctx.saved_tensors
        samples, optics, yarns = ctx.samples, ctx.optics, ctx.yarns
        lights, grad_w = _composition_backward(samples, optics, ctx.cosines, w, grad_r, grad_t)
        per_yarn = None
        for layer, layer_optics_, layer_grads in zip(samples.layers, optics, lights):
            found = _layer_backward(layer, layer_optics_, yarns, samples, *layer_grads)
            per_yarn = found if per_yarn is None else per_yarn + found
        grads = dict(zip(_CONSTANTS, per_yarn.unbind(0)))
        # D = c / d^2 and D_m: the per-sample sums of g D are divided by the yarn's c once, here
        grads["ndf_scale"] = grads["ndf_scale"] / yarns.ndf_scale
        grads["ndf_scale_m"] = grads["ndf_scale_m"] / yarns.ndf_scale_m
        return (None, None, grad_w.reshape(w.shape), *(None if getattr(yarns, n) is None else grads[n]
                                                       for n in _CONSTANTS))


def _slot_backward(layer: LayerProjections, lobes: LayerLobes, factor: torch.Tensor, grad: torch.Tensor,
                   factor_wanted: bool = True):
    """Of ``_Slots.add(layer, lobes, factor)``: the gradients of the single lobe, the multiple lobe and
    the factor (None where not ``factor_wanted``: a constant factor), from the gradient of the light's
    weights (K, S)."""
    weft = layer.weft
    g_single, g_multiple = torch.lerp(grad[0], grad[1], weft), torch.lerp(grad[2], grad[3], weft)
    g_factor = g_single * lobes.single + g_multiple * lobes.multiple if factor_wanted else None
    if layer.albedo_scale is not None:
        factor = factor * layer.albedo_scale
        g_factor = None if g_factor is None else g_factor * layer.albedo_scale
    return g_single * factor, g_multiple * factor, g_factor


def _composition_backward(samples: SampleProjections, optics: list[LayerOptics], cosines: DiffuseCosines,
                          w: torch.Tensor, grad_r: torch.Tensor, grad_t: torch.Tensor):
    """Of :func:`backend.model.bsdf.weights` (two layers, diffuse): per layer, the gradients
    (single, multiple, att(wo), wo . n) of each light and att(wi)'s; and the diffuse normal weight's."""
    layers = samples.layers
    irr_f, irr_b = samples.front.irradiance, samples.back.irradiance
    o0, o1 = optics
    s0f, m0f, _ = _slot_backward(layers[0], o0.front, irr_f, grad_r, factor_wanted=False)
    s1f, m1f, g_factor = _slot_backward(layers[1], o1.front, irr_f * o0.front.att_out * o0.att_in, grad_r)
    g_att0f, g_att0_in = g_factor * (irr_f * o0.att_in), g_factor * (irr_f * o0.front.att_out)
    s0b, m0b, g_factor = _slot_backward(layers[0], o0.back, irr_b * o1.back.att_out, grad_t)
    g_att1b = g_factor * irr_b
    s1b, m1b, g_factor = _slot_backward(layers[1], o1.back, irr_b * o0.att_in, grad_t)
    g_att0_in = g_att0_in + g_factor * irr_b

    c_front, c_back, factors = cosines
    g_wr, g_wt = grad_r[4], grad_t[4]
    front, back = samples.front, samples.back
    grad_w = ((g_wr * (front.diffuse_normal * c_front - front.diffuse_flat)).sum()
              + (g_wt * (back.diffuse_normal * c_back - back.diffuse_flat)).sum())
    g_c = g_wr * (w * front.diffuse_normal)
    yarn0 = layers[0].yarn
    n0f, n1f = o0.front.cos_normal, o1.front.cos_normal
    g_n0f = torch.where(n0f >= 0, g_c * yarn0, 0.0)
    g_n1f = torch.where(n1f >= 0, g_c * (1.0 - yarn0), 0.0)
    g_cb = g_wt * (w * back.diffuse_normal)
    g_n0b = torch.where(o0.back.cos_normal <= 0, -(g_cb * factors[1] * layers[0].yarn), 0.0)
    g_n1b = torch.where(o1.back.cos_normal <= 0, -(g_cb * factors[0] * layers[1].yarn), 0.0)
    return [((s0f, m0f, g_att0f, g_n0f), (s0b, m0b, None, g_n0b), g_att0_in),
            ((s1f, m1f, None, g_n1f), (s1b, m1b, g_att1b, g_n1b), None)], grad_w


def _add(total: torch.Tensor | None, term: torch.Tensor | None) -> torch.Tensor | None:
    if term is None:
        return total
    return term if total is None else total + term


class _Grads:
    """Per-sample gradients of one layer, gathered by name (None until a term arrives)."""

    def __init__(self):
        self.values: dict[str, torch.Tensor | None] = {}

    def add(self, name: str, term: torch.Tensor | None) -> None:
        self.values[name] = _add(self.values.get(name), term)

    def get(self, name: str) -> torch.Tensor | None:
        return self.values.get(name)


def _lobe_backward(grads: _Grads, optics: LayerOptics, lobes: LayerLobes, quarter_inv_wi_z: torch.Tensor,
                   inv_wo_z: torch.Tensor, same_side: bool,
                   g_single, g_multiple, g_att_out, g_cos_normal) -> None:
    """One light's lobes of one layer: adds the per-sample gradients of the picked constants and of
    the cosines (``cos_in``, ``cos_out:<light>``, ``cos_half:<light>``, ``cos_normal:<light>``) and A_i."""
    p, picked = lobes.parts, optics.picked
    light = "front" if same_side else "back"
    thickness, thickness_m = picked["thickness"], picked["thickness_m"]
    cos_in, cos_out, sin2_in, sin2_out = optics.cos_in, p.cos_out, optics.sin2_in, p.sin2_out
    across = p.across2 >= 1e-14  # where X = sqrt((1 - ci^2)(1 - co^2)) is not floored
    inv_cross = torch.where(across, 1.0 / p.cross, torch.zeros_like(p.cross))
    # single = D G q, multiple = D_m [A_k] G_m 2q
    g_single_q = g_single * quarter_inv_wi_z
    g_ndf, g_g = g_single_q * p.g, g_single_q * p.ndf
    g_multiple_q = g_multiple * (2.0 * quarter_inv_wi_z)
    lobe_m = p.ndf_m if p.peak is None else p.ndf_m * p.peak
    g_lobe_m, g_g_m = g_multiple_q * p.g_m, g_multiple_q * lobe_m
    g_ndf_m = g_lobe_m
    if p.peak is not None:
        g_peak = g_lobe_m * p.ndf_m
        g_ndf_m = g_lobe_m * p.peak
        k, cos_phi = picked["forward"], p.cos_phi
        den = 1.0 + k * k - 2.0 * k * cos_phi
        grads.add("forward", g_peak * (-2.0) * (k + p.peak * (k - cos_phi)) / den)
        g_cos_phi = torch.where(cos_phi.abs() < 1, g_peak * (2.0 * k * p.peak / den), 0.0)  # 0 where clamped
        g_cos_phi_r = g_cos_phi * inv_cross
        r_cos_phi = cos_phi * inv_cross
        grads.add("cos_in", g_cos_phi_r * (cos_out + r_cos_phi * cos_in * sin2_out))
        grads.add(f"cos_out:{light}", g_cos_phi_r * (cos_in + r_cos_phi * cos_out * sin2_in))
    # D = c / d^2, d = 1 + s ch^2 (c's gradient: the sum of g D, divided by c per yarn)
    t = g_ndf * p.ndf
    grads.add("ndf_scale", t)
    g_denom = -2.0 * t / p.denom
    cos_half = p.cos_half
    grads.add("ndf_shape", g_denom * (cos_half * cos_half))
    grads.add(f"cos_half:{light}", g_denom * (2.0 * picked["ndf_shape"] * cos_half))
    t_m = g_ndf_m * p.ndf_m
    grads.add("ndf_scale_m", t_m)
    g_denom_m = -2.0 * t_m / p.denom_m
    grads.add("ndf_shape_m", g_denom_m * p.half_sin2)
    g_half = torch.where((p.half_sin2 > 0) & (p.half_sin2 < 1), g_denom_m * picked["ndf_shape_m"], 0.0)
    g_half_2 = 0.5 * g_half
    grads.add("cos_in", g_half_2 * (cos_out + cos_in * sin2_out * inv_cross))
    grads.add(f"cos_out:{light}", g_half_2 * (cos_in + cos_out * sin2_in * inv_cross))
    # G = T phi(T E) [near], G_m = T_m phi(T_m E) [near_m]
    area_in, area_out = optics.area_in, p.area_out
    spread = area_in + area_out
    if not same_side:
        g_near, g_near_m = g_g * (thickness * p.phi), g_g_m * (thickness_m * p.phi_m)
        g_g, g_g_m = g_g * p.near, g_g_m * p.near_m
        in_wins = optics.att_in >= lobes.att_out
        grads.add("att_in", torch.where(in_wins, g_near, torch.zeros_like(g_near)))
        g_att_out = _add(g_att_out, torch.where(in_wins, torch.zeros_like(g_near), g_near))
        in_near = area_in <= -area_out
        near_exponent = torch.where(in_near, area_in, -area_out)  # min(A_i, -A_o)
        g_exponent = g_near_m * p.near_m
        grads.add("thickness_m", -g_exponent * near_exponent)
        g_min = -g_exponent * thickness_m
        grads.add("area_in", torch.where(in_near, g_min, torch.zeros_like(g_min)))
        g_area_out = torch.where(in_near, torch.zeros_like(g_min), -g_min)
        sign = torch.sign(spread)
        spread = spread.abs()
    else:
        g_area_out, sign = None, None
    y, y_m = thickness * spread, thickness_m * spread
    slope, slope_m = one_minus_exp_over_slope(y, p.phi), one_minus_exp_over_slope(y_m, p.phi_m)
    grads.add("thickness", g_g * (p.phi + y * slope))
    grads.add("thickness_m", g_g_m * (p.phi_m + y_m * slope_m))
    g_spread = g_g * (thickness * thickness * slope) + g_g_m * (thickness_m * thickness_m * slope_m)
    if sign is not None:
        g_spread = g_spread * sign
    grads.add("area_in", g_spread)
    g_area_out = _add(g_area_out, g_spread)
    # att(wo) = exp(-T |A_o|): A_o > 0 for the front light, < 0 for the back light
    if g_att_out is not None:
        g_exp = -g_att_out * lobes.att_out
        grads.add("thickness", g_exp * area_out.abs())
        g_area_out = g_area_out + (g_exp * thickness if same_side else -(g_exp * thickness))
    # A_o = sigma(wo) / wo_z, sigma = sqrt(1 - F co^2): 1 - F c^2 >= alpha^2 >= 1e-4 at every declared
    # roughness, so the floor of the root (frames.safe_sqrt) never holds
    h = g_area_out * inv_wo_z / p.sigma_out
    grads.add("flattening", -0.5 * h * (cos_out * cos_out))
    grads.add(f"cos_out:{light}", -h * picked["flattening"] * cos_out)
    grads.add(f"cos_normal:{light}", g_cos_normal)


def _layer_backward(layer: LayerProjections, optics: LayerOptics, yarns: YarnConstants, samples: SampleProjections,
                    front_grads, back_grads, g_att_in) -> torch.Tensor:
    """The per-yarn gradients (len(_CONSTANTS), 2) of one layer, from the gradients of its outputs."""
    grads = _Grads()
    grads.add("att_in", g_att_in)
    quarter_inv_wi_z = 0.25 * samples.inv_wi_z
    for lobes, light, same_side, light_grads in ((optics.front, samples.front, True, front_grads),
                                                (optics.back, samples.back, False, back_grads)):
        _lobe_backward(grads, optics, lobes, quarter_inv_wi_z, light.inv_wo_z, same_side,
                       *light_grads)
    picked = optics.picked
    # att(wi) = exp(-T A_i), A_i = sigma(wi) / wi_z
    g_att_in = grads.get("att_in")
    if g_att_in is not None:
        g_exp = -g_att_in * optics.att_in
        grads.add("thickness", g_exp * optics.area_in)
        grads.add("area_in", g_exp * picked["thickness"])
    cos_in = optics.cos_in
    cos2_in = cos_in * cos_in
    h = grads.get("area_in") * samples.inv_wi_z / optics.sigma_in
    grads.add("flattening", -0.5 * h * cos2_in)
    grads.add("cos_in", -h * picked["flattening"] * cos_in)
    # the cosines with the height-scaled fiber and normal: d/dbeta
    beta, inv_fiber, inv_normal = picked["height"], optics.inv_fiber, optics.inv_normal
    sum_z = sum_c = None
    cosines = [("cos_in", layer.wi, cos_in)]
    for name, lobes, splits in (("front", optics.front, layer.front), ("back", optics.back, layer.back)):
        cosines += [(f"cos_out:{name}", splits.out, lobes.parts.cos_out),
                    (f"cos_half:{name}", splits.half, lobes.parts.cos_half)]
    for name, split, cosine in cosines:
        g = grads.get(name)
        if g is not None:
            sum_z, sum_c = _add(sum_z, g * split.z), _add(sum_c, g * cosine)
    g_beta = inv_fiber * sum_z - (beta * layer.fiber_z2) * (inv_fiber * inv_fiber) * sum_c
    for name, lobes, splits in (("front", optics.front, layer.front), ("back", optics.back, layer.back)):
        g = grads.get(f"cos_normal:{name}")
        if g is not None:
            g_beta = g_beta + _normal_beta(g, splits.normal, lobes.cos_normal, beta, layer.normal_plane2, inv_normal)
    if layer.height_offset is not None:  # beta = max(pick + offset, 0.01)
        g_beta = torch.where(_unclamped_height(yarns, layer) >= 0.01, g_beta, 0.0)
    grads.values["height"] = g_beta
    scale = layer.thickness_scale
    for name in ("thickness", "thickness_m"):
        if grads.get(name) is not None:
            grads.values[name] = grads.values[name] * scale
    zero = torch.zeros_like(cos_in)
    per_sample = torch.stack([_or(grads.get(name), zero) for name in _CONSTANTS])
    weft = layer.weft
    return per_sample @ torch.stack((1.0 - weft, weft), 1)


def _normal_beta(g: torch.Tensor, split: Split, cos_normal: torch.Tensor, beta: torch.Tensor,
                 normal_plane2: torch.Tensor, inv_normal: torch.Tensor) -> torch.Tensor:
    """d(wo . n')/dbeta times ``g``: n' = normalize(beta n_xy, n_z) (:mod:`backend.model.projections`)."""
    return g * (split.plane * inv_normal - cos_normal * beta * normal_plane2 * (inv_normal * inv_normal))


def _unclamped_height(yarns: YarnConstants, layer: LayerProjections) -> torch.Tensor:
    return torch.lerp(yarns.height[0], yarns.height[1], layer.weft) + layer.height_offset


def _or(value: torch.Tensor | None, default: torch.Tensor) -> torch.Tensor:
    return default if value is None else value

