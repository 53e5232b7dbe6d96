"""The harmonic sieve: the tile spacing per fabric axis that explains the photos' spectral peaks.

Each fabric axis is a 1D comb search over a fine log grid of spacings s, on the peaks' frequencies
turned back into the fabric's (:func:`backend.texture.frequencies.fabric_frequencies`):

    score(s) = sum over peaks p of  strength_p exp(-d_p(s)^2 / (2 sigma^2))  -  tooth_cost * teeth(s) * photos,

d_p(s) the distance of |f_p| from the nearest folded multiple m s (|m s| <= reach * N), teeth(s) =
floor(reach N / s). Without the cost per tooth every sub-multiple of the true spacing (and, with
enough teeth, any small spacing) would explain the peaks equally well; with it the coarsest comb
that explains them wins. This pins the lattice up to small sub- and super-multiples, without
knowing the weave. Axis 0 (f1) reads the peaks along the normal of the wefts, axis 1 along the
normal of the warps, so each axis's score depends on one yarn angle only.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.threads import ordered_map
from ..image.spectrum import Peak
from .frequencies import fabric_frequencies, fold
from .gates import GATES
from .lattice import Lattice
from .spectra import COARSE_SIZE, Spectra


def comb_scores(freqs: np.ndarray, strengths: np.ndarray, periods: np.ndarray, size: int,
                sigma: float = 0.35, reach: float = 1.6) -> np.ndarray:
    """How well each spacing of ``periods`` explains the (folded) peak frequencies: the sum of the
    strengths of peaks within about ``sigma`` cycles of a folded multiple m * spacing,
    |m * spacing| <= reach * size."""
    multiples = np.arange(1, int(reach * size / periods.min()) + 1)[:, None] * periods[None, :]  # (M, G)
    folded = np.where(multiples <= reach * size, np.abs(fold(multiples, size)), np.inf)
    scores = np.zeros(len(periods))
    for f, s in zip(freqs, strengths):  # one peak at a time keeps the arrays (M, G) small
        # the nearest tooth's hit: exp is monotonic, so one exp per spacing instead of M
        nearest = np.abs(folded - abs(f)).min(axis=0)
        scores += s * np.exp(-0.5 * (nearest / sigma) ** 2)
    return scores


def combs(peaks: list[Peak], images: int, size: int, ranges, rotation_deg: float, skew_deg: float, step: float,
          tooth_cost: float = GATES.tooth_cost, reach: float = GATES.comb_reach
          ) -> tuple[tuple[float, float], tuple[float, float]]:
    """((spacing on axis 0, on axis 1), (their scores)): each fabric axis's best comb on a log grid
    of ``step`` over its range of ``ranges``, for the peaks turned back by ``rotation_deg`` and
    ``skew_deg``."""
    f1, f2 = fabric_frequencies(np.array([p.fx for p in peaks]), np.array([p.fy for p in peaks]), rotation_deg,
                                skew_deg)
    strengths = np.array([p.strength for p in peaks])
    spacing, score = [], []
    for freqs, (lo, hi) in ((f1, ranges[0]), (f2, ranges[1])):
        informative = np.abs(freqs) > GATES.informative_cycles
        grid = np.exp(np.arange(math.log(lo), math.log(hi), step))
        scores = comb_scores(freqs[informative], strengths[informative], grid, size, reach=reach)
        scores = scores - tooth_cost * np.floor(reach * size / grid) * images
        best = int(np.argmax(scores))
        spacing.append(float(grid[best]))
        score.append(float(scores[best]))
    return (spacing[0], spacing[1]), (score[0], score[1])


def estimate(spectra: Spectra, a_range: tuple[float, float], b_range: tuple[float, float],
             rotation_deg: float = 0.0, skew_deg: float = 0.0, coarse: bool = False,
             step: float = 0.0002) -> Lattice:
    """The tile lattice (a, b) explaining the spectral peaks of the photos (of the shrunk photos with
    ``coarse``), independent of the pattern; its score is both axes' summed."""
    by_image, size = (spectra.coarse, COARSE_SIZE) if coarse else (spectra.peaks, spectra.size)
    peaks = [p for image_peaks in by_image for p in image_peaks]
    (a, b), scores = combs(peaks, len(by_image), size, (a_range, b_range), rotation_deg, skew_deg, step)
    return Lattice(a, b, sum(scores))


def estimates(spectra: Spectra, a_range: tuple[float, float], b_range: tuple[float, float],
              rotation_deg: float = 0.0, skew_deg: float = 0.0, workers: int = 1) -> list[Lattice]:
    """:func:`estimate` on the photos' peaks, and on the shrunk photos' peaks when there are any
    (two hypotheses: which explains the peakness maps is for the candidates to say), on up to
    ``workers`` threads."""
    return ordered_map(lambda coarse: estimate(spectra, a_range, b_range, rotation_deg=rotation_deg,
                                               skew_deg=skew_deg, coarse=coarse),
                       (False, True) if spectra.coarse is not None else (False,), workers)
