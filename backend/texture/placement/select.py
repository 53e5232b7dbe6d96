"""Choosing the placement among the generators' hypotheses, in an order that cannot matter.

The incumbent is the best refined turn at the summed sieve scan's maxima (:mod:`.turned`); scores
within ``tie_ratio`` of the best do not tell turns apart, and of those the smallest turn is taken
(a sample is laid in the holder roughly straight). Each rival, the best turn at the middle of
paired angles (:mod:`.paired`), at the map scan's maxima (:mod:`.mapped`) and from peak pairs
(:mod:`.peaked`), is measured against the incumbent alone. The generic harmonics score any lattice,
and more hypotheses give them more chances to prefer a wrong one, so a rival qualifies only where it
explains the maps ``rival_turn_gain`` times better; the map and peak-pair rivals must also explain
each photo alone better (:meth:`.scan.Scan.beats_on_each_photo`: a true turn shows in both photos of
one fabric, a chance one in one photo's noise or aliased harmonics). A rival whose turn agrees with
the summed scan's strongest (within ``sieve_agreement_deg``), where the incumbent does not, needs no
gain: two readings of the peaks agree against the generic harmonics alone. Of the rivals that
qualify, the highest *standing* wins: the score, times ``rival_turn_gain`` where the turn agrees
with the sieves.

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


def incumbent(turned: list[Placement]) -> Placement:
    """The best-scoring turn; among those within ``tie_ratio`` of it, the smallest."""
    top = max(p.score for p in turned)
    return min((p for p in turned if p.score * GATES.tie_ratio >= top), key=lambda p: abs(p.rotation_deg))


def standing(placement: Placement, sieve_turn_deg: float) -> float:
    """The score, times ``rival_turn_gain`` where the turn agrees with the sieves (module docstring)."""
    return placement.score * (GATES.rival_turn_gain if _agrees(placement, sieve_turn_deg) else 1.0)


def rival_gain(rival: Placement, current: Placement, sieve_turn_deg: float) -> float:
    """How many times better than ``current`` ``rival`` must explain the maps (module docstring)."""
    agreeing = _agrees(rival, sieve_turn_deg) and not _agrees(current, sieve_turn_deg)
    return 1.0 if agreeing else GATES.rival_turn_gain


def select_turn(scan: Scan, turned: list[Placement], paired: list[Placement], mapped: list[Placement],
                peaked: list[Placement]) -> Placement:
    """The turn chosen among the generators' refined hypotheses (module docstring)."""
    held = incumbent(turned)

    def qualifies(rival: Placement | None, each_photo: bool) -> bool:
        return (rival is not None and rival.score > rival_gain(rival, held, scan.sieve_turn_deg) * held.score
                and (not each_photo or scan.beats_on_each_photo(rival, [held])))

    rivals = [(_best(paired), False), (_best(mapped), True), (_best(peaked), True)]
    qualified = [rival for rival, each_photo in rivals if qualifies(rival, each_photo)]
    return max(qualified, key=lambda p: standing(p, scan.sieve_turn_deg), default=held)


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
