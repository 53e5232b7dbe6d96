"""Turned placements read from pairs of strong peaks.

Dense weaves at 2-3 px per yarn behind a phone's blur can leave a few strong peaks (a plain's
(1, 1) and (-1, 1), a yarn harmonic) whose aliased companions pull each axis's sieve to a wrong
spacing; the peaks' positions alone still pin the turn. Two of a photo's ``peak_pair_peaks``
strongest peaks p, q (q or -q: a real image's spectrum is symmetric) taken as two harmonics
(m1, n1), (m2, n2) with |m|, n <= ``peak_pair_order``:

    p = m1 u + n1 v,    q = m2 u + n2 v

solve for the image vectors u and v of the fabric's harmonics (1, 0) and (0, 1), whose angles are
the yarns' (:func:`backend.texture.frequencies.yarn_vector_angles`) and whose lengths are the
lattice (a, b) = (|u|, |v|). Kept where both yarn angles lie within the scan and ``max_skew_deg`` of
each other and (a, b) within the ranges; the ``refined_hypotheses`` that the generic harmonics
score best are refined as turns.
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from ...core.rig import placement_of
from ..frequencies import yarn_vector_angles
from ..gates import GATES
from ..lattice import Lattice, signature_score
from ..spectra import Spectra
from .scan import Placement, Scan


def _bases(order: int) -> np.ndarray:
    """Every ordered pair of low harmonics (m, n) (half plane, |m|, n <= order) that pins u and v
    (independent harmonics), inverted: (pairs, 2, 2); a pair of peaks is then solved by two products
    per basis, not one LAPACK call per pair."""
    harmonics = [(m, n) for m in range(-order, order + 1) for n in range(order + 1) if n > 0 or m > 0]
    bases = np.array([(h1, h2) for h1, h2 in itertools.permutations(harmonics, 2)
                      if h1[0] * h2[1] != h1[1] * h2[0]], dtype=float)
    return np.linalg.inv(bases)


_INVERSES = _bases(GATES.peak_pair_order)


def peak_pair_turns(spectra: Spectra, a_range: tuple[float, float], b_range: tuple[float, float]
                    ) -> list[tuple[float, float, float]]:
    """(a, b, rotation) of every reading kept (module docstring), one per (a, b, rotation) rounded
    to (1, 1, 0.1)."""
    (a_lo, a_hi), (b_lo, b_hi) = a_range, b_range
    found = {}
    for peaks in spectra.peaks:
        for p, q in itertools.combinations(peaks[:GATES.peak_pair_peaks], 2):
            for sign in (1.0, -1.0):
                images = np.array([[p.fx, p.fy], [sign * q.fx, sign * q.fy]])
                solved = _INVERSES[:, :, 0, None] * images[0] + _INVERSES[:, :, 1, None] * images[1]
                for u, v in solved:
                    a, b = math.hypot(*u), math.hypot(*v)
                    if a_lo <= a <= a_hi and b_lo <= b <= b_hi:
                        for turn in _turns(u, v):
                            found.setdefault((round(a), round(b), round(turn, 1)), (a, b, turn))
    return list(found.values())


def _turns(u: np.ndarray, v: np.ndarray) -> list[float]:
    """The turns of the yarn vectors +-u, +-v whose angles lie within the scan and within
    ``max_skew_deg`` of each other."""
    out = []
    for u_sign, v_sign in itertools.product((1.0, -1.0), repeat=2):
        warp, weft = yarn_vector_angles(u_sign * u, v_sign * v)
        if abs(warp) <= GATES.scan_deg and abs(weft) <= GATES.scan_deg and abs(warp - weft) <= GATES.max_skew_deg:
            out.append(placement_of(warp, weft)[0])
    return out


def peaked(scan: Scan) -> list[Placement]:
    """The best-scored peak-pair readings, refined as turns."""
    spectra = scan.spectra
    readings = sorted(peak_pair_turns(spectra, scan.a_range, scan.b_range), key=lambda t: -float(
        signature_score(spectra.maps, scan.generic, t[0], t[1], spectra.size, t[2])))
    return scan.refined([(Lattice(a, b, 0.0), turn, turn) for a, b, turn in readings[:GATES.refined_hypotheses]])
