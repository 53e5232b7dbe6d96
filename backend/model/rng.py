"""Counter-based random numbers: a hash of integer coordinates, so results do not depend on how
work is split into chunks (or on the device).

The mixer is Chris Wellons' "lowbias32" (xor-shift-multiply), evaluated in int64 with 32-bit
wrap-around; products are split into 16-bit halves so nothing overflows int64.
"""
from __future__ import annotations

import torch

_MASK = 0xFFFFFFFF


def _mul32(x: torch.Tensor, m: int) -> torch.Tensor:
    lo, hi = m & 0xFFFF, m >> 16
    return (x * lo + ((x * hi) & 0xFFFF) * 65536) & _MASK


def hash32(x: torch.Tensor) -> torch.Tensor:
    x = x & _MASK
    x = x ^ (x >> 16)
    x = _mul32(x, 0x7FEB352D)
    x = x ^ (x >> 15)
    x = _mul32(x, 0x846CA68B)
    return x ^ (x >> 16)


def hash32_int(x: int) -> int:
    """:func:`hash32` of one Python integer (for seeding generators)."""
    x &= _MASK
    x ^= x >> 16
    x = (x * 0x7FEB352D) & _MASK
    x ^= x >> 15
    x = (x * 0x846CA68B) & _MASK
    return x ^ (x >> 16)


def uniform(*keys, seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    """A uniform number in [0, 1) for each combination of integer keys (broadcast together)."""
    tensors = [k if isinstance(k, torch.Tensor) else torch.tensor(k, dtype=torch.int64) for k in keys]
    tensors = torch.broadcast_tensors(*[t.to(torch.int64) for t in tensors])
    h = hash32(torch.full_like(tensors[0], seed & _MASK))
    for t in tensors:
        h = hash32(h ^ (t & _MASK))
    return (h >> 8).to(dtype) * (1.0 / (1 << 24))
