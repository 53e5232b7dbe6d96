"""Candidate weaves and yarn densities for a placed sample, read from the spectrum (no optimisation).

For a sample placed as a rig says (rotation, skew), per pattern of the fit:

1. the harmonic sieve (:func:`backend.texture.sieve.estimates`) finds the lattice that explains the
   photos' peaks (at their size and shrunk), up to small sub- and super-multiples;
2. those lattices times the ``ratios`` per axis, within the pattern's tile range, each polished and
   scored by the pattern's signature (:mod:`.signatures`): the *comb lattices*;
3. joined by lattices read from single peaks (:func:`anchored`): a dense weave behind a phone's blur
   can leave one low oblique harmonic standing, which no comb on one axis explains, but whose
   position pins the lattice once the harmonic is named. One joins where it scores ``anchor_gain``
   times the best comb lattice; where no comb lattice makes ``low_coverage`` of the photos' peak
   strength (:func:`backend.texture.lattice.peak_coverage`), one that scores higher and makes more
   of it joins without the gain;
4. each at the mean spacing over the whole photo, read from the phase of its harmonics
   (:func:`backend.texture.spacing.mean_lattice`), not the centre's that the windowed spectrum reads.

Scores compare within a pattern only: the fit's trial fits choose the weave (:mod:`backend.fit.search`).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core import priors
from ..core.rig import CaptureRig
from ..core.threads import ordered_map
from ..core.weave import PRESETS
from . import spacing
from .frequencies import fabric_frequencies
from .gates import GATES
from .lattice import Lattice, Signature, peak_coverage, polish, signature_score
from .sieve import estimates
from .signatures import signatures
from .spectra import Spectra


@dataclass(frozen=True)
class Candidate:
    pattern: str
    tiles: tuple[float, float]
    score: float


@dataclass(frozen=True)
class Read:
    """A placement's candidates, best first per pattern, with their mean-spacing readings (same order)."""

    candidates: list[Candidate]
    readings: list[spacing.MeanSpacing]


def tile_range(pattern: str, rig: CaptureRig) -> tuple[tuple[float, float], tuple[float, float]]:
    """(tu range, tv range) of the tiles proposed for ``pattern``: what its dataset prior can produce
    (:func:`backend.core.priors.tile_range`), and down to the density at which the yarns get
    ``coarsest_pixels_per_yarn`` film pixels. The prior's densities are those of the paper's 512-px
    training renders (mostly aliased); a phone photo that shows the weave has 2-4 px per yarn on its
    denser axis, and twice that on the other axis of a weave whose pitches differ."""
    (u_lo, u_hi), (v_lo, v_hi) = priors.tile_range(pattern)
    weave = PRESETS.get(pattern)
    if weave is None:
        return (u_lo, u_hi), (v_lo, v_hi)
    in_view = rig.view_size / rig.plane_size
    coarsest = rig.film_size / GATES.coarsest_pixels_per_yarn / in_view  # yarns across the whole plane
    return (min(u_lo, coarsest / weave.cols), u_hi), (min(v_lo, coarsest / weave.rows), v_hi)


def search_range(rig: CaptureRig, patterns: tuple[str, ...]) -> tuple[float, float]:
    """Tiles across the image that the search proposes for any of ``patterns``."""
    scale = rig.view_size / rig.plane_size
    ranges = [tile_range(p, rig) for p in patterns]
    return (min(min(r[0][0], r[1][0]) for r in ranges) * scale, max(max(r[0][1], r[1][1]) for r in ranges) * scale)


def _image_ranges(pattern: str, rig: CaptureRig) -> tuple[tuple[float, float], tuple[float, float]]:
    """The pattern's :func:`tile_range` in tiles across and down the image."""
    scale = rig.view_size / rig.plane_size
    (tu_lo, tu_hi), (tv_lo, tv_hi) = tile_range(pattern, rig)
    return (tu_lo * scale, tu_hi * scale), (tv_lo * scale, tv_hi * scale)


def placed_rig(rig: CaptureRig, placement: tuple[float, float]) -> CaptureRig:
    return replace(rig, sample_rotation_deg=placement[0], sample_skew_deg=placement[1])


def comb_lattices(spectra: Spectra, rig: CaptureRig, patterns: tuple[str, ...], per_pattern: int,
                  also: tuple[Lattice, ...] = (), workers: int = 1) -> dict[str, list[Lattice]]:
    """Per pattern, its ``per_pattern`` best comb lattices (module docstring, 1-2) for a sample placed
    as ``rig`` says, from the sieve's estimates and ``also``."""
    lo, hi = search_range(rig, patterns)
    rotation, skew = rig.sample_rotation_deg, rig.sample_skew_deg
    combs = estimates(spectra, (lo, hi), (lo, hi), rotation_deg=rotation, skew_deg=skew, workers=workers) + list(also)
    sigs = signatures(rig, patterns)

    def best(pattern: str) -> list[Lattice]:
        starts = [(comb.a * ra, comb.b * rb) for comb in combs for ra in GATES.ratios for rb in GATES.ratios]
        found = _polished(spectra, sigs[pattern], starts, *_image_ranges(pattern, rig), rotation, skew)
        return sorted(found, key=lambda lat: -lat.score)[:per_pattern]

    return dict(zip(patterns, ordered_map(best, patterns, workers)))


