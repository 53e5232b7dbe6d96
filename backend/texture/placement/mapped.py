"""Turned placements where the maps, rather than the sieves, peak.

Uneven yarn spacing smears the peaks the sieves sum, so the summed score's maxima can all miss the
turn while the 2D peakness maps still show it: each scan angle's sieve lattice at its best multiple,
scored by the generic harmonics (:attr:`.scan.Scan.multiples`), is a scan of its own; its best
local maxima not already among the summed scan's are refined as turns.
"""
from __future__ import annotations

import numpy as np

from ..gates import GATES
from .scan import Placement, Scan, local_maxima


def mapped(scan: Scan) -> list[Placement]:
    """The refined placements at the map scan's maxima that the summed scan's maxima miss."""
    by_map = np.array([lattices[0].score for lattices in scan.multiples])
    ks = [k for k in local_maxima(by_map)[:GATES.turn_hypotheses] if k not in scan.turn_maxima]
    return scan.refined_at(ks)
