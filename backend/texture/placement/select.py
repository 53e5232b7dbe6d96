"""Choosing the placement among the generators' hypotheses: one rule, the same whatever their order.

Every refined turn competes on its *standing*: its generic score, times ``rival_turn_gain`` where
its turn agrees with the summed sieve scan's strongest (within ``sieve_agreement_deg``):

    standing(h) = score(h) * (rival_turn_gain if |turn(h) - sieve turn| <= sieve_agreement_deg else 1)

Two readings of the peaks agreeing (their positions or the maps, and the sieves over all of them)
outweigh the generic harmonics alone, which score any lattice: a turn the sieves do not back must
explain the maps ``rival_turn_gain`` times better than one they do. The turns from the map scan
(:mod:`.mapped`) and from peak pairs (:mod:`.peaked`) must also explain each photo alone better than
the best summed-scan turn (:meth:`.scan.Scan.beats_on_each_photo`): a true turn shows in both
photos of one fabric, a chance one in one photo's noise or aliased harmonics. The highest standing
wins; a tie goes to the earlier generator (summed scan, paired angles, maps, peak pairs).

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


def standing(placement: Placement, sieve_turn_deg: float) -> float:
    """The score a turn competes on (module docstring)."""
    agrees = abs(placement.rotation_deg - sieve_turn_deg) <= GATES.sieve_agreement_deg
    return placement.score * (GATES.rival_turn_gain if agrees else 1.0)


def select_turn(scan: Scan, turned: list[Placement], paired: list[Placement], mapped: list[Placement],
                peaked: list[Placement]) -> Placement:
    """The turn chosen among the generators' refined hypotheses (module docstring)."""
    def rank(placements: list[Placement]) -> Placement | None:
        return max(placements, key=lambda p: standing(p, scan.sieve_turn_deg), default=None)

    summed = rank(turned)
    contenders = [summed, rank(paired)] + [rival for rival in (rank(mapped), rank(peaked))
                                           if rival is not None and scan.beats_on_each_photo(rival, [summed])]
    return rank([c for c in contenders if c is not None])


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
