"""Yarn variation: the irregularity of real yarns, as a deterministic function of yarn and position.

Real cloth is not a perfect lattice (the paper's limitation: "variations in yarn diameter, yarn
sliding, ..."). Each yarn family (warp, weft) can carry five random variations, each an amplitude
(a standard deviation; 0, the default, is none) and a correlation length:

    =====================  ==========================================================  ===============
    variation              what changes, for yarn k of a family at along-position p     correlation in
    =====================  ==========================================================  ===============
    width_variation        the yarn's width: xi_k = max(xi (1 + a g(k) + s(k, p)),     yarns
                           XI_MIN); narrower yarns open gaps, wider ones close them
    thickness_variation    optical thickness: T, T_m times max(1 + a g(k) + s(k, p), 0) yarns
    spacing_variation      sliding: the yarn's centre line moves across by             yarns
                           a g(k) times its nominal width (clipped by its band)
    brightness_variation   albedo: k_s, k_m (and k_d where the yarn is the one seen)   yarns
                           times max(1 + a g(k), 0)
    slub_variation         along-yarn (slub) variation s(k, p) = a g(k, p) of width    crossings
                           and thickness together: thick and thin stretches            (along the yarn)
    =====================  ==========================================================  ===============

Each ``<name>`` has its correlation length ``<name>_length`` (per yarn family): across yarns in
yarns (1: every yarn independent; 8: neighbouring yarns drift together over about 8), along a
yarn in crossings (pitches of the yarns it crosses). Ranges (backend/core/params.py, with the priors
a generator draws from): amplitudes 0 to 0.5, lengths 1 to 64 yarns, the slub's 0.5 to 64 crossings.
Gap variation is width variation: the model's gap scale is the yarn's width as a fraction of its band (spec 3.1).

Indexing. Warp k counts columns of bands to the right, weft k rows down the image, over the whole
plane (tile index times the tile's yarns plus the band's index in the tile); p is the position
along the yarn in crossings (down the image for a warp, to the right for a weft), from the plane's
UV origin. So the variation is a function of the cloth, not of the render: the draped cloth in
Blender shows the re-render's irregularity.

Smooth values. With knots every L (the correlation length) along the axis x (k for per-yarn values,
p for slubs), t = x / L, j = floor(t), f = t - j and w = f^2 (3 - 2 f)::

    g(x) = ((1 - w) G(j) + w G(j + 1)) / sqrt((1 - w)^2 + w^2)

unit variance at every x, and G(j) = (u_0(j) + u_1(j) - 1) sqrt(6), the sum of two hashed uniforms
(zero mean, unit variance, bounded by sqrt(6)). With L = 1 on yarn indices g(k) = G(k): independent
yarns.

The hash (the one definition: the renderer, the slow reference and the OSL shader compute the same
numbers; the standard-node fallback's program has it too, but its built node group leaves it out:
blender_addon/core/shader_fallback.py). Integers only, every intermediate below 2^24, so float32 arithmetic
(OSL, Blender's Math nodes) is exact and gives the same bits as int64 (torch) and Python::

    R(x)       = y^3 mod 4091,  y = (x + 1013) mod 4091   (cubing permutes 0..4090: 4091 is a prime
                                                            with 3 not dividing 4090; y^2 < 2^24)
    lo(n)      = n mod 4091,  hi(n) = ((n - lo(n)) / 4091) mod 4091   (floored modulo, any sign)
    start(s,c) = R(R(s) + c)                              (stream s, component c: constants)
    H(s,c; n1, n2, ...) = fold h <- R(R(h + lo(n)) + hi(n)) over the keys, from start(s, c)
    u_c        = (H + 0.5) / 4091

with stream ``s = 2 kind + family`` (kinds in :data:`KINDS` order, family 0 warp, 1 weft). Per-yarn
values hash the knot index (keys j), slubs the yarn and the knot (keys k, j). Keys must stay below
2^24 in magnitude (yarn indices and knots of any cloth do). A quadratic permutation mod 289 (the
GLSL noise "permute") is cheaper but is the identity mod 17, which left neighbouring yarns
correlated by up to -0.24; this cube's are within +-0.01 (tests/test_variation.py).

This module is torch-free (the add-on reads its constants); :mod:`backend.model.variation` is the
tensor form, and its test checks both give the same bits.
"""
from __future__ import annotations