def _polished(spectra: Spectra, sigs: list[Signature], starts, a_range, b_range, rotation_deg: float,
              skew_deg: float) -> list[Lattice]:
    """Each distinct start (a, b) inside the ranges, polished."""
    seen, out = set(), []
    for a, b in starts:
        if not (a_range[0] <= a <= a_range[1] and b_range[0] <= b <= b_range[1]):
            continue
        key = (round(a, 1), round(b, 1))
        if key in seen:
            continue
        seen.add(key)
        out.append(polish(spectra.maps, sigs, Lattice(a, b, 0.0), spectra.size, span=0.004, step=0.0002,
                          rotation_deg=rotation_deg, skew_deg=skew_deg))
    return out


def anchored(spectra: Spectra, sigs: list[Signature], a_range, b_range, rotation_deg: float, skew_deg: float,
             keep: int = 6) -> list[Lattice]:
    """Lattices read from single peaks: each of a photo's ``anchor_peaks`` strongest peaks p (or -p)
    taken as one of its signature's ``anchor_harmonics`` strongest oblique harmonics (m, n), both
    non-zero, and turned back into fabric frequencies (f1, f2): (a, b) = (f1 / m, f2 / n); the
    ``keep`` best by signature score. The peak is taken as it is, not as an alias: what survives
    the optics' blur lies below Nyquist."""
    hyp_a, hyp_b = [], []
    for image_peaks, sig in zip(spectra.peaks, sigs):
        oblique = [(m, n) for m, n in zip(sig.m, sig.n) if m != 0 and n != 0][:GATES.anchor_harmonics]
        for p in image_peaks[:GATES.anchor_peaks]:
            for sign in (1.0, -1.0):
                f1, f2 = fabric_frequencies(np.array([sign * p.fx]), np.array([sign * p.fy]), rotation_deg,
                                            skew_deg)
                for m, n in oblique:
                    hyp_a.append(f1 / m)
                    hyp_b.append(f2 / n)
    if not hyp_a:
        return []
    a, b = np.concatenate(hyp_a), np.concatenate(hyp_b)
    ok = (a >= a_range[0]) & (a <= a_range[1]) & (b >= b_range[0]) & (b <= b_range[1])
    a, b = a[ok], b[ok]
    if a.size == 0:
        return []
    scores = signature_score(spectra.maps, sigs, a, b, spectra.size, rotation_deg, skew_deg)
    best = np.argsort(-scores, kind="stable")[:keep]
    return [Lattice(float(a[i]), float(b[i]), float(scores[i])) for i in best]


def with_anchored(spectra: Spectra, found: list[Lattice], sigs: list[Signature], a_range, b_range,
                  top: int, rotation_deg: float, skew_deg: float) -> list[Lattice]:
    """``found`` (a pattern's comb lattices, best first) joined by the lattices read from single
    peaks that pass the module docstring's test (3.), best ``top`` first."""
    best = max((lat.score for lat in found), default=0.0)
    read = anchored(spectra, sigs, a_range, b_range, rotation_deg, skew_deg)
    polished = _polished(spectra, sigs, [(lat.a, lat.b) for lat in read], a_range, b_range, rotation_deg, skew_deg)
    joined = [lat for lat in polished if lat.score > GATES.anchor_gain * best]
    rest = [lat for lat in polished if best < lat.score <= GATES.anchor_gain * best]
    if rest:
        covered = max((peak_coverage(spectra, lat.a, lat.b, rotation_deg, skew_deg) for lat in found), default=0.0)
        if covered < GATES.low_coverage:
            joined += [lat for lat in rest if peak_coverage(spectra, lat.a, lat.b, rotation_deg, skew_deg) > covered]
    return sorted(found + joined, key=lambda lat: -lat.score)[:top]


def read_combs(spectra: Spectra, rig: CaptureRig, combs: dict[str, list[Lattice]], per_pattern: int,
               workers: int = 1) -> Read:
    """The comb lattices per pattern joined by those read from single peaks, as candidates, each at
    the mean spacing over the whole photo (module docstring, 3-4)."""
    sigs = signatures(rig, tuple(combs))
    rotation, skew = rig.sample_rotation_deg, rig.sample_skew_deg
    reflection, transmission = spectra.highpassed

    def read(pattern: str) -> list[spacing.MeanSpacing]:
        found = with_anchored(spectra, combs[pattern], sigs[pattern], *_image_ranges(pattern, rig), per_pattern,
                              rotation, skew)
        return [spacing.mean_lattice(transmission, reflection, start, tuple(sigs[pattern]), rotation, skew)
                for start in found]

    out, readings = [], []
    for pattern, reads in zip(combs, ordered_map(read, tuple(combs), workers)):
        for reading in reads:
            out.append(Candidate(pattern, reading.lattice.tiles(rig.view_size, rig.plane_size),
                                 reading.lattice.score))
            readings.append(reading)
    return Read(out, readings)


def read_at(spectra: Spectra, rig: CaptureRig, placement: tuple[float, float], patterns: tuple[str, ...],
            per_pattern: int, also: tuple[Lattice, ...] = (), workers: int = 1) -> Read:
    """The candidates and their readings for the sample at ``placement`` (rotation, skew)."""
    at = placed_rig(rig, placement)
    return read_combs(spectra, at, comb_lattices(spectra, at, patterns, per_pattern, also, workers), per_pattern,
                      workers)


def propose(spectra: Spectra, rig: CaptureRig, patterns: tuple[str, ...], per_pattern: int = 2,
            workers: int = 1) -> list[Candidate]:
    """(pattern, tiles) candidates for a sample placed as the rig says, best lattice score first
    within each pattern."""
    return read_at(spectra, rig, (rig.sample_rotation_deg, rig.sample_skew_deg), patterns, per_pattern,
                   workers=workers).candidates
