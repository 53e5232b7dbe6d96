"""``python -m devtools signatures``: renders the default rig's pattern signatures into the backend's data."""
from __future__ import annotations

from ..signatures import write_shipped_signatures


def run_signatures(args) -> int:
    print(f"wrote {write_shipped_signatures()}")
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("signatures", help="render the default rig's pattern signatures shipped with the backend")
    p.set_defaults(run=run_signatures)
