"""The files of a fit (no bpy): its photos, its result folder, its rig.json, its params.json.

Result folders are never reused: :func:`new_run_folder` creates ``<parent>/<name>_001``,
``_002``, ... atomically (``mkdir`` without ``exist_ok``), so an earlier fit is never overwritten.
:func:`new_fit` prepares one fit of a photo pair in such a folder; the panel's Fit and the batch
both start their fits through it.
"""
from __future__ import annotations

import json
import re
import tempfile
from pathlib import Path

from .backend_bridge import Backend, FitProcess, FitRequest

_RUN_NUMBER = re.compile(r"_\d{3}$")  # the suffix new_run_folder adds


def require_photo(label: str, chosen: str, path: Path) -> Path:
    """``path`` when the user chose a photo and it exists; else a ValueError saying which is missing."""
    if not chosen:
        raise ValueError(f"Choose the {label} photo first.")
    if not path.is_file():
        raise ValueError(f"The {label} photo {path} does not exist.")
    return path


def fit_name(chosen: str, reflection: Path) -> str:
    """The material and folder name: the chosen name, else the photo's name without ``_R``."""
    if chosen:
        return chosen
    stem = reflection.stem
    return stem[:-2] if stem[-2:] in ("_R", "_r") else (stem or "Fabric")


def safe_name(name: str) -> str:
    """A folder-safe version of a material or photo name."""
    cleaned = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._")
    return cleaned or "fabric"


def new_run_folder(parent: str | Path, name: str) -> Path:
    """Creates and returns a folder no earlier fit used: ``<parent>/<name>_NNN``."""
    parent = Path(parent)
    parent.mkdir(parents=True, exist_ok=True)
    base = safe_name(name)
    for number in range(1, 100000):
        folder = parent / f"{base}_{number:03d}"
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return folder
    raise OSError(f"{parent}: no free result folder name for {base}")


def run_name(folder: Path) -> str:
    """The name a result folder was made for: ``linen_002`` -> ``linen``."""
    return _RUN_NUMBER.sub("", folder.name) or "Fabric"


def default_results_parent(blend_path: str = "") -> Path:
    """Beside the saved .blend (``fabric_fits``), else in the temporary folder."""
    if blend_path:
        return Path(blend_path).resolve().parent / "fabric_fits"
    return Path(tempfile.gettempdir()) / "woven_fabric_fits"


def unused_path(path: str | Path) -> Path:
    """``path`` if it does not exist, else ``<stem>-2<suffix>``, ``-3``, ...: never overwrite."""
    path = Path(path)
    number = 2
    candidate = path
    while candidate.exists():
        candidate = path.with_name(f"{path.stem}-{number}{path.suffix}")
        number += 1
    return candidate


def write_rig_json(folder: Path, rig: dict) -> Path:
    path = Path(folder) / "rig.json"
    path.write_text(json.dumps(rig, indent=2) + "\n")
    return path


def new_fit(backend: Backend, reflection: Path, transmission: Path, results_parent: str | Path, name: str,
            rig: dict, **options) -> FitProcess:
    """A fit of one photo pair in a new result folder holding its ``rig.json`` (not started yet).

    ``options`` are FitRequest's (pattern, iterations, size, device, output_spp); the backend's
    whole stderr goes to ``backend.log`` in the folder when the run ends.
    """
    out_dir = new_run_folder(results_parent, name)
    request = FitRequest(reflection, transmission, out_dir, rig_json=write_rig_json(out_dir, rig), **options)
    return FitProcess.fit(backend, request, log_path=out_dir / "backend.log")


def read_fit_params(result: dict) -> dict:
    """The ``params.json`` named by a fit's result event, as a dict."""
    path = Path(result.get("params") or Path(result["out_dir"]) / "params.json")
    try:
        return json.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the fitted parameters ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: the fitted parameters are not valid JSON ({exc})") from None
