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
from backend.texture.signatures import SHIPPED_SIGNATURES, rendered_signatures, to_json


def write_shipped_signatures(path: Path = SHIPPED_SIGNATURES) -> Path:
    """Renders the default rig's signatures of every preset into ``path`` (JSON)."""
    rendered = rendered_signatures(DEFAULT_RIG, priors.FIT_PATTERNS)
    path.write_text(json.dumps(to_json(DEFAULT_RIG, rendered)) + "\n")
    return path
