"""The patterns' harmonic signatures: which lattice harmonics carry a weave's energy.

Per preset, the (reflection, transmission) signatures (:func:`backend.texture.lattice.signature`) of
a render of its typical parameters at ``signature_density`` tiles across, unturned and unsheared
whatever the rig's placement: the scores read a placed sample's lattice at its turned frequencies,
so the weave's own harmonic weights are the ones to compare (a turned render's harmonics sit off
the unturned lattice, and its weights would drift with the turn).

The default rig's ship with the backend (:data:`SHIPPED_SIGNATURES`, written by ``python -m devtools
signatures``); any other rig's are rendered once per process, only for the patterns asked for.
"""
from __future__ import annotations

import functools
import json
from collections import OrderedDict
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from ..core import priors
from ..core.rig import CaptureRig
from ..model.render import Renderer
from .gates import GATES
from .lattice import Signature, signature

SHIPPED_SIGNATURES = Path(__file__).resolve().parent.parent / "data" / "signatures.json"
CACHED_RIGS = 4  # rigs whose signatures a process keeps

_SIGNATURES: OrderedDict[tuple[CaptureRig, str], list[Signature]] = OrderedDict()


def signatures(rig: CaptureRig, patterns: tuple[str, ...] = priors.FIT_PATTERNS) -> dict[str, list[Signature]]:
    """Per pattern of ``patterns``, its (reflection, transmission) signatures for ``rig``."""
    unsheared = replace(rig, sample_skew_deg=0.0, sample_rotation_deg=0.0)
    missing = [pattern for pattern in patterns if (unsheared, pattern) not in _SIGNATURES]
    shipped = _shipped() if missing else {}
    _SIGNATURES.update({(unsheared, p): shipped[unsheared, p] for p in missing if (unsheared, p) in shipped})
    missing = [pattern for pattern in missing if (unsheared, pattern) not in shipped]
    if missing:
        _SIGNATURES.update(rendered_signatures(unsheared, missing))
    for pattern in patterns:
        _SIGNATURES.move_to_end((unsheared, pattern))
    while len(_SIGNATURES) > CACHED_RIGS * len(priors.FIT_PATTERNS):
        _SIGNATURES.popitem(last=False)
    return {pattern: _SIGNATURES[unsheared, pattern] for pattern in patterns}


def rendered_signatures(rig: CaptureRig, patterns) -> dict[tuple[CaptureRig, str], list[Signature]]:
    """The signatures of ``patterns`` for an unsheared ``rig``, rendered now (one renderer: its camera
    samples serve each pattern)."""
    renderer = Renderer(rig, size=512, spp=4, geometry_cache=0)
    density = GATES.signature_density
    tiles = density * rig.plane_size / rig.view_size
    out = {}
    for pattern in patterns:
        with torch.no_grad():
            pair = renderer.render(priors.typical(pattern).replace(tiles=(tiles, tiles)))
        out[rig, pattern] = [signature(img.numpy(), density, density) for img in (pair.reflection, pair.transmission)]
    return out


def to_json(rig: CaptureRig, rendered: dict[tuple[CaptureRig, str], list[Signature]]) -> dict:
    """The shipped file's table of ``rendered`` (every preset of the fit for ``rig``)."""
    return {"rig": rig.to_dict(), "density": GATES.signature_density,
            "patterns": {pattern: [{"m": s.m.tolist(), "n": s.n.tolist(), "weight": s.weight.tolist()}
                                   for s in rendered[rig, pattern]] for pattern in priors.FIT_PATTERNS}}


@functools.lru_cache(maxsize=1)
def _shipped() -> dict[tuple[CaptureRig, str], list[Signature]]:
    return shipped_signatures()


def shipped_signatures(path: Path = SHIPPED_SIGNATURES) -> dict[tuple[CaptureRig, str], list[Signature]]:
    """The signatures in ``path`` (none when it is missing or was made for other presets or another
    density: they are then rendered as needed)."""
    try:
        table = json.loads(path.read_text())
        rig = CaptureRig.from_dict(table["rig"])
        if table["density"] != GATES.signature_density or set(table["patterns"]) != set(priors.FIT_PATTERNS):
            return {}
        return {(rig, pattern): [Signature(np.asarray(s["m"]), np.asarray(s["n"]), np.asarray(s["weight"],
                                                                                              dtype=np.float64))
                                 for s in pair]
                for pattern, pair in table["patterns"].items()}
    except (OSError, ValueError, KeyError, TypeError):
        return {}
