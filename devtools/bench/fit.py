"""Fit benchmark: ``python -m devtools bench fit [--synthetic DIR ...] [--real DIR ...] [--cases ...]``.

Runs the real ``fit`` command (a subprocess per pair, so wall time and peak memory are the
product's; wall time includes starting Python and importing torch) on
- synthetic folders (``cases.json`` + ``<name>_R.*``/``_T.*``): the golden renders of the paper's
  renderer (cases with ablation flags are skipped: the fit uses the full model) and photo-like sets
  (``python -m devtools photolike``: their cases also carry the true rig and phone effects). Against
  the truth: pattern and weave family, roughness and thickness MAE (warp and weft), tiles error
  (worst axis, %), the rotation error, and the novel-light error (:mod:`devtools.bench.novel_light`);
  the true weave's pixels per yarn, and the truth figures again over the pairs at or above the
  sampling limit (``resolved``: what an image can show at all);
- real pairs (``<name>_R.*``/``_T.*``; no truth);
and, for every pair, FLIP, 16 x 16 colour L1 and spectrum correlation of the re-renders against the
photos (the definitions of the team's ``photo_metrics.py``), the camera blur, rotation and spacing
warp the fit found (on photo-like sets also the phone's warp and the fit's distance from it:
:func:`warp_errors`, and the phone's blur and the fit's camera blur minus it: :func:`blur_errors`),
which parameters ended at a bound, wall time, peak memory and the optimisation's steps run
of its iterations (fewer where it converged). Prints one line per pair and a
summary per kind of pair with the targets of the fit issue.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from operator import itemgetter
from pathlib import Path

import numpy as np

from backend.core import variation
from backend.core.pairs import find_pairs
from backend.core.params import FabricParams
from backend.core.priors import family
from backend.core.rig import DEFAULT_RIG, CaptureRig
from backend.model.spacing_warp import SpacingWarp, grid_centres, non_affine, rms
from backend.texture.frequencies import yarns_in_view

from ..phone import PhoneEffects
from .ledger import NOT_RECORDED, Ledger
from .novel_light import novel_light_error

KINDS = ("real", "golden", "photolike")  # the kinds of pair, in the summary's order
TARGETS = {
    "real": {"flip_max": 0.12, "colour_l1_max": 0.015, "spectrum_corr_min": 0.65, "family_accuracy_min": 1.0,
             "texture_gap_db_max": 3.0},
    "photolike": {"pattern_accuracy_min": 0.95, "roughness_mae_max": 0.06, "tiles_error_pct_max": 1.0,
                  "novel_colour_l1_max": 0.01, "variation_rms_abs_error_max": 0.25, "blur_abs_error_px_max": 0.3},
    "golden": {"pattern_accuracy_min": 1.0, "roughness_mae_max": 0.103, "tiles_error_pct_max": 1.0,
               "thickness_mae_max": 0.447},
    "wall_s": {"mean_max": 90.0, "max_max": 120.0},
}


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
    saved = json.loads((out / "params.json").read_text())
    run = saved["fit"]["settings"]
    return {"params": FabricParams.from_dict(saved), "rig": CaptureRig.from_dict(saved["rig"]),
            "metrics": metrics["metrics"], "wall_s": wall, "cpu_s": cpu, "timings": metrics.get("timings", {}),
            "stderr": stderr, "peak_mb": metrics.get("peak_mb"), "at_bounds": metrics.get("at_bounds", []),
            "steps": run.get("steps"), "iterations": run.get("iterations"),
            "registration": saved.get("photos", {}).get("registration"),
            "warp": SpacingWarp.from_dict(warp) if (warp := saved["fit"].get("spacing_warp")) else None}


RESOLVED_PX_PER_YARN = 2.0  # the sampling limit: finer yarns alias, and a phone's optics blur them away


def pixels_per_yarn(truth: FabricParams, rig: CaptureRig) -> float:
    """Film pixels per yarn of the true weave on its finer axis. Below RESOLVED_PX_PER_YARN the yarns
    are past the sampling limit: a clean render aliases them into a lattice that only a model with the
    same sampling reads back (the dev goldens), and a photo's optics, noise and spacing warp leave
    little of that to read (the photo-like sets apply them after the render has aliased)."""
    return rig.film_size / yarns_in_view(truth.pattern, truth.tiles, rig)


def parameter_errors(fitted: FabricParams, truth: FabricParams) -> dict:
    def mae(name):
        return sum(abs(a - b) for a, b in zip(fitted.flat(name), truth.flat(name))) / 2

    return {"pattern_ok": fitted.pattern == truth.pattern, "family_ok": family(fitted.pattern) == family(truth.pattern),
            "roughness_mae": mae("roughness"), "thickness_mae": mae("thickness"),
            "tiles_error_pct": tiles_error_pct(fitted.tiles, truth.tiles)}


def warp_errors(fitted: SpacingWarp | None, phone: PhoneEffects, film_size: int) -> dict:
    """The phone's uneven yarn spacing against the one the fit read: the root mean square of the true
    warp's non-affine part (the tiles, rotation and skew carry the rest) and of the fitted one's
    difference from it, film pixels."""
    x, y = np.meshgrid(grid_centres(film_size), grid_centres(film_size), indexing="xy")
    true = [non_affine(d, film_size) for d in phone.displacement(x, y)]
    found = (0.0, 0.0) if fitted is None else fitted.sampled(film_size)
    return {"warp_true_rms_px": round(rms(*true), 3),
            "warp_error_px": round(rms(true[0] - found[0], true[1] - found[1]), 3)}


def blur_errors(fitted_px: float, phone: PhoneEffects) -> dict:
    """The camera blur the fit used against the phone's (film pixels). Not a truth to the last
    hundredth (the sensor's pixels, the JPEG and the resize soften a photo a little more), but a fit
    far from it has the rest wrong with it: its roughness and its loss too."""
    return {"phone_blur_px": round(phone.blur_px, 3), "blur_error_px": round(fitted_px - phone.blur_px, 3)}


def variation_rms(params: FabricParams) -> float:
    """The yarn variation's overall amplitude: the root of the summed squared amplitudes of every
    kind, meaned over warp and weft (the variation reading gives warp and weft alike)."""
    return math.sqrt(sum(a * a for kind in variation.KINDS
                         for a in getattr(params, variation.amplitude_name(kind))) / 2)


def forward_error(fitted: FabricParams, truth: FabricParams) -> float:
    """The forward scattering's error, meaned over warp and weft (a pair without it: its truth is 0)."""
    return sum(abs(a - b) for a, b in zip(fitted.forward_scattering, truth.forward_scattering)) / 2


def variation_errors(fitted: FabricParams, truth: FabricParams) -> dict:
    """The variation's overall amplitude, true and fitted, and the fitted one's relative error
    (None where the truth has none)."""
    true, found = variation_rms(truth), variation_rms(fitted)
    return {"variation_rms_true": round(true, 4), "variation_rms": round(found, 4),
            "variation_rms_error": round(found / true - 1, 3) if true > 0 else None}


def tiles_error_pct(found, truth) -> float:
    """The worst axis's relative error of ``found`` tiles against the ``truth``, in percent."""
    return 100 * max(abs(f / t - 1) for f, t in zip(found, truth))


def pair_jobs(synthetic: list[str], real: list[str], names: list[str] | None) -> list[dict]:
    jobs = []
    for folder in map(Path, synthetic):
        files = {pair.name: pair for pair in find_pairs(folder)[0]}
        for case in json.loads((folder / "cases.json").read_text()):
            if case.get("flags") or (names and case["name"] not in names) or case["name"] not in files:
                continue
            pair = files[case["name"]]
            jobs.append({"kind": "photolike" if "phone" in case else "golden", "name": case["name"],
                         "reflection": pair.reflection, "transmission": pair.transmission,
                         "truth": FabricParams.from_interchange(case["params"]).replace(
                             **{name: tuple(value) for name, value in case.get("variation", {}).items()},
                             forward_scattering=tuple(case.get("forward_scattering", (0.0, 0.0)))),
                         "rig": CaptureRig.from_dict(case["rig"]) if "rig" in case else DEFAULT_RIG,
                         "phone": PhoneEffects(**case["phone"]) if "phone" in case else None,
                         "move": case.get("move")})
    for folder in map(Path, real):
        for pair in find_pairs(folder)[0]:
            if not names or pair.name in names:
                jobs.append({"kind": "real", "name": pair.name, "reflection": pair.reflection,
                             "transmission": pair.transmission, "truth": None})
    return jobs


def bench_fit(synthetic: list[str], real: list[str], names: list[str] | None, extra: list[str], as_json: bool,
              keep: str | None = None, novel_light: bool = True, ledger: Ledger = NOT_RECORDED) -> int:
    rows = []
    with tempfile.TemporaryDirectory(prefix="fit-bench-") as tmp:
        work = Path(keep) if keep else Path(tmp)
        for job in pair_jobs(synthetic, real, names):
            out = work / f"{job['kind']}_{job['name']}"
            if keep and out.exists():
                shutil.rmtree(out)
            row = pair_row(job, run_fit(job["reflection"], job["transmission"], out, extra), novel_light)
            rows.append(row)
            ledger.print_row(row, as_json, _format)
    summary = summarise(rows)
    ledger.print_summary(summary, as_json, _format_summary)
    return 0 if all("error" not in r for r in rows) else 1


def pair_row(job: dict, result: dict, novel_light: bool) -> dict:
    """One pair's row (a :func:`pair_jobs` job, its :func:`run_fit` result): what the fit found, the
    photos' framing, the re-renders' metrics and, where the pair has a truth, the errors against it."""
    row = {"kind": job["kind"], "name": job["name"], "wall_s": round(result["wall_s"], 1)}
    if "error" in result:
        return {**row, "error": result["error"]}
    fitted, rig = result["params"], result["rig"]
    row.update(pattern=fitted.pattern, tiles=[round(x, 1) for x in fitted.tiles],
               peak_mb=round(result["peak_mb"] or 0, 1), camera_blur_px=rig.camera_blur_px,
               rotation_deg=rig.sample_rotation_deg, skew_deg=rig.sample_skew_deg,
               at_bounds=result["at_bounds"], steps=result["steps"], iterations=result["iterations"],
               warp_rms_px=round(result["warp"].rms_px(rig.film_size) if result["warp"] else 0.0, 3))
    registration = result["registration"]
    if registration is not None or job.get("move") is not None:
        # the photos' framing as registered, beside the phone's true move where the set has one
        row["registered"] = None if registration is None else {
            k: registration[k] for k in ("moved", "magnification", "turn_deg", "matches")}
        row["move"] = job.get("move")
    for tag in ("reflection", "transmission"):
        for key, value in result["metrics"][tag].items():
            row[f"{key}_{tag[0].upper()}"] = round(value, 4)
    if job["truth"] is not None:
        row.update(truth_errors(job, result, novel_light))
    return row


def truth_errors(job: dict, result: dict, novel_light: bool) -> dict:
    """The fit against the pair's truth: parameters, rotation, the weave's pixels per yarn, on
    photo-like pairs the phone's warp and blur, and (``novel_light``) the novel-light error."""
    fitted, rig, truth, phone = result["params"], result["rig"], job["truth"], job["phone"]
    row = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in parameter_errors(fitted, truth).items()}
    row["rotation_error_deg"] = round(abs(rig.sample_rotation_deg - job["rig"].sample_rotation_deg), 3)
    row["family_true"] = family(truth.pattern)
    row["pixels_per_yarn"] = round(pixels_per_yarn(truth, job["rig"]), 2)
    if phone is not None:
        row.update(warp_errors(result["warp"], phone, rig.film_size))
        row.update(blur_errors(rig.camera_blur_px, phone))
    row.update(variation_errors(fitted, truth))
    row["forward_error"] = round(forward_error(fitted, truth), 4)
    if novel_light:
        gains = (phone.gains(0), phone.gains(1)) if phone else None
        errors = novel_light_error(fitted, truth, gains=gains)
        row["novel_colour_l1"] = round(errors["colour_l1"], 4)
        row["novel_spectrum_corr"] = round(errors["spectrum_corr"], 4)
    return row


