"""The turn the candidates' yarn vectors show.

Each candidate's mean spacing solves its yarn vectors u and v from its harmonics' measured
frequencies over the whole photo (:func:`backend.texture.spacing.mean_lattice`), so their
directions read the turn where the centre-weighted spectrum's peaks, which placed the sample, are
smeared by uneven spacing. A candidate of the wrong pattern demodulates where nothing or a
neighbour shows, and its vectors come out sheared by degrees, while those of the true pattern (and
of its sub- and super-lattices) share the placement's skew: only readings whose skew is the
placement's within ``vote_skew_deg`` and whose turn lies within ``vote_reach_deg`` of it vote. The
transmission's readings vote first (the reflection's harmonics ride on glints that drift across the
photo); those made with the reflection's help only where none of the transmission's does. The
votes' median is the turn where they agree within ``vote_spread_deg``; the skew stays the
placement's.
"""
from __future__ import annotations

import statistics

from ..gates import GATES
from ..spacing import MeanSpacing


def yarn_turn(readings: list[MeanSpacing], placement: tuple[float, float],
              reflection_votes: int | None = 1) -> float | None:
    """The rotation the readings' yarn vectors show at ``placement`` (rotation, skew), or None where
    they show none. ``reflection_votes``: how many readings made with the reflection's help must
    agree to vote where the transmission's do not (None: they never vote)."""
    rotation, skew = placement
    agreeing = [r for r in readings if r.placement is not None
                and abs(r.placement[1] - skew) <= GATES.vote_skew_deg
                and abs(r.placement[0] - rotation) <= GATES.vote_reach_deg]
    votes = [r.placement[0] for r in agreeing if r.from_transmission]
    if not votes and reflection_votes is not None:
        votes = [r.placement[0] for r in agreeing]
        votes = votes if len(votes) >= reflection_votes else []
    if not votes or max(votes) - min(votes) > GATES.vote_spread_deg:
        return None
    return float(round(statistics.median(votes), 3)) + 0.0  # never -0.0
