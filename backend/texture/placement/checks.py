"""The placement checked against the candidates it gives: the unturned sample, and the sieve's turn.

1. A turned estimate against the unturned sample (:func:`versus_unturned`). Both get their
   candidates. The harmonics of the true placement's lattices are where the photos show them, so
   their phases pin the yarn vectors (:mod:`.votes`); at a placement degrees off they are
   demodulated where nothing shows. Where one placement's vectors show a turn and the other's do
   not, that one is kept. Where neither shows one, or both the same one, a turn of at least
   ``min_turn_deg`` stands (the comb scores of two placements do not compare). Otherwise the
   unturned sample stays unless the turned one's best comb lattice scores higher. The comparison
   leaves out the lattices read from single peaks: on an aliased clean render one can explain a
   signature better at a wrong turn than the true lattice does unturned.
2. A rescue (:func:`rescued`): every peak of a weave's photos is a harmonic of its lattice at the
   true placement, so there the true lattice makes nearly all of them. Where none of the placement's
   candidates makes ``low_coverage`` of the peak strength, the placement compared in 1. and the
   unsheared sample at the summed sieve scan's strongest turn are rivals, and the one whose best
   candidate makes the most is kept where that is ``rescue_gain`` more. The coverage is one-sided (a
   lattice too coarse makes every peak), hence the gain asked of a rival.
"""
from __future__ import annotations

from ...core.rig import CaptureRig
from ..candidates import Candidate, Read, comb_lattices, placed_rig, read_at, read_combs
from ..frequencies import lattice_of
from ..gates import GATES
from ..lattice import Lattice, peak_coverage
from ..spectra import Spectra
from .votes import yarn_turn

Placed = tuple[float, float]  # (rotation, skew), degrees


def versus_unturned(spectra: Spectra, rig: CaptureRig, patterns: tuple[str, ...], per_pattern: int,
                    found: Placed, workers: int) -> tuple[Placed, Read, dict[Placed, Read]]:
    """(the placement kept of ``found`` (turned, unsheared) and the unturned sample, its read, the
    other's) (module docstring, 1)."""
    unturned = (0.0, 0.0)
    at = {p: comb_lattices(spectra, placed_rig(rig, p), patterns, per_pattern, workers=workers)
          for p in (unturned, found)}
    reads = {p: read_combs(spectra, placed_rig(rig, p), at[p], per_pattern, workers) for p in (unturned, found)}
    turns = _turns_shown(reads)
    shown = [p for p in reads if turns[p] is not None]
    if len(shown) == 1:
        placement = shown[0]
    elif abs(found[0]) >= GATES.min_turn_deg and (
            not shown or abs(turns[found] - turns[unturned]) <= GATES.vote_spread_deg):
        placement = found
    else:
        placement = found if _best_score(at[found]) > _best_score(at[unturned]) else unturned
    return placement, reads[placement], {p: reads[p] for p in reads if p != placement}


def _turns_shown(reads: dict[Placed, Read]) -> dict[Placed, float | None]:
    """Per placement, the turn its candidates' yarn vectors show from the transmission alone, or,
    where neither placement's do, with ``deciding_reflection_votes`` of the reflection's help."""
    turns = {p: yarn_turn(read.readings, p, reflection_votes=None) for p, read in reads.items()}
    if all(turn is None for turn in turns.values()):
        turns = {p: yarn_turn(read.readings, p, GATES.deciding_reflection_votes) for p, read in reads.items()}
    return turns


def rescued(spectra: Spectra, rig: CaptureRig, patterns: tuple[str, ...], per_pattern: int, sieve_turn_deg: float,
            placement: Placed, read: Read, rivals: dict[Placed, Read], workers: int) -> tuple[Placed, Read]:
    """(placement, its read): the one given, or a rival that makes more of the photos' peaks (module
    docstring, 2)."""
    covered = best_coverage(spectra, rig, placement, read.candidates)
    if covered >= GATES.low_coverage:
        return placement, read
    rivals = dict(rivals)
    if not any(skew == 0.0 and abs(sieve_turn_deg - rotation) < GATES.min_turn_deg
               for rotation, skew in [placement, *rivals]):
        rivals[sieve_turn_deg, 0.0] = read_at(spectra, rig, (sieve_turn_deg, 0.0), patterns, per_pattern,
                                              workers=workers)
    coverage = {rival: best_coverage(spectra, rig, rival, r.candidates) for rival, r in rivals.items()}
    best = max(coverage, key=coverage.get, default=None)
    if best is not None and coverage[best] > covered + GATES.rescue_gain:
        return best, rivals[best]
    return placement, read


def best_coverage(spectra: Spectra, rig: CaptureRig, placement: Placed, found: list[Candidate]) -> float:
    """The most of the photos' peak strength that one of ``found``'s lattices makes at ``placement``."""
    return max((peak_coverage(spectra, *lattice_of(c.tiles, rig), *placement) for c in found), default=0.0)


def _best_score(found: dict[str, list[Lattice]]) -> float:
    return max((lat.score for lats in found.values() for lat in lats), default=-float("inf"))
