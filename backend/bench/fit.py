"""Fit benchmark: ``python -m backend bench fit --golden DIR --real DIR [--cases ...] [--json]``.

Runs the real ``fit`` command (a subprocess per pair, so wall time and peak memory are the
product's; wall time includes starting Python and importing torch) on
- the synthetic targets of a golden folder (``cases.json`` + ``<name>_R.png``/``_T.png``; cases with
  ablation flags are skipped, the fit uses the full model), reporting parameter errors against the
  true parameters: pattern, roughness MAE, thickness MAE (warp and weft), tiles error (worst axis, %);
- the real pairs of a folder (``<name>_R.*``/``_T.*``);
and, for every pair, FLIP, 16 x 16 colour L1 and spectrum correlation of the re-renders against the
photos (same definitions as the team's ``photo_metrics.py``), the camera blur the fit found, wall time
and peak memory. Prints one
line per pair and a summary with the targets of the fit issue.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ..core.pairs import find_pairs
from ..core.params import FabricParams

TARGETS = {"flip": 0.12, "colour_l1": 0.02, "spectrum_corr": 0.6, "roughness_mae": 0.05,
           "thickness_mae": 0.25, "tiles_error_pct": 2.0, "wall_s": 120.0}


def _children_cpu_s() -> float | None:
    """User + system CPU time of the waited-for child processes so far (POSIX; None elsewhere)."""
    try:
        import resource  # POSIX only
    except ImportError:
        return None
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_fit(reflection: Path, transmission: Path, out: Path, extra: list[str], env: dict | None = None) -> dict:
    """The ``fit`` command on one pair in a subprocess (``env`` adds environment variables): its
    parameters, metrics, wall time, CPU time (POSIX) and stage timings, or ``error``."""
    cmd = [sys.executable, "-m", "backend", "fit", str(reflection), str(transmission), "--out", str(out),
           "--json-progress", *extra]
    cpu_before = _children_cpu_s()
    started = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parents[2], env={**os.environ, **(env or {})})
    stdout, stderr = proc.communicate()
    wall = time.perf_counter() - started
    cpu = None if cpu_before is None else _children_cpu_s() - cpu_before
    lines = [json.loads(line) for line in stdout.splitlines() if line.startswith("{")]
    final = lines[-1] if lines else {"event": "error", "message": stderr[-500:]}
    if final.get("event") != "result":
        return {"error": final.get("message", "no result"), "wall_s": wall}
    metrics = json.loads((out / "metrics.json").read_text())
    params = FabricParams.from_dict(json.loads((out / "params.json").read_text()))
    return {"params": params, "metrics": metrics["metrics"], "wall_s": wall, "cpu_s": cpu, "fit_s": metrics["wall_s"],
            "timings": metrics.get("timings", {}), "stderr": stderr,
            "peak_mb": metrics.get("peak_mb"), "camera_blur_px": metrics.get("camera_blur_px")}


def _errors(fitted: FabricParams, truth: FabricParams) -> dict:
    def mae(name):
        return sum(abs(a - b) for a, b in zip(fitted.flat(name), truth.flat(name))) / 2

    return {"pattern_ok": fitted.pattern == truth.pattern, "roughness_mae": mae("roughness"),
            "thickness_mae": mae("thickness"),
            "tiles_error_pct": 100 * max(abs(f / t - 1) for f, t in zip(fitted.tiles, truth.tiles))}


def bench_fit(golden: str | None, real: str | None, cases: list[str] | None, extra: list[str], as_json: bool) -> int:
    rows = []
    with tempfile.TemporaryDirectory(prefix="fit-bench-") as tmp:
        jobs = []
        if golden:
            gdir = Path(golden)
            for case in json.loads((gdir / "cases.json").read_text()):
                if case.get("flags") or (cases and case["name"] not in cases):
                    continue
                jobs.append(("synthetic", case["name"], gdir / f"{case['name']}_R.png", gdir / f"{case['name']}_T.png",
                             FabricParams.from_interchange(case["params"])))
        if real:
            for pair in find_pairs(Path(real))[0]:
                if not cases or pair.name in cases:
                    jobs.append(("real", pair.name, pair.reflection, pair.transmission, None))
        for kind, name, r, t, truth in jobs:
            result = run_fit(r, t, Path(tmp) / f"{kind}_{name}", extra)
            row = {"kind": kind, "name": name, "wall_s": round(result["wall_s"], 1)}
            if "error" in result:
                row["error"] = result["error"]
            else:
                row.update(pattern=result["params"].pattern, tiles=[round(x, 1) for x in result["params"].tiles],
                           peak_mb=round(result["peak_mb"] or 0, 1), camera_blur_px=result["camera_blur_px"])
                for tag in ("reflection", "transmission"):
                    for key, value in result["metrics"][tag].items():
                        row[f"{key}_{tag[0].upper()}"] = round(value, 4)
                if truth is not None:
                    errors = _errors(result["params"], truth)
                    row.update({k: (round(v, 4) if isinstance(v, float) else v) for k, v in errors.items()})
            rows.append(row)
            print(json.dumps(row) if as_json else _format(row), flush=True)
    summary = _summary(rows)
    print(json.dumps(summary) if as_json else _format_summary(summary), flush=True)
    return 0 if all("error" not in r for r in rows) else 1


def _format(row: dict) -> str:
    if "error" in row:
        return f"{row['kind']:9s} {row['name']:16s} ERROR {row['error']}"
    text = (f"{row['kind']:9s} {row['name']:16s} {row['pattern']:7s} "
            f"tiles {row['tiles'][0]:6.1f} {row['tiles'][1]:6.1f}"
            f"  FLIP {row['flip_R']:.3f}/{row['flip_T']:.3f}  colour {row['colour_l1_R']:.4f}/{row['colour_l1_T']:.4f}"
            f"  spectrum {row['spectrum_corr_R']:.3f}/{row['spectrum_corr_T']:.3f}"
            f"  blur {row['camera_blur_px'] or 0:.2f}"
            f"  {row['wall_s']:5.1f} s  {row['peak_mb']:.0f} MB")
    if "roughness_mae" in row:
        text += (f"  pattern {'ok' if row['pattern_ok'] else 'WRONG'}  roughness {row['roughness_mae']:.3f}"
                 f"  thickness {row['thickness_mae']:.3f}  tiles {row['tiles_error_pct']:.2f}%")
    return text


def _summary(rows: list[dict]) -> dict:
    def mean(key, kind=None):
        values = [r[key] for r in rows if key in r and (kind is None or r["kind"] == kind)]
        return round(sum(values) / len(values), 4) if values else None

    out = {"pairs": len(rows), "failed": sum("error" in r for r in rows), "wall_s_mean": mean("wall_s"),
           "wall_s_max": max((r["wall_s"] for r in rows), default=None)}
    for kind in ("real", "synthetic"):
        out[kind] = {f"{m}_{t}": mean(f"{m}_{t}", kind) for m in ("flip", "colour_l1", "spectrum_corr") for t in "RT"}
    synthetic = [r for r in rows if r["kind"] == "synthetic" and "pattern_ok" in r]
    if synthetic:
        out["synthetic"].update(pattern_accuracy=sum(r["pattern_ok"] for r in synthetic) / len(synthetic),
                                roughness_mae=mean("roughness_mae"), thickness_mae=mean("thickness_mae"),
                                tiles_error_pct_max=round(max(r["tiles_error_pct"] for r in synthetic), 3))
    out["targets"] = TARGETS
    return out


def _format_summary(s: dict) -> str:
    lines = [f"summary: {s['pairs']} pairs, {s['failed']} failed, wall time mean {s['wall_s_mean']} s, "
             f"max {s['wall_s_max']} s (target <= {TARGETS['wall_s']:.0f} s)"]
    for kind in ("real", "synthetic"):
        k = s[kind]
        if k.get("flip_R") is None:
            continue
        lines.append(f"  {kind}: FLIP {k['flip_R']}/{k['flip_T']} (<= {TARGETS['flip']}), "
                     f"colour L1 {k['colour_l1_R']}/{k['colour_l1_T']} (<= {TARGETS['colour_l1']}), "
                     f"spectrum {k['spectrum_corr_R']}/{k['spectrum_corr_T']} (>= {TARGETS['spectrum_corr']})")
    syn = s["synthetic"]
    if "pattern_accuracy" in syn:
        lines.append(f"  synthetic parameters: pattern {syn['pattern_accuracy']:.0%} right, "
                     f"roughness MAE {syn['roughness_mae']} (<= {TARGETS['roughness_mae']}), "
                     f"thickness MAE {syn['thickness_mae']} (<= {TARGETS['thickness_mae']}),"
                     f" worst tiles error {syn['tiles_error_pct_max']}% (<= {TARGETS['tiles_error_pct']}%)")
    return "\n".join(lines)
