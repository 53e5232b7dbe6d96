"""The files of a fit (no bpy): its photos, its result folder, its rig.json, its params.json.

Result folders are never reused: :func:`new_run_folder` creates ``<parent>/<name>_001``,
``_002``, ... atomically (``mkdir`` without ``exist_ok``), so an earlier fit is never overwritten.
:func:`new_fit` prepares one fit of a photo pair in such a folder; the panel's Fit and the batch
both start their fits through it.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

from . import declarations, paths, rig_settings
from .backend_bridge import Backend, BackendError, FitProcess, FitRequest

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


UNSAVED_RESULTS = "Woven Fabric Fits"  # the results folder of an unsaved .blend, in Documents or the home folder
PARTIAL = " (partial)"  # the name of a material made from a cancelled fit's best parameters so far


def default_results_parent(blend_path: str = "", home: Path | None = None) -> Path:
    """Beside the saved .blend (``fabric_fits``); for an unsaved one, ``Woven Fabric Fits`` in the
    user's Documents folder (the home folder where there is none): a place the artist finds again,
    unlike the system's temporary folder, which is cleared behind their back."""
    if blend_path:
        return Path(blend_path).resolve().parent / "fabric_fits"
    home = Path.home() if home is None else home
    documents = home / "Documents"
    return (documents if documents.is_dir() else home) / UNSAVED_RESULTS


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
    return paths.write_whole(Path(folder) / "rig.json", json.dumps(rig, indent=2) + "\n")


def check_fit_options(options: dict) -> None:
    """Raises BackendError with the declaration's message where ``options`` (FitRequest's fields) hold
    a value the backend would refuse: checked before a fit (or a batch) makes anything."""
    try:
        FitRequest(Path(), Path(), Path(), **options).arguments()
    except TypeError as exc:
        raise BackendError(f"not an option of a fit: {exc}") from None


def new_fit(backend: Backend, reflection: Path, transmission: Path, results_parent: str | Path, name: str,
            rig: dict, **options) -> FitProcess:
    """A fit of one photo pair in a new result folder holding its ``rig.json`` (not started yet).

    ``options`` are FitRequest's (pattern, iterations, size, device, output_spp, strict), checked by the
    backend's declaration before anything is made (BackendError); the backend's whole stderr goes to
    ``backend.log`` in the folder when the run ends.
    """
    check_fit_options(options)
    out_dir = new_run_folder(results_parent, name)
    request = FitRequest(reflection, transmission, out_dir, rig_json=write_rig_json(out_dir, rig), **options)
    return FitProcess.fit(backend, request, log_path=out_dir / "backend.log")


def read_fit_params(result: dict) -> dict:
    """The ``params.json`` named by a fit's result event, as a dict, checked whole before anything
    is made from it: ValueError naming the file and the problem where it is not a fit (wrong types,
    values out of range or not finite, an unknown weave, a bad rig), so no material is half made."""
    path = Path(result.get("params") or Path(result["out_dir"]) / "params.json")
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the fitted parameters ({exc.strerror or exc})") from None
    except (ValueError, RecursionError) as exc:  # bad syntax or encoding, an integer of thousands of digits
        raise ValueError(f"{path}: the fitted parameters are not valid JSON ({exc})") from None
    try:
        declarations.check_params(data)
        rig_settings.capture_rig(data.get("rig"))
    except ValueError as exc:
        raise ValueError(f"{path}: not a fit's parameters: {exc}") from None
    return data


def cancelled_fit_params(out_dir: str | Path) -> tuple[dict, bool] | None:
    """What a cancelled fit left in ``out_dir``: (its params.json, False) when it was cancelled after
    the fit ended (in the re-renders or the report), else (its best parameters so far, True: the
    protocol's partial file), or None when it was cancelled before it had any."""
    for name, partial in (("params.json", False), (declarations.protocol().PARTIAL_PARAMS_FILE, True)):
        path = Path(out_dir) / name
        if path.is_file():
            return read_fit_params({"params": str(path)}), partial
    return None