def _format(row: dict) -> str:
    if "error" in row:
        return f"{row['kind']:9s} {row['name']:16s} ERROR {row['error']}"
    text = (f"{row['kind']:9s} {row['name']:16s} {row['pattern']:7s} "
            f"tiles {row['tiles'][0]:6.1f} {row['tiles'][1]:6.1f}"
            f"  FLIP {row['flip_R']:.3f}/{row['flip_T']:.3f}  colour {row['colour_l1_R']:.4f}/{row['colour_l1_T']:.4f}"
            f"  spectrum {row['spectrum_corr_R']:.3f}/{row['spectrum_corr_T']:.3f}"
            f"  blur {row['camera_blur_px']:.2f}  rot {row['rotation_deg']:+.2f}  skew {row['skew_deg']:+.2f}"
            f"  {row['wall_s']:5.1f} s  {row['peak_mb']:.0f} MB  {row['steps']}/{row['iterations']} steps")
    if "roughness_mae" in row:
        text += (f"  pattern {'ok' if row['pattern_ok'] else 'WRONG'}{'' if row['family_ok'] else ' (family WRONG)'}"
                 f"  roughness {row['roughness_mae']:.3f}  thickness {row['thickness_mae']:.3f}"
                 f"  tiles {row['tiles_error_pct']:.2f}%  rot err {row['rotation_error_deg']:.2f}")
    if "novel_colour_l1" in row:
        text += f"  novel light: colour {row['novel_colour_l1']:.4f} spectrum {row['novel_spectrum_corr']:.3f}"
    text += f"  spacing warp {row['warp_rms_px']:.2f} px"
    if "warp_error_px" in row:
        text += f" (true {row['warp_true_rms_px']:.2f}, off by {row['warp_error_px']:.2f})"
    if "blur_error_px" in row:
        text += f"  blur vs the phone's {row['phone_blur_px']:.2f}: {row['blur_error_px']:+.2f} px"
    if row.get("at_bounds"):
        text += f"  at bounds: {', '.join(row['at_bounds'])}"
    return text


