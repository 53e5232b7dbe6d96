"""Placements from pairs of angles, one per yarn direction: sheared, and turned at their middle.

Each axis's sieve score depends on one yarn angle (:mod:`.scan`), so the ``shear_hypotheses`` best
local maxima of the warps' scan and of the wefts' pair up as the two yarn angles of a cloth pulled
out of square (within ``max_skew_deg``). Each pair's lattice (the wefts' angle gives axis 0's
spacing, the warps' angle axis 1's) is verified at its multiples against the maps; the
``refined_hypotheses`` best are refined as shears (:func:`sheared`) and, at their middle angle, as
turns (:func:`paired`): each axis's own angle can place the lattice where the summed scan misses it.
"""
from __future__ import annotations

from ...core.rig import placement_of
from ..gates import GATES
from ..lattice import Lattice
from .scan import Placement, Scan, local_maxima


def angle_pairs(scan: Scan) -> list[tuple[float, float, Lattice]]:
    """(warp angle, weft angle, lattice) of the verified pairs, best generic score first."""
    warps = local_maxima(scan.by_warp)[:GATES.shear_hypotheses]
    wefts = local_maxima(scan.by_weft)[:GATES.shear_hypotheses]
    verified = []
    for i, j in sorted((i, j) for i in warps for j in wefts
                       if i != j and abs(scan.angles[i] - scan.angles[j]) <= GATES.max_skew_deg):
        warp, weft = scan.angle(i), scan.angle(j)
        start = Lattice(scan.spacings[j][0], scan.spacings[i][1], 0.0)
        verified += [(lat.score, warp, weft, lat) for lat in
                     scan.multiples_of(start, warp, weft)[:GATES.verified_ratios]]
    verified.sort(key=lambda v: -v[0])
    return [(warp, weft, lat) for _, warp, weft, lat in verified[:GATES.refined_hypotheses]]


def paired(scan: Scan, pairs: list[tuple[float, float, Lattice]]) -> list[Placement]:
    """Each pair's lattice refined as a turn at the pair's middle angle."""
    return scan.refined([(lat, middle, middle) for warp, weft, lat in pairs
                         for middle in (placement_of(warp, weft)[0],)])


def sheared(scan: Scan, pairs: list[tuple[float, float, Lattice]]) -> list[Placement]:
    """Each pair refined as a shear, each yarn angle on its own."""
    return scan.refined([(lat, warp, weft) for warp, weft, lat in pairs], sheared=True)
