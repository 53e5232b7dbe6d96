"""Turned placements where the summed sieve scan peaks.

The sum of both axes' sieve scores over the scan peaks where both yarn directions line the photos'
peaks up (:attr:`.scan.Scan.turn_maxima`: its best local maxima, and the unturned sample always);
each such angle's best multiples (:meth:`.scan.Scan.refined_at`) are refined as turns. The best of
them is the incumbent the other generators' rivals are measured against (:mod:`.select`).
"""
from __future__ import annotations

from .scan import Placement, Scan


def turned(scan: Scan) -> list[Placement]:
    """The refined placements at the summed scan's maxima, in the maxima's order."""
    return scan.refined_at(scan.turn_maxima)