def _mean(values) -> float | None:
    values = list(values)
    return round(statistics.fmean(values), 4) if values else None


def summarise(rows: list[dict]) -> dict:
    done = [r for r in rows if "error" not in r]
    out = {"pairs": len(rows), "failed": len(rows) - len(done), "wall_s_mean": _mean(r["wall_s"] for r in rows),
           "wall_s_max": max((r["wall_s"] for r in rows), default=None)}
    for kind in KINDS:
        group = [r for r in done if r["kind"] == kind]
        if group:
            out[kind] = _kind_summary(group)
    out["targets"] = TARGETS
    return out


def _kind_summary(group: list[dict]) -> dict:
    """The means over one kind's fitted pairs; the truth's figures where the pairs have one."""
    section = {f"{m}_{t}": _mean(r[f"{m}_{t}"] for r in group) for m in ("flip", "colour_l1", "spectrum_corr")
               for t in "RT"}
    section.update(_means_where(group, "texture_gap_db_R", texture_gap_db_R=itemgetter("texture_gap_db_R"),
                                texture_gap_db_T=itemgetter("texture_gap_db_T")))
    section["pairs"] = len(group)
    section["at_bounds_pairs"] = sum(bool(r.get("at_bounds")) for r in group)
    truthful = [r for r in group if "pattern_ok" in r]
    if truthful:
        section.update(_truth_figures(truthful))
        section["rotation_error_deg_mean"] = _mean(r["rotation_error_deg"] for r in truthful)
        resolved = [r for r in truthful if r.get("pixels_per_yarn", 0.0) >= RESOLVED_PX_PER_YARN]
        section["resolved"] = {"pairs": len(resolved), **(_truth_figures(resolved) if resolved else {})}
        section.update(_partial_figures(truthful))
    section["warp_rms_px"] = _mean(r.get("warp_rms_px", 0.0) for r in group)
    return section


