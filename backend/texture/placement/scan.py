"""The evidence every placement hypothesis reads: the harmonic sieves at each angle of a scan.

A sample turned by theta shows its lattice turned by theta (:mod:`backend.texture.frequencies`), so
the sieve (:mod:`backend.texture.sieve`) on the peaks turned back by the right angle finds a strong
comb on each axis. The scan runs it at every angle of +-``scan_deg`` in ``scan_step_deg`` steps on a
coarse spacing grid. Axis 0's score depends on the weft angle only, axis 1's on the warp angle, so
one scan gives both a turn (where their sum peaks) and a shear (a pair of angles).

Each angle's sieve lattice is also scored against the whole 2D peakness maps at its multiples
(:func:`multiples`, the ``rotation_ratios`` per axis: a sieve pins a spacing only up to sub- and
super-multiples) with every low harmonic (:func:`backend.texture.lattice.generic_signature`): the
*generic score* that compares placements of any weave. A hypothesis is then refined
(:func:`refine`): the best yarn angles within +-``refine_reach_deg`` for its spacing, and the best
spacing for those angles, twice.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ...core.rig import placement_of
from ...core.threads import ordered_map
from ..gates import GATES
from ..lattice import Lattice, Signature, generic_signature, polish, scores_at_angles, signature_score
from ..sieve import combs
from ..spectra import Spectra

SCAN_COMB_STEP = 0.003  # the scan's coarse log-spacing grid (the candidates' sieve reads 0.0002)


@dataclass(frozen=True)
class Placement:
    """A placement hypothesis: its generic score, the yarn angles (degrees) and the lattice."""

    score: float
    warp_deg: float
    weft_deg: float
    lattice: Lattice
    sieve_turn_deg: float | None = None  # the turn where the summed sieve scan peaks

    @property
    def rotation_deg(self) -> float:
        return float(round(placement_of(self.warp_deg, self.weft_deg)[0], 3))

    @property
    def skew_deg(self) -> float:
        return float(round(placement_of(self.warp_deg, self.weft_deg)[1], 3))


def local_maxima(scores: np.ndarray) -> list[int]:
    """Indices of the local maxima of a 1D scan, highest first."""
    last = len(scores) - 1
    local = [k for k in range(len(scores))
             if scores[k] >= scores[max(k - 1, 0)] and scores[k] >= scores[min(k + 1, last)]]
    return sorted(local, key=lambda k: -scores[k])


class Scan:
    """The sieves of ``spectra`` at every angle of the scan, and what is derived from them."""

    def __init__(self, spectra: Spectra, a_range: tuple[float, float], b_range: tuple[float, float],
                 workers: int = 1):
        self.spectra, self.a_range, self.b_range, self.workers = spectra, a_range, b_range, workers
        self.generic = [generic_signature()] * len(spectra.peaks)
        peaks, images, size = spectra.all_peaks, len(spectra.peaks), spectra.size
        self.angles = np.arange(-GATES.scan_deg, GATES.scan_deg + 1e-9, GATES.scan_step_deg)
        scan = ordered_map(lambda angle: combs(peaks, images, size, (a_range, b_range), angle, 0.0, SCAN_COMB_STEP),
                           self.angles, workers)
        self.spacings = [spacing for spacing, _ in scan]
        self.by_weft = np.array([scores[0] for _, scores in scan])   # axis 0 depends on the weft angle
        self.by_warp = np.array([scores[1] for _, scores in scan])   # axis 1 on the warp angle
        # each angle's sieve lattice at its multiples, best first
        self.multiples = ordered_map(lambda k: self.multiples_of(Lattice(*self.spacings[k], 0.0), self.angle(k),
                                                                 self.angle(k)), range(len(self.angles)), workers)

    def angle(self, k: int) -> float:
        return float(self.angles[k])

    @functools.cached_property
    def turn_maxima(self) -> list[int]:
        """The summed scan's best local maxima, and the unturned sample always (weak textures give
        weak evidence)."""
        found = local_maxima(self.by_weft + self.by_warp)[:GATES.turn_hypotheses]
        unturned = int(np.argmin(np.abs(self.angles)))
        return found + ([] if unturned in found else [unturned])

    @property
    def sieve_turn_deg(self) -> float:
        """The turn where the summed sieve scan peaks."""
        return self.angle(self.turn_maxima[0])

    def multiples_of(self, lattice: Lattice, warp_deg: float, weft_deg: float) -> list[Lattice]:
        """``lattice`` times every pair of ``rotation_ratios`` inside the ranges, scored by the generic
        harmonics at the yarn angles, best first."""
        ratios = GATES.rotation_ratios
        pairs = [(lattice.a * ra, lattice.b * rb) for ra in ratios for rb in ratios
                 if self.a_range[0] <= lattice.a * ra <= self.a_range[1]
                 and self.b_range[0] <= lattice.b * rb <= self.b_range[1]]
        pairs = pairs or [(lattice.a, lattice.b)]
        a, b = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
        scores = signature_score(self.spectra.maps, self.generic, a, b, self.spectra.size,
                                 *placement_of(warp_deg, weft_deg))
        order = np.argsort(-scores, kind="stable")
        return [Lattice(float(a[i]), float(b[i]), float(scores[i])) for i in order]

    def refined(self, starts: list[tuple[Lattice, float, float]], sheared: bool = False) -> list[Placement]:
        """Each (lattice, warp angle, weft angle) of ``starts`` refined (:func:`refine`), in order."""
        return ordered_map(lambda start: refine(self.spectra.maps, self.generic, *start, self.spectra.size, sheared),
                           starts, self.workers)

    def refined_at(self, ks: list[int]) -> list[Placement]:
        """Each scan angle's best ``verified_ratios`` multiples refined as turns, in order."""
        return self.refined([(lat, self.angle(k), self.angle(k)) for k in ks
                             for lat in self.multiples[k][:GATES.verified_ratios]])

    def map_score(self, q: np.ndarray, placement: Placement) -> float:
        """The generic score of ``placement`` on one peakness map."""
        return float(signature_score([q], self.generic[:1], placement.lattice.a, placement.lattice.b,
                                     self.spectra.size, *placement_of(placement.warp_deg, placement.weft_deg)))

    def beats_on_each_photo(self, placement: Placement, rivals: list[Placement], gain: float = 1.0) -> bool:
        """Whether ``placement`` explains each photo's peakness map alone ``gain`` times better than
        every one of ``rivals``: a true turn or shear shows in both photos of one fabric, a chance one
        in one photo's noise or aliased harmonics."""
        return all(self.map_score(q, placement) > gain * max(self.map_score(q, rival) for rival in rivals)
                   for q in self.spectra.maps)


