"""How the sample lies in the holder (its turn and skew), and the lattice candidates there.

The photos' spectra show an axis-aligned tile lattice once the sample's placement is undone. The
order of the decisions (every threshold is a named gate of :mod:`backend.texture.gates`):

    0. a given rotation is used as it is (with the rig's skew)
    1. the photos that show the weave                                   Spectra.of_the_weave
    2. the harmonic sieves at every angle of the scan                   .scan.Scan
    3. hypotheses, each refined and scored by the generic harmonics:
         turns where the summed sieves peak (the incumbent)            .turned
         turns at the middle of each axis's paired angles              .paired
         turns where the maps peak                                      .mapped
         turns read from pairs of strong peaks                          .peaked
         shears from each axis's paired angles                          .paired
    4. the turn: a rival beats the incumbent by rival_turn_gain, or
       by any margin where two readings agree on it                     .select.select_turn
    5. the shear, kept only where each photo confirms it                .select.shear_confirmed
    6. a turned estimate against the unturned sample: the candidates'
       yarn vectors, else the turn stands, else the comb scores         .checks.versus_unturned
    7. where no candidate makes the photos' peaks: the rival placement
       whose candidates make the most of them                           .checks.rescued
    8. the turn the candidates' yarn vectors agree on                   .votes.yarn_turn

Scans, refinements and readings independent of each other run on up to ``workers`` threads; the
result does not depend on their number.
"""
from __future__ import annotations

from dataclasses import replace

from ...core.rig import CaptureRig
from ..candidates import Candidate, read_at, search_range
from ..spectra import Spectra
from . import checks
from .mapped import mapped
from .paired import angle_pairs, paired, sheared
from .peaked import peaked
from .scan import Placement, Scan
from .select import select_shear, select_turn, shear_confirmed
from .turned import turned
from .votes import yarn_turn


def estimate(spectra: Spectra, rig: CaptureRig, patterns: tuple[str, ...], workers: int = 1) -> Placement:
    """Steps 1-5: the placement the spectra show, with its lattice and the summed scan's strongest
    turn (``sieve_turn_deg``)."""
    span = search_range(rig, patterns)
    scan = Scan(spectra.of_the_weave(), span, span, workers)
    pairs = angle_pairs(scan)
    turn = select_turn(scan, turned(scan), paired(scan, pairs), mapped(scan), peaked(scan))
    shear = select_shear(sheared(scan, pairs))
    chosen = shear if shear is not None and shear_confirmed(scan, shear, turn) else turn
    return replace(chosen, sieve_turn_deg=scan.sieve_turn_deg)


def place(spectra: Spectra, rig: CaptureRig, patterns: tuple[str, ...], rotation: float | None,
          per_pattern: int = 1, workers: int = 1) -> tuple[tuple[float, float], list[Candidate]]:
    """((the sample's rotation, its skew), the candidates there), best first within each pattern."""
    if rotation is not None:
        placement = (rotation, rig.sample_skew_deg)
        return placement, read_at(spectra, rig, placement, patterns, per_pattern, workers=workers).candidates
    found = estimate(spectra, rig, patterns, workers)
    placement = (found.rotation_deg, found.skew_deg)
    if placement == (0.0, 0.0) or found.skew_deg != 0.0:  # unturned, or sheared: kept as it is
        placement = (0.0, 0.0) if placement == (0.0, 0.0) else placement  # never a -0.0 turn
        also = (found.lattice,) if found.skew_deg != 0.0 else ()  # the sieve can miss a shear's lattice
        read, rivals = read_at(spectra, rig, placement, patterns, per_pattern, also, workers), {}
    else:
        placement, read, rivals = checks.versus_unturned(spectra, rig, patterns, per_pattern, placement, workers)
    placement, read = checks.rescued(spectra, rig, patterns, per_pattern, found.sieve_turn_deg, placement, read,
                                     rivals, workers)
    turn = yarn_turn(read.readings, placement)
    return (placement[0] if turn is None else turn, placement[1]), read.candidates
