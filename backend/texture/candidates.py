"""Candidate weaves and yarn densities for a photo pair, read from the spectrum (no optimisation).

1. :func:`backend.texture.lattice.estimates` finds the tile lattice that explains the spectral peaks of
   both photos (at their size and shrunk), up to small sub- and super-multiples;
2. for each preset, :func:`backend.texture.lattice.candidates` scales those lattices by small ratios,
   polishes each hypothesis and scores it with the preset's *signature* (its harmonic structure,
   measured once per rig from a render of the preset's typical parameters at a low density);
3. :func:`placed` does this for the sample's rotation read from the spectra and for the unturned
   sample, and keeps the placement whose best candidate scores higher.

The fit then gives the best few (pattern, tiles) candidates a short optimisation each and keeps the
one that explains the photos best (:mod:`backend.fit.search`).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import torch

from ..core import priors
from ..core.rig import CaptureRig
from ..core.weave import PRESETS
from ..model.render import Renderer
from . import lattice

SIGNATURE_DENSITY = 20.0  # tiles across the image for the signature renders: every harmonic below Nyquist
COARSEST_PIXELS_PER_YARN = 10.0  # film pixels per yarn of the coarsest weave the search proposes


@dataclass(frozen=True)
class Candidate:
    pattern: str
    tiles: tuple[float, float]
    score: float


@lru_cache(maxsize=4)
def signatures(rig: CaptureRig) -> dict[str, list[lattice.Signature]]:
    """Per preset, the (reflection, transmission) harmonic signatures of its typical parameters."""
    renderer = Renderer(rig, size=512, spp=4, cache_samples=0)
    tiles = SIGNATURE_DENSITY * rig.plane_size / rig.view_size
    out = {}
    for pattern in priors.PATTERNS:
        params = priors.typical(pattern).replace(tiles=(tiles, tiles))
        with torch.no_grad():
            pair = renderer.render(params)
        out[pattern] = [lattice.signature(img.numpy(), SIGNATURE_DENSITY, SIGNATURE_DENSITY)
                        for img in (pair.reflection, pair.transmission)]
    return out


def tile_range(pattern: str, rig: CaptureRig) -> tuple[tuple[float, float], tuple[float, float]]:
    """(tu range, tv range) of the tiles the search proposes for ``pattern``: what its dataset prior
    can produce (:func:`backend.core.priors.tile_range`), and down to the density at which the yarns
    get COARSEST_PIXELS_PER_YARN film pixels. The prior's densities are those of the paper's 512-px
    training renders (0.7-2.7 px per yarn, mostly aliased); a phone photo that shows the weave has
    2-4 px per yarn on its denser axis (the dev real pairs), and twice that on the other axis of a
    weave whose pitches differ, which is below the twill and satin priors."""
    (u_lo, u_hi), (v_lo, v_hi) = priors.tile_range(pattern)
    weave = PRESETS.get(pattern)
    if weave is None:
        return (u_lo, u_hi), (v_lo, v_hi)
    in_view = rig.view_size / rig.plane_size
    coarsest = rig.film_size / COARSEST_PIXELS_PER_YARN / in_view  # yarns across the whole plane
    return (min(u_lo, coarsest / weave.cols), u_hi), (min(v_lo, coarsest / weave.rows), v_hi)


def _search_range(rig: CaptureRig, patterns: tuple[str, ...]) -> tuple[float, float]:
    """Tiles across the image that the search proposes for any of ``patterns``."""
    scale = rig.view_size / rig.plane_size
    ranges = [tile_range(p, rig) for p in patterns]
    return (min(min(r[0][0], r[1][0]) for r in ranges) * scale, max(max(r[0][1], r[1][1]) for r in ranges) * scale)


def sample_rotation(spectra: lattice.Spectra, rig: CaptureRig, patterns: tuple[str, ...] = priors.PATTERNS) -> float:
    """The sample's rotation in the holder, read from both photos' spectra (degrees)."""
    span = _search_range(rig, patterns)
    return lattice.estimate_rotation(spectra, span, span)


def propose(spectra: lattice.Spectra, rig: CaptureRig, patterns: tuple[str, ...],
            per_pattern: int = 2) -> list[Candidate]:
    """(pattern, tiles) candidates for a sample turned by the rig's ``sample_rotation_deg``, best
    lattice score first (scores compare within a pattern only): the comb lattices joined by those
    read from single peaks (:func:`backend.texture.lattice.with_anchored`)."""
    return _with_anchored(spectra, rig, _comb_lattices(spectra, rig, patterns, per_pattern), per_pattern)


def _scaled_ranges(pattern: str, rig: CaptureRig) -> tuple[tuple[float, float], tuple[float, float]]:
    """The pattern's :func:`tile_range` in tiles across and down the image."""
    scale = rig.view_size / rig.plane_size
    (tu_lo, tu_hi), (tv_lo, tv_hi) = tile_range(pattern, rig)
    return (tu_lo * scale, tu_hi * scale), (tv_lo * scale, tv_hi * scale)


