"""SGGX fiber microflake distribution (spec 4.1).

In the fiber frame (n, b, o) with fiber direction o and roughness alpha (S = diag(1, 1, alpha^2)):

    sigma(w) = sqrt(w1^2 + w2^2 + alpha^2 w3^2)                 projected area
    D(w)     = 1 / (pi alpha (w1^2 + w2^2 + w3^2 / alpha^2)^2)  microflake normal distribution

Both are symmetric about o, so for a unit w they depend only on c = w . o (w1^2 + w2^2 = 1 - c^2):

    sigma = sqrt(1 - (1 - alpha^2) c^2),   D = 1 / (pi alpha (1 + (1 / alpha^2 - 1) c^2)^2)

which is what the fast path evaluates (no frame is ever built); the ``*_from`` forms take the
per-yarn constants 1 - alpha^2, 1 / alpha^2 - 1 and 1 / (pi alpha) ready-made (the renderer forms them
once per iteration and picks them per sample). The phase function of specular
microflakes, p(wi -> wo) = D(h) / (4 sigma(wi)) with h = normalize(wi + wo), integrates to 1 over
the sphere (tested).
"""
from __future__ import annotations

import math

import torch

from .frames import safe_sqrt


def projected_area(cos_fiber: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """sigma(w) from c = w . o (unit w)."""
    return projected_area_from(cos_fiber * cos_fiber, 1.0 - alpha * alpha)


def projected_area_from(cos2_fiber: torch.Tensor, flattening: torch.Tensor) -> torch.Tensor:
    """sigma(w) from c^2 and ``flattening`` = 1 - alpha^2."""
    return safe_sqrt(1.0 - flattening * cos2_fiber)


def ndf(cos2_fiber: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """D(w) from c^2 = (w . o)^2 (unit w)."""
    return ndf_from(cos2_fiber, 1.0 / (alpha * alpha) - 1.0, 1.0 / (math.pi * alpha))


def ndf_from(cos2_fiber: torch.Tensor, shape: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """D(w) from c^2, ``shape`` = 1 / alpha^2 - 1 and ``scale`` = 1 / (pi alpha)."""
    denom = 1.0 + shape * cos2_fiber
    return scale / (denom * denom)


def phase(cos_fiber_in: torch.Tensor, cos2_fiber_half: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """Specular microflake phase function D(h) / (4 sigma(wi)), per steradian."""
    return ndf(cos2_fiber_half, alpha) / (4.0 * projected_area(cos_fiber_in, alpha))
