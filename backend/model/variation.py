"""Yarn variation per sample, in torch: :mod:`backend.core.variation`'s hash and smooth values on
tensors, and the factors the geometry applies (the formulas and the parameter table are there).

Per yarn family (0 warp, 1 weft), at every sample, from the yarn's plane-wide index k and its
along-yarn position p (crossings)::

    width:      xi_k  = max(xi (1 + a_w g_w(k) + a_s g_s(k, p)), XI_MIN)
    thickness:  tau_k = max(1 + a_t g_t(k) + a_s g_s(k, p), 0)       (multiplies T and T_m)
    spacing:    d_k   = a_d g_d(k) width                              (tile units, across the yarn)
    brightness: b_k   = max(1 + a_b g_b(k), 0)                        (multiplies the yarn's albedos)

The hash runs on int64 tensors (the same integers as the plain-Python form, which a test checks);
the smooth values are float64. Everything here is geometry: it depends on the variation parameters
alone, none of them optimised, so the renderer computes it once per geometry state.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..core import variation as declared
from ..core.variation import GAUSS_SCALE, HASH_MODULUS, HASH_OFFSET, KINDS, XI_MIN
from ..core.weave import WARP, WEFT, Weave


def permute(x: torch.Tensor) -> torch.Tensor:
    """R(x) = y^3 mod 4091, y = (x + 1013) mod 4091, on int64."""
    y = (x + HASH_OFFSET) % HASH_MODULUS
    return (y * y % HASH_MODULUS) * y % HASH_MODULUS


def hash_keys(stream: int, component: int, *keys: torch.Tensor) -> torch.Tensor:
    """H(s, c; keys) in 0..4090 (int64), keys broadcast together."""
    h = torch.tensor(declared.start(stream, component), dtype=torch.int64)
    for n in keys:
        n = n.to(torch.int64)
        lo = n % HASH_MODULUS
        hi = torch.div(n - lo, HASH_MODULUS, rounding_mode="floor") % HASH_MODULUS
        h = permute(permute(h + lo) + hi)
    return h


def uniform(stream: int, component: int, *keys: torch.Tensor) -> torch.Tensor:
    """u = (H + 0.5) / 4091 (float64)."""
    return (hash_keys(stream, component, *keys).to(torch.float64) + 0.5) / HASH_MODULUS


def gauss(stream: int, *keys: torch.Tensor) -> torch.Tensor:
    """G = (u_0 + u_1 - 1) sqrt(6) (float64)."""
    return (uniform(stream, 0, *keys) + uniform(stream, 1, *keys) - 1.0) * GAUSS_SCALE


def smooth(stream: int, x: torch.Tensor, length: float, *keys: torch.Tensor) -> torch.Tensor:
    """g(x): unit-variance blend of G at the knots every ``length`` along x (float64)."""
    t = x.to(torch.float64) / length
    j = torch.floor(t)
    f = t - j
    w = f * f * (3.0 - 2.0 * f)
    at, following = knot_gauss(stream, j.to(torch.int64), *keys)
    return ((1.0 - w) * at + w * following) / torch.sqrt((1.0 - w) ** 2 + w * w)


def knot_gauss(stream: int, j: torch.Tensor, *keys: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(G(keys, j), G(keys, j + 1)) at every point, the keys and j broadcast together.

    A cloth's keys take few values (a few hundred yarns, knots) over a million samples, so G is
    hashed once per combination in the keys' ranges and gathered: the same numbers as
    :func:`knot_gauss_direct`, which hashes every sample, for a small part of its cost. Where the
    ranges hold more combinations than there are samples, it hashes every sample."""
    keys = torch.broadcast_tensors(*(k.to(torch.int64) for k in keys), j)
    if keys[0].numel() == 0:
        return knot_gauss_direct(stream, j, *keys[:-1])
    lows = [int(k.min()) for k in keys]
    spans = [int(k.max()) - low + 1 for k, low in zip(keys, lows)]
    spans[-1] += 1                                  # the last knot's following one
    if math.prod(spans) >= keys[0].numel():
        return knot_gauss_direct(stream, j, *keys[:-1])
    grid = torch.meshgrid(*(torch.arange(low, low + span, device=j.device) for low, span in zip(lows, spans)),
                          indexing="ij")
    table = gauss(stream, *grid).reshape(-1)
    index = torch.zeros_like(keys[0])
    for k, low, span in zip(keys, lows, spans):
        index = index * span + (k - low)
    return table[index], table[index + 1]         # j is the grid's last axis: j + 1 is the next entry