def _comb_lattices(spectra: lattice.Spectra, rig: CaptureRig, patterns: tuple[str, ...],
                   per_pattern: int) -> dict[str, list[lattice.Lattice]]:
    """Per pattern, the comb lattices (:func:`backend.texture.lattice.candidates`) for a sample
    turned by the rig's ``sample_rotation_deg``."""
    lo, hi = _search_range(rig, patterns)
    rotation = rig.sample_rotation_deg
    combs = lattice.estimates(spectra, (lo, hi), (lo, hi), rotation_deg=rotation)
    sigs = signatures(rig)
    return {pattern: lattice.candidates(spectra, combs, sigs[pattern], *_scaled_ranges(pattern, rig),
                                        top=per_pattern, rotation_deg=rotation)
            for pattern in patterns}


def _with_anchored(spectra: lattice.Spectra, rig: CaptureRig, combs: dict[str, list[lattice.Lattice]],
                   per_pattern: int) -> list[Candidate]:
    """The comb lattices per pattern joined by those read from single peaks, as candidates."""
    sigs = signatures(rig)
    out = []
    for pattern, found in combs.items():
        found = lattice.with_anchored(spectra, found, sigs[pattern], *_scaled_ranges(pattern, rig),
                                      top=per_pattern, rotation_deg=rig.sample_rotation_deg)
        out += [Candidate(pattern, c.tiles(rig.view_size, rig.plane_size), c.score) for c in found]
    return out


def placed(spectra: lattice.Spectra, rig: CaptureRig, patterns: tuple[str, ...], rotation: float | None,
           per_pattern: int = 1) -> tuple[float, list[Candidate]]:
    """(the sample's rotation, the candidates for it). A given ``rotation`` is used as it is; otherwise
    the rotation read from the spectra (:func:`sample_rotation`) is checked against the unturned
    sample: both get comb lattices, and the unturned one stays unless the turned one's best lattice
    scores higher. The rotation estimate verifies lattices with generic low harmonics; on a dense
    satin those can prefer a turn of a tenth of a degree by a hair, and at that turn the sieve misses
    the weave's own lattice (measured on the dev golden satin1 renders: 0.15 and 0.24 degrees). The
    comparison leaves out the lattices read from single peaks: on an aliased clean render one can
    explain a pattern's signature better at a wrong turn than the true lattice does unturned (dev
    golden twill0_s2: -1.98 degrees, tiles 4.6 % off); they join the comb lattices of the rotation
    chosen."""
    if rotation is None:
        rotation, turned = 0.0, sample_rotation(spectra, rig, patterns)
        if turned != 0.0:
            at = {angle: _comb_lattices(spectra, replace(rig, sample_rotation_deg=angle), patterns, per_pattern)
                  for angle in (0.0, turned)}
            rotation = turned if _best_score(at[turned]) > _best_score(at[0.0]) else 0.0
            return rotation, _with_anchored(spectra, replace(rig, sample_rotation_deg=rotation), at[rotation],
                                            per_pattern)
    return rotation, propose(spectra, replace(rig, sample_rotation_deg=rotation), patterns, per_pattern)


def _best_score(found: dict[str, list[lattice.Lattice]]) -> float:
    return max((lat.score for lats in found.values() for lat in lats), default=-float("inf"))
