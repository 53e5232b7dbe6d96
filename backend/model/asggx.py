"""ASGGX: the azimuthally symmetric SGGX lobe of the multiple-scattering term (spec 4.3).

Longitudinal angles to the fiber, theta = atan2(w3, sqrt(w1^2 + w2^2)) = asin(w . o) for unit w.
Rotating wi and wo about the fiber into one longitudinal plane gives the half vector
h' = (cos th, 0, sin th) with th = (theta_i + theta_o) / 2, and the lobe uses D_alpha(h'), which
depends only on sin^2 th:

    sin^2 th = (1 - cos(theta_i + theta_o)) / 2
             = (1 + ci co - sqrt((1 - ci^2)(1 - co^2))) / 2        (ci = wi . o, co = wo . o)

so no trigonometric function is evaluated. The lobe is invariant under rotation of wo about the
fiber, which is what produces the back-lit highlight at the centre of the transmission image.

Normalisation (measured, see tests/test_bsdf_math.py): the implied phase function
D(h') / (2 sigma(wi)) is *not* a unit-integral phase function: over the sphere it integrates to
about pi for small roughness (-> the 1D half-vector Jacobian of the spec) and to 2 at alpha = 1.
The multiple-scattering albedo k_m absorbs that scale; this is the lobe the paper's renderer uses.

Forward scattering (beyond the paper). The lobe is even in the azimuth around the fiber, so a back-lit
satin's streak is as bright at its ends as at its middle, where photos show it peaked at the
straight-through direction: light crossing a yarn keeps its direction around the fibres. For light
crossing the layer (wi and wo on opposite sides of it) the lobe is multiplied by a wrapped Cauchy of
the azimuth phi of wo around the fiber, measured from the straight-through direction -wi::

    A_k(phi) = (1 - k^2) / (1 + k^2 - 2 k cos phi)
    cos phi  = -(wi . wo - ci co) / sqrt((1 - ci^2)(1 - co^2))

Its mean over the azimuth is 1 (the lobe's energy around the fiber is kept, only moved), its peak
(1 + k) / (1 - k) at phi = 0, its half-height at cos phi = 2 k / (1 + k^2); k = 0 is the paper's lobe.

===================== ======================================================== =========
parameter             meaning                                                  range
===================== ======================================================== =========
forward_scattering    k, per yarn (:mod:`backend.core.params`)                 0 - 0.9
===================== ======================================================== =========
"""
from __future__ import annotations

import torch

from .frames import safe_sqrt
from .sggx import ndf


def half_sin2(cos_in: torch.Tensor, cos_out: torch.Tensor,
              sin2_in: torch.Tensor | None = None, sin2_out: torch.Tensor | None = None) -> torch.Tensor:
    """sin^2 of the in-plane half angle th from ci = wi . o and co = wo . o (and 1 - ci^2, 1 - co^2
    when the caller has them)."""
    if sin2_in is None:
        sin2_in = 1.0 - cos_in * cos_in
    if sin2_out is None:
        sin2_out = 1.0 - cos_out * cos_out
    return half_sin2_with_cross(cos_in, cos_out, sin2_in * sin2_out)[0]


def half_sin2_with_cross(cos_in: torch.Tensor, cos_out: torch.Tensor, across2: torch.Tensor
                         ) -> tuple[torch.Tensor, torch.Tensor]:
    """(sin^2 th, sqrt((1 - ci^2)(1 - co^2))) from ci, co and ``across2`` = (1 - ci^2)(1 - co^2): the
    hand-written gradient (:mod:`backend.model.bsdf_gradient`) reads the root again."""
    cross = safe_sqrt(across2, eps=1e-14)
    return (0.5 * (1.0 + cos_in * cos_out - cross)).clamp(0.0, 1.0), cross


def lobe(cos_in: torch.Tensor, cos_out: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """D_alpha(h') of the ASGGX lobe."""
    return ndf(half_sin2(cos_in, cos_out), alpha)


def forward_peak(cos_in: torch.Tensor, cos_out: torch.Tensor, sin2_in: torch.Tensor, sin2_out: torch.Tensor,
                 cos_in_out: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """A_k(phi) from ci = wi . o, co = wo . o, their 1 - c^2 and wi . wo (module docstring)."""
    return peak_at(forward_azimuth(cos_in, cos_out, sin2_in * sin2_out, cos_in_out), k)


def forward_azimuth(cos_in: torch.Tensor, cos_out: torch.Tensor, across2: torch.Tensor,
                    cos_in_out: torch.Tensor) -> torch.Tensor:
    """cos phi from ci, co, ``across2`` = (1 - ci^2)(1 - co^2) and wi . wo; where wi or wo lies along the
    fiber the azimuth is undefined and cos phi is taken as 0 (A_k there is between its extremes, and
    the lobe's G vanishes at the fiber anyway)."""
    cos_phi = -(cos_in_out - cos_in * cos_out) * torch.rsqrt(across2.clamp_min(1e-14))
    return torch.where(across2 > 1e-14, cos_phi.clamp(-1.0, 1.0), torch.zeros_like(cos_phi))


def peak_at(cos_phi: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """A_k(phi) = (1 - k^2) / (1 + k^2 - 2 k cos phi)."""
    k2 = k * k
    return (1.0 - k2) / (1.0 + k2 - 2.0 * k * cos_phi)
