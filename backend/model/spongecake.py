"""SpongeCake layer of fiber microflakes: single and multiple scattering, attenuation (spec 4.2-4.4).

For one layer of optical thickness T, with A_i = sigma(wi) / wi_z and A_o = sigma(wo) / wo_z
(world z cosines; transmission makes A_o < 0), E1 the sum of the positive ones and E0 the sum of
the negative ones::

    G   = (exp(T E0) - exp(-T E1)) / (A_i + A_o)
    f_s = k_s D(h) G / (4 |wi_z|)                      SGGX single scattering
    f_m = k_m D_{alpha_m}(h') G_m / (2 |wi_z|)         ASGGX multiple scattering (G_m: T_m for T)
    att(w) = exp(-T sigma(w) / |w_z|)                  attenuation through the layer

f values are cosine-weighted (they include the light-side cosine). G is the divided difference of
x -> exp(-T x) between p = -E0 and q = E1, computed here as
``T exp(-T min(p, q)) phi(T |q - p|)`` with ``phi(y) = (1 - exp(-y)) / y``: equal to the formula
above, finite everywhere, and with finite gradients where A_i + A_o = 0 (the spec's "divide by 1"
gives 0 there, a single point of measure zero where the continuous limit is T exp(-T p)).
"""
from __future__ import annotations

import torch

from . import asggx, sggx
from .frames import dot, normalize

# The vectorised float32 expm1 of the CPU takes a slow path, several times slower, for arguments of
# magnitude below about 3e-15 and above about 56: phi's argument is kept within [PHI_FLOOR_FLOAT32,
# EXPM1_SATURATION] there, where phi and expm1 take the same float32 values as at the bounds (phi(y) is
# 1 below y = 6e-8, expm1(-y) is -1 from y = 17, to the last bit).
PHI_FLOOR_FLOAT32 = 1e-12
PHI_FLOOR = 1e-30  # in float64, whose expm1 has no such slow path
EXPM1_SATURATION = 40.0


class _OneMinusExpOver(torch.autograd.Function):
    """phi with a hand-written derivative: one expm1 and no branch in the forward pass (phi(0) = 1 =
    phi of the floor, PHI_FLOOR_FLOAT32 in float32 and PHI_FLOOR in float64, and -expm1(-y) / y is
    accurate to an ulp for every y > 0),
    and phi'(y) = (exp(-y) - phi(y)) / y, or its series -1/2 + y/3 below 1e-4 where that difference
    cancels. Autograd of the formula would spend about three times the memory traffic."""

    @staticmethod
    def forward(ctx, y):
        positive = y.clamp_min(PHI_FLOOR_FLOAT32 if y.dtype == torch.float32 else PHI_FLOOR)
        exp_m1 = torch.expm1(-positive.clamp_max(EXPM1_SATURATION))
        phi = exp_m1 / -positive
        ctx.save_for_backward(positive, exp_m1, phi)
        return phi

    @staticmethod
    def backward(ctx, grad):
        y, exp_m1, phi = ctx.saved_tensors
        return grad * _slope(y, exp_m1, phi)