def _partial_figures(rows: list[dict]) -> dict:
    """The means of the figures only some rows have: the novel-light error (not with
    ``--no-novel-light``), the warp and the blur against the phone's (photo-like pairs)."""
    return {**_means_where(rows, "novel_colour_l1", novel_colour_l1=itemgetter("novel_colour_l1"),
                           novel_spectrum_corr=itemgetter("novel_spectrum_corr")),
            **_means_where(rows, "warp_error_px", warp_true_rms_px=itemgetter("warp_true_rms_px"),
                           warp_error_px=itemgetter("warp_error_px")),
            **_means_where(rows, "blur_error_px", blur_error_px_mean=itemgetter("blur_error_px"),
                           blur_error_px_mean_abs=lambda r: abs(r["blur_error_px"]))}


def _means_where(rows: list[dict], key: str, **figures) -> dict:
    """The mean of each figure (name=its value in a row) over the rows that have ``key``; none without any."""
    having = [r for r in rows if key in r]
    return {name: _mean(value(r) for r in having) for name, value in figures.items()} if having else {}


def _truth_figures(rows: list[dict]) -> dict:
    """Pattern and family accuracy, roughness and thickness MAE, tiles error (max and mean) of rows
    with a truth."""
    return {"pattern_accuracy": _mean(r["pattern_ok"] for r in rows),
            "family_accuracy": _mean(r["family_ok"] for r in rows),
            "roughness_mae": _mean(r["roughness_mae"] for r in rows),
            "thickness_mae": _mean(r["thickness_mae"] for r in rows),
            "tiles_error_pct_max": round(max(r["tiles_error_pct"] for r in rows), 3),
            "tiles_error_pct_mean": _mean(r["tiles_error_pct"] for r in rows),
            **_optional_mean("blur_abs_error_px", [abs(r["blur_error_px"]) for r in rows if "blur_error_px" in r]),
            **_optional_mean("variation_rms_abs_error", [abs(r["variation_rms_error"]) for r in rows
                                                         if r.get("variation_rms_error") is not None]),
            **_optional_mean("forward_error", [r["forward_error"] for r in rows if "forward_error" in r])}


