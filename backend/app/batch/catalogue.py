"""The batch's catalogue: one row per photo pair, written as ``DIR/catalogue.json`` and ``DIR/catalogue.csv``.

A row (:data:`COLUMNS`, the CSV's header in this order):

- ``name``, ``status``: done (fitted by this run), kept (a complete folder of an earlier run,
  ``--resume``), failed, cancelled (Ctrl+C came first), pending (not finished yet: only while the
  batch runs);
- the key fitted parameters: ``pattern``, ``tiles``, ``roughness`` and ``thickness`` per yarn
  (``_warp``, ``_weft``) and the ``diffuse_reflection`` colour (``_r``, ``_g``, ``_b``);
- the fit's metrics of both re-renders against the photos (``flip``, ``colour_l1``,
  ``spectrum_corr``; ``_R`` reflection, ``_T`` transmission) and its ``loss``;
- ``fit_s`` (the fit's own wall time, from metrics.json), ``wall_s`` (the pair's time in this batch:
  the fit plus moving its photos and results; empty for kept pairs), ``attempts``, ``reason``
  (why it failed);
- ``folder`` (the results folder, relative to DIR), ``reflection`` and ``transmission`` (the
  photos) and ``interchange`` (every fitted parameter in the paper's one-string form).

The JSON holds the same rows under ``pairs``, plus the batch's photo folder and settings. Both
files are rewritten whole after every finished pair (:func:`backend.core.jsonfile.write_whole`: a
temporary file, then a rename), so at any moment they describe what is on disk.
"""
from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from ...core.jsonfile import write_whole
from ...core.pair_jobs import DONE, KEPT, PairJob
from ...core.results import METRICS_FILE, PARAMS_FILE

JSON_NAME, CSV_NAME = "catalogue.json", "catalogue.csv"
_PER_YARN = ("tiles", "roughness", "thickness")
_RGB = "diffuse_reflection"
_METRICS = ("flip", "colour_l1", "spectrum_corr")
COLUMNS = ("name", "status", "pattern",
           *(f"{name}_{yarn}" for name in _PER_YARN for yarn in ("warp", "weft")),
           *(f"{_RGB}_{channel}" for channel in "rgb"),
           *(f"{metric}_{side}" for metric in _METRICS for side in "RT"),
           "loss", "fit_s", "wall_s", "attempts", "reason", "folder", "reflection", "transmission", "interchange")


class CatalogueError(ValueError):
    """A results folder whose params.json or metrics.json cannot be read; the message names the file."""


def row(job: PairJob, fitted: dict | None = None) -> dict:
    """A job's row: its state, and, for a done or kept job, ``fitted`` (:func:`fitted_values`). A job
    not finished yet is ``pending``, without attempts or a reason."""
    out = dict.fromkeys(COLUMNS)
    files = {side: str(path) if path else None for side, path in (("reflection", job.reflection),
                                                                   ("transmission", job.transmission))}
    if not job.finished:
        return {**out, "name": job.name, "status": "pending", "attempts": 0, **files}
    out.update(name=job.name, status=job.state, attempts=job.attempts, reason=job.reason,
               wall_s=None if job.wall_s is None else round(job.wall_s, 2), **files)
    if job.state in (DONE, KEPT):
        out.update(fitted or {})
    return out


def fitted_values(folder: Path, out_dir: Path) -> dict:
    """The columns a complete results folder fills, read from its params.json and metrics.json."""
    params, metrics = _read(folder / PARAMS_FILE), _read(folder / METRICS_FILE)
    out = {}
    try:
        for key in _PER_YARN:
            out[f"{key}_warp"], out[f"{key}_weft"] = (float(v) for v in params[key])
        for channel, value in zip("rgb", params[_RGB], strict=True):
            out[f"{_RGB}_{channel}"] = float(value)
        for metric in _METRICS:
            for side, image in (("R", "reflection"), ("T", "transmission")):
                out[f"{metric}_{side}"] = float(metrics["metrics"][image][metric])
        out.update(pattern=str(params["pattern"]), interchange=params.get("interchange"),
                   loss=metrics.get("loss"), fit_s=metrics.get("wall_s"), folder=folder.relative_to(out_dir).as_posix())
    except (KeyError, TypeError, ValueError) as exc:
        raise CatalogueError(f"{folder}: params.json or metrics.json lacks a value the catalogue needs "
                             f"({type(exc).__name__}: {exc})") from None
    return out


def _read(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise CatalogueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise CatalogueError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise CatalogueError(f"{path}: expected a JSON object")
    return data


def write(out_dir: Path, rows: list[dict], header: dict) -> tuple[Path, Path]:
    """Writes both files whole (rows sorted by name) and returns their paths."""
    rows = sorted(rows, key=lambda r: r["name"])
    table = io.StringIO(newline="")
    writer = csv.DictWriter(table, fieldnames=COLUMNS)
    writer.writeheader()
    writer.writerows({k: "" if v is None else v for k, v in r.items()} for r in rows)
    document = json.dumps({**header, "columns": list(COLUMNS), "pairs": rows}, indent=2) + "\n"
    return write_whole(out_dir / JSON_NAME, document), write_whole(out_dir / CSV_NAME, table.getvalue())