def knot_gauss_direct(stream: int, j: torch.Tensor, *keys: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`knot_gauss` hashed at every sample (its plain twin, and its path for sparse keys)."""
    return gauss(stream, *keys, j), gauss(stream, *keys, j + 1)


@dataclass(frozen=True)
class VariationSettings:
    """The variation parameters of one state, by name: (warp, weft) each (:data:`PARAMETER_NAMES`)."""

    values: tuple[tuple[float, float], ...]

    @classmethod
    def of(cls, get) -> "VariationSettings":
        """From a getter of parameter values by name (``FabricParams`` attributes, tensors' scalars)."""
        return cls(tuple(tuple(float(v) for v in get(name)) for name in declared.PARAMETER_NAMES))

    def value(self, name: str, family: int) -> float:
        return self.values[declared.PARAMETER_NAMES.index(name)][family]

    def amplitude(self, kind: str, family: int) -> float:
        return self.value(declared.amplitude_name(kind), family)

    def length(self, kind: str, family: int) -> float:
        return self.value(declared.length_name(kind), family)

    @property
    def active(self) -> bool:
        """Whether any amplitude is above 0 (with none, the geometry is exactly the unvaried one)."""
        return any(self.amplitude(kind, family) > 0 for kind in KINDS for family in (0, 1))


def yarn_positions(weave: Weave, X, Y, tile_u, tile_v, col, row) -> tuple[tuple[torch.Tensor, torch.Tensor], ...]:
    """((k, p) of the warp, (k, p) of the weft) through each point: the plane-wide yarn index (int64)
    and the along-yarn position in crossings (float64), from tile units (X, Y), tile indices and the
    band's column / row in the tile (``WeaveLookup.bands``)."""
    X, Y = X.to(torch.float64), Y.to(torch.float64)
    right = X + tile_u.to(torch.float64) * weave.tile_width      # to the right, over the plane
    down = Y - tile_v.to(torch.float64) * weave.tile_height      # down the image, over the plane
    # the tile of the band: the lookup's own wrap (remainder(X - offset, tile width)), so k agrees with col
    warp_tile = torch.floor((X - weave.warp_offset) / weave.tile_width).to(torch.int64) + tile_u
    weft_tile = torch.floor((Y - weave.weft_offset) / weave.tile_height).to(torch.int64) - tile_v
    warp = (warp_tile * weave.cols + col.to(torch.int64), down / weave.weft_pitch)
    weft = (weft_tile * weave.rows + row.to(torch.int64), right / weave.warp_pitch)
    return warp, weft


def family_factors(settings: VariationSettings, family: int, weave: Weave, xi: float, k: torch.Tensor,
                   p: torch.Tensor, dtype) -> dict[str, torch.Tensor]:
    """One family's factors at its yarn (k, p) through each point: ``xi`` (the varied gap scale),
    ``shift`` (tile units), ``thickness`` and ``brightness`` (the module's formulas), in ``dtype``."""
    zero = torch.zeros_like(p)

    def per_yarn(kind: str) -> torch.Tensor:
        a = settings.amplitude(kind, family)
        if a <= 0:
            return zero
        return a * smooth(declared.stream(kind, family), k.to(torch.float64), settings.length(kind, family))

    a_slub = settings.amplitude("slub", family)
    slub = (a_slub * smooth(declared.stream("slub", family), p, settings.length("slub", family), k)
            if a_slub > 0 else zero)
    width = weave.band(family)[0]
    return {"xi": torch.clamp(xi * (1.0 + (per_yarn("width") + slub)), min=XI_MIN).to(dtype),
            "shift": (per_yarn("spacing") * width).to(dtype),
            "thickness": torch.clamp(1.0 + (per_yarn("thickness") + slub), min=0.0).to(dtype),
            "brightness": torch.clamp(1.0 + per_yarn("brightness"), min=0.0).to(dtype)}


def factors(settings: VariationSettings, weave: Weave, gap_scale, X, Y, tile_u, tile_v, col, row,
            dtype) -> tuple[dict, dict]:
    """The warp's and the weft's :func:`family_factors` at every point."""
    positions = yarn_positions(weave, X, Y, tile_u, tile_v, col, row)
    return tuple(family_factors(settings, family, weave, gap_scale[family], k, p, dtype)
                 for family, (k, p) in zip((WARP, WEFT), positions))