def _optional_mean(key: str, values: list[float]) -> dict:
    """{key: the mean of ``values``} where there are any, else nothing."""
    return {key: _mean(values)} if values else {}


def _format_summary(s: dict) -> str:
    lines = [f"summary: {s['pairs']} pairs, {s['failed']} failed, wall time mean {s['wall_s_mean']} s, "
             f"max {s['wall_s_max']} s (targets: mean <= {TARGETS['wall_s']['mean_max']:.0f} s, "
             f"max <= {TARGETS['wall_s']['max_max']:.0f} s)"]
    for kind in KINDS:
        k = s.get(kind)
        if not k:
            continue
        line = (f"  {kind} ({k['pairs']}): FLIP {k['flip_R']}/{k['flip_T']}, colour L1 {k['colour_l1_R']}/"
                f"{k['colour_l1_T']}, spectrum {k['spectrum_corr_R']}/{k['spectrum_corr_T']}, "
                f"pairs with a parameter at a bound {k['at_bounds_pairs']}")
        if "texture_gap_db_R" in k:
            line += f", texture gap {k['texture_gap_db_R']}/{k['texture_gap_db_T']} dB"
        if "pattern_accuracy" in k:
            line += (f"; pattern {k['pattern_accuracy']:.0%} (family {k['family_accuracy']:.0%}), "
                     f"roughness MAE {k['roughness_mae']}, thickness MAE {k['thickness_mae']}, tiles error "
                     f"max {k['tiles_error_pct_max']}% mean {k['tiles_error_pct_mean']}%, "
                     f"rotation error {k['rotation_error_deg_mean']} deg")
            r = k["resolved"]
            line += (f"; of them {r['pairs']} with >= {RESOLVED_PX_PER_YARN:g} px per yarn"
                     + (f": pattern {r['pattern_accuracy']:.0%}, tiles error max {r['tiles_error_pct_max']}%"
                        if r["pairs"] else ""))
        if "variation_rms_abs_error" in k:
            line += f"; variation amplitude error (mean size, relative) {k['variation_rms_abs_error']}"
        if "forward_error" in k:
            line += f"; forward scattering error {k['forward_error']}"
        if "novel_colour_l1" in k:
            line += f"; novel light colour L1 {k['novel_colour_l1']}, spectrum {k['novel_spectrum_corr']}"
        line += f"; spacing warp {k['warp_rms_px']} px"
        if "warp_error_px" in k:
            line += f" (true {k['warp_true_rms_px']}, off by {k['warp_error_px']})"
        if "blur_error_px_mean" in k:
            line += (f"; camera blur minus the phone's: mean {k['blur_error_px_mean']} px, "
                     f"mean size {k['blur_error_px_mean_abs']} px")
        lines.append(line)
    lines.append(f"  targets: {json.dumps(TARGETS)}")
    return "\n".join(lines)

