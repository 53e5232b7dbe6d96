"""Every threshold of the sample's placement and the lattice reading, declared once.

Each gate is a field of :class:`Gates`: its value and one line on what it guards. The code reads
them from :data:`GATES`; ``python -m devtools bench placement`` prints this table with its figures.
The order in which the decisions use them is :func:`backend.texture.placement.place`'s.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields


def gate(value, guards: str):
    return field(default=value, metadata={"guards": guards})


def _ratios(largest: int) -> tuple[float, ...]:
    return tuple(sorted({p / q for p in range(1, largest + 1) for q in range(1, largest + 1)}))


@dataclass(frozen=True)
class Gates:
    # -- the harmonic sieve (texture/sieve.py) --
    tooth_cost: float = gate(1.0, "peak strength a comb tooth must explain: else a finer comb would explain any peaks")
    comb_reach: float = gate(2.5, "comb teeth up to this many times the image size: a dense weave's aliased harmonics")
    informative_cycles: float = gate(3.0, "peaks this close to DC (cycles per image) are lighting, not the weave")
    # -- how much of the photos' peaks a lattice makes (texture/lattice.py peak_coverage) --
    coverage_peaks: int = gate(8, "the strongest peaks of each photo that the coverage weighs")
    coverage_tolerance: tuple[float, float] = gate((3.0, 0.02), "a peak is on a harmonic within 3 cycles + 2 % of "
                                                               "its frequency")
    coverage_reach: float = gate(1.6, "harmonics up to this many times Nyquist fold into the image")
    low_coverage: float = gate(0.7, "lattices that make less of the peak strength have not explained the photos")
    # -- the placement's hypotheses (texture/placement/) --
    scan_deg: float = gate(6.0, "turns the sieves scan, +-: a sample turned further is not looked for")
    scan_step_deg: float = gate(0.25, "the scan's step: a turn is read to this, then refined")
    turn_hypotheses: int = gate(6, "the best local maxima of a scan (summed sieves, maps) refined as turns")
    shear_hypotheses: int = gate(8, "each axis's best sieve maxima paired as the two yarn angles of a shear")
    refined_hypotheses: int = gate(8, "paired angles and peak-pair readings refined, best scored first")
    max_skew_deg: float = gate(5.0, "yarn angles further apart than this are not one cloth pulled out of square")
    verified_ratios: int = gate(2, "a sieve's spacings times each ratio pair: the best this many refined")
    rotation_ratios: tuple[float, ...] = gate(_ratios(5), "p / q, p, q <= 5: a sieve may lock onto a yarn's "
                                                           "frequency, an aliased harmonic, or a multiple")
    refine_reach_deg: float = gate(0.3, "a refinement moves a yarn angle by up to this, in refine_step_deg steps")
    refine_step_deg: float = gate(0.02, "the refinement's angle step")
    peak_pair_peaks: int = gate(6, "each photo's strongest peaks read in pairs as two low harmonics of one lattice")
    peak_pair_order: int = gate(2, "the harmonics (m, n), |m|, n <= this, a strong peak is taken for")
    # -- choosing among them (texture/placement/select.py) --
    tie_ratio: float = gate(1.01, "turns scoring within this ratio of the best are not told apart: the smallest wins")
    rival_turn_gain: float = gate(1.1, "how many times better a rival turn must explain the maps than the summed "
                                       "scan's best")
    sieve_agreement_deg: float = gate(0.3, "a turn this close to the summed sieve scan's strongest agrees with it")
    shear_gain: float = gate(1.15, "how many times better, on each photo, a shear must explain it than a turn")
    # -- the lattice candidates (texture/candidates.py) --
    ratios: tuple[float, ...] = gate((1 / 3, 1 / 2, 2 / 3, 1.0, 3 / 2, 2.0, 3.0),
                                     "a comb pins a pattern's lattice up to these sub- and super-multiples")
    anchor_gain: float = gate(1.25, "a lattice read from one peak joins the combs' where it scores this much better")
    anchor_peaks: int = gate(4, "each photo's strongest peaks read as single oblique harmonics")
    anchor_harmonics: int = gate(4, "the signature's strongest oblique harmonics a single peak is taken for")
    signature_density: float = gate(20.0, "tiles across the signature renders: every harmonic below Nyquist")
    coarsest_pixels_per_yarn: float = gate(10.0, "film pixels per yarn of the coarsest weave the search proposes")
    # -- the turn the candidates' yarn vectors show (texture/placement/votes.py) --
    vote_skew_deg: float = gate(0.25, "a reading votes only where its skew is the placement's within this")
    vote_spread_deg: float = gate(0.3, "votes move the turn only where they agree within this")
    vote_reach_deg: float = gate(1.5, "and only by up to this")
    deciding_reflection_votes: int = gate(2, "readings made with the reflection's help that must agree to decide")
    # -- the placement checked against the unturned sample and the sieve's turn (texture/placement/checks.py) --
    min_turn_deg: float = gate(0.5, "a turn this close to an unsheared placement is the same placement")
    rescue_gain: float = gate(0.3, "a placement whose lattices miss the peaks gives way to one making this much more")


GATES = Gates()


def table(gates: Gates = GATES) -> list[tuple[str, object, str]]:
    """(name, value, what it guards) of every gate, in declaration order."""
    return [(f.name, getattr(gates, f.name), f.metadata["guards"]) for f in fields(gates)]
