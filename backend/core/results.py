"""A fit's results folder: the files ``python -m backend fit --out DIR`` writes, and when it is complete.

A folder is complete when every file of :data:`RESULT_FILES` is there and not empty; anything less
(a fit stopped half-way, a copy cut short) is not a result. The batch's ``--resume`` skips only
complete folders, and the Blender batch's ``--from-results`` imports only those. Plain Python: the
add-on reads this module without torch.
"""
from __future__ import annotations

from pathlib import Path

PARAMS_FILE = "params.json"
METRICS_FILE = "metrics.json"
# Everything a finished fit leaves in its folder (backend/app/cli/fit.py writes them; a test keeps the two in step).
RESULT_FILES = (PARAMS_FILE, METRICS_FILE, "reflection.png", "transmission.png", "report.png")


def missing_files(folder: str | Path) -> list[str]:
    """The result files that ``folder`` lacks (or holds empty), in :data:`RESULT_FILES` order."""
    folder = Path(folder)
    missing = []
    for name in RESULT_FILES:
        path = folder / name
        if not path.is_file() or path.stat().st_size == 0:
            missing.append(name)
    return missing


def is_complete(folder: str | Path) -> bool:
    """True when ``folder`` holds every result file of a finished fit."""
    return not missing_files(folder)
