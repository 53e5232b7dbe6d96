"""How well a tile lattice explains a photo's spectrum.

A weave repeats on its tile, so every peak of its photos (but noise) is a harmonic ``(m a, n b)`` of
its lattice (:mod:`.frequencies`), folded by the sampling. Which harmonics carry the energy depends
on the weave: its *signature* (:class:`Signature`), the relative power of each harmonic, measured
once from a render at a low density where every significant one is below Nyquist (:func:`signature`).

- :func:`signature_score`: the signature-weighted peakness of the photos at a lattice's harmonics,

      score(a, b) = sum over photos, harmonics k of  w_k' * h_k * q(fold(turned(m_k a, n_k b))),

  with q the photo's peakness map (bilinear lookup), w_k' = sqrt(w_k) / sum sqrt(w) (the square root
  lets the weaker harmonics count) and h_k = 1/2 where the harmonic folded (an alias is less sure);
- :func:`polish`: the best lattice on a small log grid around a start;
- :func:`peak_coverage`: the share of the photos' peak strength the lattice can make at all.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..image.spectrum import windowed_highpass
from .frequencies import UNTURNED, fold, turn, turned_by, turned_frequencies
from .gates import GATES
from .spectra import Spectra


@dataclass(frozen=True)
class Signature:
    """Relative power of the lattice harmonics (m, n) of a pattern; n >= 0 (half plane)."""

    m: np.ndarray
    n: np.ndarray
    weight: np.ndarray   # sums to 1


@dataclass(frozen=True)
class Lattice:
    a: float       # tiles across the image (cycles per image width)
    b: float       # tiles down the image
    score: float

    def tiles(self, view_size: float, plane_size: float) -> tuple[float, float]:
        return self.a * plane_size / view_size, self.b * plane_size / view_size


def generic_signature(order: int = 3) -> Signature:
    """Every low harmonic |m|, n <= order (half plane), equally weighted: any weave's lattice."""
    m, n = np.meshgrid(np.arange(-order, order + 1), np.arange(0, order + 1))
    keep = (n > 0) | (m > 0)
    return Signature(m[keep], n[keep], np.full(int(keep.sum()), 1.0 / int(keep.sum())))


def harmonic_spectrum(image: np.ndarray, a: float, b: float, m: np.ndarray, n: np.ndarray) -> np.ndarray:
    """|DFT|^2 of the windowed, high-passed luminance at the frequencies (m a, n b), cycles per image
    (exact: the separable DFT at those frequencies, not the FFT grid)."""
    y = windowed_highpass(image, image.shape[0] / 64)
    h, w = y.shape
    um, un = np.unique(m), np.unique(n)
    ex = np.exp(-2j * np.pi * np.outer(um * a, np.arange(w)) / w)
    ey = np.exp(-2j * np.pi * np.outer(un * b, np.arange(h)) / h)
    full = ey @ y @ ex.T
    return np.abs(full[np.searchsorted(un, n), np.searchsorted(um, m)]) ** 2


def signature(image: np.ndarray, a: float, b: float, order: int = 6, keep: int = 24) -> Signature:
    """The ``keep`` strongest lattice harmonics, |m|, n <= ``order``, of an image whose lattice (a, b)
    is known and unaliased, with the render's own pixel box filter (sinc^2) undone so that the
    signature describes the tile, not the film."""
    h, w = image.shape[:2]
    mm, nn = np.meshgrid(np.arange(-order, order + 1), np.arange(0, order + 1))
    mm, nn = mm.ravel(), nn.ravel()
    ok = ((nn > 0) | (mm > 0)) & (np.abs(mm) * a < w / 2) & (nn * b < h / 2)
    mm, nn = mm[ok], nn[ok]
    power = harmonic_spectrum(image, a, b, mm, nn)
    power = power / (np.sinc(mm * a / w) ** 2 * np.sinc(nn * b / h) ** 2)
    best = np.argsort(-power)[:keep]
    weight = power[best] / power[best].sum()
    return Signature(mm[best], nn[best], weight)


def _lookup(q: np.ndarray, fx: np.ndarray, fy: np.ndarray, size: int) -> np.ndarray:
    """Bilinear lookup of a zero-padded, fftshifted map at frequencies (cycles per image; fy along
    image rows, downwards, as the DFT probe)."""
    pad = q.shape[0] // size
    cx, cy = q.shape[1] / 2, q.shape[0] / 2
    x = np.clip(cx + fx * pad, 0, q.shape[1] - 1.001)
    y = np.clip(cy + fy * pad, 0, q.shape[0] - 1.001)
    x0, y0 = np.floor(x).astype(np.intp), np.floor(y).astype(np.intp)
    tx, ty = x - x0, y - y0
    # gathers from the flat map: the same four samples as q[y0, x0] ..., in half the time
    flat, width = q.ravel(), q.shape[1]
    corner = y0 * width + x0
    return ((1 - tx) * (1 - ty) * flat.take(corner) + tx * (1 - ty) * flat.take(corner + 1)
            + (1 - tx) * ty * flat.take(corner + width) + tx * ty * flat.take(corner + width + 1))


