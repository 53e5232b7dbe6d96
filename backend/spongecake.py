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


def one_minus_exp_over(y: torch.Tensor) -> torch.Tensor:
    """phi(y) = (1 - exp(-y)) / y for y >= 0, with phi(0) = 1 and a smooth gradient near 0."""
    small = y < 1e-4
    y_safe = torch.where(small, torch.ones_like(y), y)
    return torch.where(small, 1.0 - 0.5 * y + y * y / 6.0, -torch.expm1(-y_safe) / y_safe)


def slab_g(thickness: torch.Tensor, a_in: torch.Tensor, a_out: torch.Tensor) -> torch.Tensor:
    """G(T, A_i, A_o) of spec 4.2, stable form (see the module docstring)."""
    pos = a_in.clamp_min(0) + a_out.clamp_min(0)     # E1
    neg = -(a_in.clamp_max(0) + a_out.clamp_max(0))  # -E0 >= 0
    near = torch.minimum(pos, neg)
    return thickness * torch.exp(-thickness * near) * one_minus_exp_over(thickness * (pos - neg).abs())


def safe_cos(cos_z: torch.Tensor) -> torch.Tensor:
    """A zero world cosine is replaced by 1 (spec 4.2)."""
    return torch.where(cos_z == 0, torch.ones_like(cos_z), cos_z)


def attenuation(thickness: torch.Tensor, sigma: torch.Tensor, cos_z: torch.Tensor) -> torch.Tensor:
    """att(w) = exp(-T sigma(w) / |w_z|)."""
    return torch.exp(-thickness * sigma / safe_cos(cos_z).abs())
