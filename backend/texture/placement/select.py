"""Choosing the placement among the generators' hypotheses.

The incumbent is the best refined turn at the summed sieve scan's maxima (:mod:`.turned`). Rivals:
the best turn at the middle of paired angles (:mod:`.paired`), at the map scan's maxima
(:mod:`.mapped`) and from peak pairs (:mod:`.peaked`). The generic harmonics score any lattice, and
more hypotheses give them more chances to prefer a wrong one, so a rival replaces the turn so far
only where it explains the maps ``rival_turn_gain`` times better; the map and peak-pair rivals must
also explain each photo alone better (:meth:`.scan.Scan.beats_on_each_photo`). A rival whose turn
agrees with the summed scan's strongest (within ``sieve_agreement_deg``), where the turn so far does
not, needs no gain: two readings of the peaks agree against the generic harmonics alone.

A shear (:mod:`.paired`) has one more degree of freedom, so it explains the noise or aliased
harmonics of unsheared samples better too; it is kept only where, on each photo alone, it explains
the map ``shear_gain`` times better than the chosen turn and than its own lattice at any single
angle (:func:`shear_confirmed`).
"""
from __future__ import annotations

from ...core.rig import placement_of
from ..gates import GATES
from .scan import Placement, Scan, refine


def _best(placements: list[Placement]) -> Placement | None:
    return max(placements, key=lambda p: p.score, default=None)


def _agrees(placement: Placement, sieve_turn_deg: float) -> bool:
    return abs(placement.rotation_deg - sieve_turn_deg) <= GATES.sieve_agreement_deg


def rival_gain(rival: Placement, current: Placement, sieve_turn_deg: float) -> float:
    """How many times better than ``current`` ``rival`` must explain the maps (module docstring)."""
    return 1.0 if _agrees(rival, sieve_turn_deg) and not _agrees(current, sieve_turn_deg) else GATES.rival_turn_gain


def select_turn(scan: Scan, turned: list[Placement], paired: list[Placement], mapped: list[Placement],
                peaked: list[Placement]) -> Placement:
    """The turn chosen among the generators' refined hypotheses (module docstring)."""
    best = _best(turned)
    best_paired = _best(paired)
    if best_paired is not None and best_paired.score > GATES.rival_turn_gain * best.score:
        best = best_paired
    for rival in (_best(mapped), _best(peaked)):  # in turn, each against the turn so far
        if (rival is not None and rival.score > rival_gain(rival, best, scan.sieve_turn_deg) * best.score
                and scan.beats_on_each_photo(rival, [best])):
            best = rival
    return best


def select_shear(sheared: list[Placement]) -> Placement | None:
    return _best(sheared)


def shear_confirmed(scan: Scan, sheared: Placement, turned: Placement) -> bool:
    """Whether the sheared placement explains *each* photo's map ``shear_gain`` times better than the
    chosen turn does, and than its own lattice does at the best single angle (each yarn's angle and
    their middle, refined). The cheap comparison with the turn goes first: most shears fail it."""
    if not scan.beats_on_each_photo(sheared, [turned], GATES.shear_gain):
        return False
    angles = (sheared.warp_deg, sheared.weft_deg, placement_of(sheared.warp_deg, sheared.weft_deg)[0])
    at_one_angle = [refine(scan.spectra.maps, scan.generic, sheared.lattice, angle, angle, scan.spectra.size, False)
                    for angle in angles]
    return scan.beats_on_each_photo(sheared, at_one_angle, GATES.shear_gain)