def _slope(y: torch.Tensor, exp_m1: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    """phi'(y) from y (> 0), expm1(-y) and phi(y) (:class:`_OneMinusExpOver`)."""
    return torch.where(y < 1e-4, y * (1.0 / 3.0) - 0.5, (exp_m1 + 1.0 - phi) / y)


def one_minus_exp_over_slope(y: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    """phi'(y) at y >= 0 where phi(y) is known (the hand-written gradient of
    :mod:`backend.model.bsdf_gradient`): exp(-y) - 1 = -y phi(y), as exact as expm1 where the series
    is not taken."""
    return _slope(y, -y * phi, phi)


def one_minus_exp_over(y: torch.Tensor) -> torch.Tensor:
    """phi(y) = (1 - exp(-y)) / y for y >= 0, with phi(0) = 1 and a smooth gradient near 0."""
    return _OneMinusExpOver.apply(y)


def slab_g(thickness: torch.Tensor, a_in: torch.Tensor, a_out: torch.Tensor) -> torch.Tensor:
    """G(T, A_i, A_o) of spec 4.2, stable form (see the module docstring)."""
    pos = a_in.clamp_min(0) + a_out.clamp_min(0)     # E1
    neg = -(a_in.clamp_max(0) + a_out.clamp_max(0))  # -E0 >= 0
    near = torch.minimum(pos, neg)
    return slab_g_from(thickness, (pos - neg).abs(), torch.exp(-thickness * near))


def slab_g_from(thickness: torch.Tensor, spread: torch.Tensor, near_attenuation: torch.Tensor | None = None):
    """T phi(T |q - p|) exp(-T min(p, q)) from ``spread`` = |q - p| and ``near_attenuation`` =
    exp(-T min(p, q)) (None: min(p, q) = 0, both directions on one side of the layer)."""
    g = thickness * one_minus_exp_over(thickness * spread)
    return g if near_attenuation is None else g * near_attenuation


def safe_cos(cos_z: torch.Tensor) -> torch.Tensor:
    """A zero world cosine is replaced by 1 (spec 4.2)."""
    return torch.where(cos_z == 0, torch.ones_like(cos_z), cos_z)


def attenuation(thickness: torch.Tensor, area: torch.Tensor) -> torch.Tensor:
    """att(w) = exp(-T sigma(w) / |w_z|) from the signed A = sigma(w) / w_z."""
    return torch.exp(-thickness * area.abs())


def single_scattering(cos2_half: torch.Tensor, area_in: torch.Tensor, area_out: torch.Tensor,
                      alpha: torch.Tensor, thickness: torch.Tensor, inv_wi_z: torch.Tensor) -> torch.Tensor:
    """f_s / k_s = D(h) G / (4 |wi_z|), from the fiber projection of h and A_i, A_o."""
    return sggx.ndf(cos2_half, alpha) * slab_g(thickness, area_in, area_out) * (0.25 * inv_wi_z)


def multiple_scattering_asggx(cos_in: torch.Tensor, cos_out: torch.Tensor, area_in: torch.Tensor,
                              area_out: torch.Tensor, alpha_m: torch.Tensor, thickness_m: torch.Tensor,
                              inv_wi_z: torch.Tensor) -> torch.Tensor:
    """f_m / k_m = D_{alpha_m}(h') G_m / (2 |wi_z|); A_i, A_o use the single-scattering alpha."""
    return asggx.lobe(cos_in, cos_out, alpha_m) * slab_g(thickness_m, area_in, area_out) * (0.5 * inv_wi_z)


def multiple_scattering_sggx(cos_in: torch.Tensor, cos_out: torch.Tensor, cos2_half: torch.Tensor,
                             wo_z: torch.Tensor, alpha_m: torch.Tensor, thickness_m: torch.Tensor,
                             inv_wi_z: torch.Tensor) -> torch.Tensor:
    """The ablation: the single-scattering formula with alpha_m, T_m (and k_m)."""
    area_in = sggx.projected_area(cos_in, alpha_m) * inv_wi_z
    area_out = sggx.projected_area(cos_out, alpha_m) / wo_z
    return single_scattering(cos2_half, area_in, area_out, alpha_m, thickness_m, inv_wi_z)


def eval_layer(wi: torch.Tensor, wo: torch.Tensor, fiber: torch.Tensor, alpha, thickness, alpha_m, thickness_m,
               lobe: str = "asggx", forward_scattering=None):
    """One layer from directions (each (3, *batch), unit): (f_s / k_s, f_m / k_m, att(wi), att(wo)).

    ``forward_scattering``: k of :func:`backend.model.asggx.forward_peak`, applied to the ASGGX lobe
    where wi and wo lie on opposite sides of the layer (None: the paper's lobe).

    The renderer evaluates the same functions from cached projections; this form is for tests and
    tools that start from directions.
    """
    cos_in, cos_out = dot(wi, fiber), dot(wo, fiber)
    up = torch.zeros_like(wi)
    up[2] = 1.0
    half = torch.where(dot(wi + wo, wi + wo) > 1e-24, normalize(wi + wo), up)
    cos_half = dot(half, fiber)
    wi_z, wo_z = safe_cos(wi[2]), safe_cos(wo[2])
    inv_wi_z = 1.0 / wi_z.abs()
    area_in = sggx.projected_area(cos_in, alpha) / wi_z
    area_out = sggx.projected_area(cos_out, alpha) / wo_z
    single = single_scattering(cos_half * cos_half, area_in, area_out, alpha, thickness, inv_wi_z)
    if lobe == "asggx":
        multiple = multiple_scattering_asggx(cos_in, cos_out, area_in, area_out, alpha_m, thickness_m, inv_wi_z)
        if forward_scattering is not None:
            peak = asggx.forward_peak(cos_in, cos_out, 1.0 - cos_in * cos_in, 1.0 - cos_out * cos_out,
                                      dot(wi, wo), torch.as_tensor(forward_scattering, dtype=wi.dtype))
            multiple = torch.where(wi_z * wo_z < 0, multiple * peak, multiple)
    else:
        multiple = multiple_scattering_sggx(cos_in, cos_out, cos_half * cos_half, wo_z, alpha_m, thickness_m, inv_wi_z)
    return single, multiple, attenuation(thickness, area_in), attenuation(thickness, area_out)
