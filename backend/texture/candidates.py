"""Candidate weaves and yarn densities for a photo pair, read from the spectrum (no optimisation).

1. :func:`backend.texture.lattice.estimate` finds the tile lattice that explains the spectral peaks of both
   photos, up to small sub- and super-multiples;
2. for each preset, :func:`backend.texture.lattice.candidates` scales that lattice by small ratios, polishes
   each hypothesis and scores it with the preset's *signature* (its harmonic structure, measured once
   per rig from a render of the preset's typical parameters at a low density).

The fit then gives the best few (pattern, tiles) candidates a short optimisation each and keeps the
one that explains the photos best (:mod:`backend.fit.search`).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import torch

from ..core import priors
from ..core.rig import CaptureRig
from ..model.render import Renderer
from . import lattice

SIGNATURE_DENSITY = 20.0  # tiles across the image for the signature renders: every harmonic below Nyquist


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


def _search_range(rig: CaptureRig, patterns: tuple[str, ...]) -> tuple[float, float]:
    """Tiles across the image that any of ``patterns``' priors can produce."""
    scale = rig.view_size / rig.plane_size
    ranges = [priors.tile_range(p) for p in patterns]
    return (min(min(r[0][0], r[1][0]) for r in ranges) * scale, max(max(r[0][1], r[1][1]) for r in ranges) * scale)


def sample_rotation(spectra: lattice.Spectra, rig: CaptureRig, patterns: tuple[str, ...] = priors.PATTERNS) -> float:
    """The sample's rotation in the holder, read from both photos' spectra (degrees)."""
    span = _search_range(rig, patterns)
    return lattice.estimate_rotation(spectra, span, span)


def propose(spectra: lattice.Spectra, rig: CaptureRig, patterns: tuple[str, ...],
            per_pattern: int = 2) -> list[Candidate]:
    """(pattern, tiles) candidates for a sample turned by the rig's ``sample_rotation_deg``, best
    lattice score first (scores compare within a pattern only)."""
    scale = rig.view_size / rig.plane_size
    ranges = {p: priors.tile_range(p) for p in patterns}
    lo, hi = _search_range(rig, patterns)
    rotation = rig.sample_rotation_deg
    comb = lattice.estimate(spectra, (lo, hi), (lo, hi), rotation_deg=rotation)
    sigs = signatures(rig)
    out = []
    for pattern in patterns:
        (tu_lo, tu_hi), (tv_lo, tv_hi) = ranges[pattern]
        found = lattice.candidates(spectra, comb, sigs[pattern], (tu_lo * scale, tu_hi * scale),
                                   (tv_lo * scale, tv_hi * scale), top=per_pattern, rotation_deg=rotation)
        out += [Candidate(pattern, c.tiles(rig.view_size, rig.plane_size), c.score) for c in found]
    return out