def signature_score(maps, signatures, a, b, size, rotation_deg: float = 0.0, skew_deg: float = 0.0) -> np.ndarray:
    """The score (module docstring) of lattices (a, b) (numbers or arrays that broadcast; the score
    has their broadcast shape) of a sample turned by ``rotation_deg`` and sheared by ``skew_deg``."""
    shape = np.broadcast(a, b).shape
    a, b = np.broadcast_to(a, shape).ravel(), np.broadcast_to(b, shape).ravel()
    return _scores(maps, signatures, a, b, size, turn(rotation_deg, skew_deg)).reshape(shape)


def scores_at_angles(maps, signatures, a: float, b: float, size: int, placements) -> np.ndarray:
    """:func:`signature_score` of one lattice (a, b) at each (rotation, skew) of ``placements``, at
    once: the same numbers as one call per placement (the same floating-point operations per
    element), without the overhead of hundreds of small calls."""
    turns = np.array([turn(rotation, skew) for rotation, skew in placements])  # (P, 4)
    return _scores(maps, signatures, np.full(len(turns), float(a)), np.full(len(turns), float(b)), size,
                   tuple(turns.T))


def _scores(maps, signatures, a: np.ndarray, b: np.ndarray, size: int, factors) -> np.ndarray:
    """:func:`signature_score` of lattices (a[k], b[k]) (K,) at the factors of :func:`.frequencies.turn`
    (numbers, or arrays (K,) with one placement per lattice)."""
    total = np.zeros(a.shape)
    for q, sig in zip(maps, signatures):
        weights = np.sqrt(sig.weight)
        weights = weights / weights.sum()
        f1, f2 = sig.m[:, None] * a[None, :], sig.n[:, None] * b[None, :]  # every harmonic at once (rows)
        # an unturned sample skips the products (the same frequencies, up to the sign of a zero)
        fx, fy = (f1, f2) if factors is UNTURNED else turned_by(f1, f2, *factors)
        folded = (np.abs(fx) > size / 2) | (np.abs(fy) > size / 2)
        looked_up = _lookup(q, fold(fx, size), fold(fy, size), size)
        # added one row at a time in the signature's order: numpy's reduction would sum a single
        # lattice's column pairwise, and the sums must not depend on how many are scored at once
        for row in weights[:, None] * np.where(folded, 0.5, 1.0) * looked_up:
            total = total + row
    return total


def polish(maps, signatures, start: Lattice, size: int, span: float, step: float, rotation_deg: float = 0.0,
           skew_deg: float = 0.0) -> Lattice:
    """The best-scoring lattice on a log grid of +-``span`` (relative, in ``step`` steps) around
    ``start``, on each axis."""
    factors = np.exp(np.arange(-span, span + step / 2, step))
    a = start.a * factors[None, :]
    b = start.b * factors[:, None]
    scores = signature_score(maps, signatures, a, b, size, rotation_deg, skew_deg)
    row, col = np.unravel_index(int(np.argmax(scores)), scores.shape)
    a_best = float(np.broadcast_to(a, scores.shape)[row, col])
    b_best = float(np.broadcast_to(b, scores.shape)[row, col])
    return Lattice(a_best, b_best, float(scores[row, col]))


def peak_coverage(spectra: Spectra, a: float, b: float, rotation_deg: float = 0.0, skew_deg: float = 0.0) -> float:
    """The share of the photos' peak strength that the tile lattice (a, b) (tiles across and down the
    image, the sample turned and sheared as given) can make: over each photo's ``coverage_peaks``
    strongest peaks, the strength of those within ``coverage_tolerance`` of a folded harmonic,
    divided by the strength of all of them.

    A lattice too fine on one axis misses the harmonics between its own; one too coarse has
    harmonics everywhere and explains everything, so the measure can rule a lattice out, never in."""
    size = spectra.size
    peaks = [p for image_peaks in spectra.peaks for p in image_peaks[:GATES.coverage_peaks]]
    total = sum(p.strength for p in peaks)
    if total <= 0:
        return 1.0
    reach = GATES.coverage_reach * size / 2
    m = np.arange(-math.ceil(reach / a), math.ceil(reach / a) + 1)
    n = np.arange(-math.ceil(reach / b), math.ceil(reach / b) + 1)
    fx, fy = turned_frequencies(m[:, None] * a, n[None, :] * b, rotation_deg, skew_deg)
    fx, fy = np.broadcast_to(fx, (m.size, n.size)).ravel(), np.broadcast_to(fy, (m.size, n.size)).ravel()
    near = (np.abs(fx) <= reach) & (np.abs(fy) <= reach)
    fx, fy = fold(fx[near], size), fold(fy[near], size)
    within, per_cycle = GATES.coverage_tolerance
    explained = 0.0
    for p in peaks:
        # a real image's spectrum is symmetric: the peak at -f is the same peak
        distance = min(np.min(np.hypot(fx - p.fx, fy - p.fy)), np.min(np.hypot(fx + p.fx, fy + p.fy)))
        if distance <= within + per_cycle * math.hypot(p.fx, p.fy):
            explained += p.strength
    return explained / total
