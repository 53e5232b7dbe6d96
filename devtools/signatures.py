"""The default rig's pattern signatures shipped with the backend (``backend/data/signatures.json``).

Run ``python -m devtools signatures`` after a change to the renderer, the presets' typical parameters
or :func:`backend.texture.lattice.signature`; tests/test_placement.py checks the shipped file against
fresh renders.
"""
from __future__ import annotations

import json
from pathlib import Path

from backend.core import priors
from backend.core.rig import DEFAULT_RIG
from backend.texture.candidates import SHIPPED_SIGNATURES, SIGNATURE_DENSITY, rendered_signatures


def write_shipped_signatures(path: Path = SHIPPED_SIGNATURES) -> Path:
    """Renders the default rig's signatures of every preset into ``path`` (JSON)."""
    rendered = rendered_signatures(DEFAULT_RIG, priors.FIT_PATTERNS)
    table = {"rig": DEFAULT_RIG.to_dict(), "density": SIGNATURE_DENSITY,
             "patterns": {pattern: [{"m": s.m.tolist(), "n": s.n.tolist(), "weight": s.weight.tolist()}
                                    for s in rendered[DEFAULT_RIG, pattern]] for pattern in priors.FIT_PATTERNS}}
    path.write_text(json.dumps(table) + "\n")
    return path
