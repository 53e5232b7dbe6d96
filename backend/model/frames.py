"""Vector helpers shared by the geometry and BSDF modules.

Vector fields are stored *component first*: a tensor of shape ``(3, *batch)``, so that each
component is contiguous (cheap elementwise work on the CPU) and ``v[0]``, ``v[1]``, ``v[2]`` are
the x, y, z components. Directions follow the spec's naming: ``wi`` points from the surface to the
camera, ``wo`` to the light; world +z is the macroscopic normal on the camera side.
"""
from __future__ import annotations

import torch


def dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Dot product over the leading (component) axis."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.stack((a[1] * b[2] - a[2] * b[1],
                        a[2] * b[0] - a[0] * b[2],
                        a[0] * b[1] - a[1] * b[0]))


def normalize(a: torch.Tensor) -> torch.Tensor:
    """a / |a|; a zero vector stays (near) zero instead of becoming NaN (|a|^2 is floored at 1e-20)."""
    return a * torch.rsqrt(dot(a, a).clamp_min(1e-20))


def safe_sqrt(x: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """sqrt that tolerates tiny negative rounding and has a finite gradient at 0."""
    return torch.sqrt(x.clamp_min(eps))