import math

KINDS = ("width", "thickness", "spacing", "brightness", "slub")
# The kinds whose correlation length runs across yarns (in yarns); the slub's runs along a yarn.
ACROSS_YARNS = ("width", "thickness", "spacing", "brightness")

HASH_MODULUS = 4091    # a prime below 2^12: products of two residues stay below 2^24 (exact in float32)
HASH_OFFSET = 1013     # added before cubing: moves the cube's fixed points (0, 1, p - 1) off small keys
GAUSS_SCALE = math.sqrt(6.0)  # (u0 + u1 - 1) has variance 1/6: this makes G unit variance
XI_MIN = 0.01          # the narrowest a varied yarn gets (gap scale's lower bound): a yarn never vanishes


def amplitude_name(kind: str) -> str:
    """The parameter holding a kind's amplitude (``width`` -> ``width_variation``)."""
    return f"{kind}_variation"


def length_name(kind: str) -> str:
    """The parameter holding a kind's correlation length (``width`` -> ``width_variation_length``)."""
    return f"{kind}_variation_length"


PARAMETER_NAMES = tuple(name for kind in KINDS for name in (amplitude_name(kind), length_name(kind)))


def stream(kind: str, family: int) -> int:
    """The hash stream of one kind and yarn family (0 warp, 1 weft)."""
    return 2 * KINDS.index(kind) + family


# -- the plain reference: Python integers -------------------------------------------------------
def permute(x: int) -> int:
    """R(x) = y^3 mod 4091 with y = (x + 1013) mod 4091."""
    y = (x + HASH_OFFSET) % HASH_MODULUS
    return (y * y % HASH_MODULUS) * y % HASH_MODULUS


def split(n: int) -> tuple[int, int]:
    """(lo, hi) of an integer key: n mod 4091 and ((n - lo) / 4091) mod 4091 (floored, any sign)."""
    lo = n % HASH_MODULUS
    return lo, ((n - lo) // HASH_MODULUS) % HASH_MODULUS


def start(stream_: int, component: int) -> int:
    """The fold's start value of a stream and component (a constant per kind and family)."""
    return permute(permute(stream_) + component)


def hash_keys(stream_: int, component: int, *keys: int) -> int:
    """H(s, c; keys) in 0..4090."""
    h = start(stream_, component)
    for n in keys:
        lo, hi = split(int(n))
        h = permute(permute(h + lo) + hi)
    return h


def uniform(stream_: int, component: int, *keys: int) -> float:
    """u = (H + 0.5) / 4091, in (0, 1)."""
    return (hash_keys(stream_, component, *keys) + 0.5) / HASH_MODULUS


def gauss(stream_: int, *keys: int) -> float:
    """G = (u_0 + u_1 - 1) sqrt(6): zero mean, unit variance, |G| < sqrt(6)."""
    return (uniform(stream_, 0, *keys) + uniform(stream_, 1, *keys) - 1.0) * GAUSS_SCALE


def smooth(stream_: int, x: float, length: float, *keys: int) -> float:
    """g(x): G at knots every ``length`` along x (keys ``*keys, j``), smoothly blended at unit variance."""
    t = x / length
    j = math.floor(t)
    f = t - j
    w = f * f * (3.0 - 2.0 * f)
    return (((1.0 - w) * gauss(stream_, *keys, j) + w * gauss(stream_, *keys, j + 1))
            / math.sqrt((1.0 - w) ** 2 + w * w))