def refine(maps, signatures: list[Signature], start: Lattice, warp_deg: float, weft_deg: float, size: int,
           sheared: bool) -> Placement:
    """Alternately the best angle within +-``refine_reach_deg`` for the current spacing (of each yarn
    in turn when ``sheared``, else of both together) and the polished spacing for those angles, twice."""
    rotation, skew = placement_of(warp_deg, weft_deg)
    lattice = polish(maps, signatures, start, size, span=0.01, step=0.0005, rotation_deg=rotation,
                     skew_deg=skew)
    steps = np.arange(-GATES.refine_reach_deg, GATES.refine_reach_deg + 1e-9, GATES.refine_step_deg)
    for _ in range(2):
        for moves in ((1, 0), (0, 1)) if sheared else ((1, 1),):
            trial = [(warp_deg + moves[0] * d, weft_deg + moves[1] * d) for d in steps]
            scores = scores_at_angles(maps, signatures, lattice.a, lattice.b, size,
                                      [placement_of(*angles) for angles in trial])
            warp_deg, weft_deg = trial[int(np.argmax(scores))]
        rotation, skew = placement_of(warp_deg, weft_deg)
        lattice = polish(maps, signatures, lattice, size, span=0.004, step=0.0002, rotation_deg=rotation,
                         skew_deg=skew)
    return Placement(lattice.score, warp_deg, weft_deg, lattice)
