"""Placement benchmark: ``python -m devtools bench placement --synthetic DIR ... [--cases ...] [--json]``.

The fit's first stage alone, run as the fit runs it: the photos loaded at the default rig's film
size, then :func:`backend.texture.placement.place`. For each golden or photo-like pair (folders
with ``cases.json``, as for ``bench fit``): the sample's rotation and skew found against the true
ones, the worst-axis tiles error (%) of the true pattern's best lattice candidate, and whether the
best-scoring candidate is of the true pattern (scores compare within a pattern only, so this is a
hint, not the fit's choice: the fit's trial fits choose, :mod:`backend.fit.search`).

The placement and the tiles stay fixed through the fit, so these errors are the fit's; a pair takes
seconds where ``bench fit`` takes minutes, so this is the loop for work on the lattice and the
placement. It prints one line per pair and a summary against the fit issue's tiles target; the
summary names the placement's gates (:mod:`backend.texture.gates`) it ran with, as the ledger keeps
it (as text, the gates' table comes first). Measure a change on a photo-like seed no decision was tuned on.
"""
from __future__ import annotations

import json
import statistics
import time

import torch

from backend.core.priors import FIT_PATTERNS
from backend.core.rig import DEFAULT_RIG
from backend.image.photos import load_pair
from backend.texture import gates, placement
from backend.texture.spectra import Spectra

from .fit import TARGETS, pair_jobs, tiles_error_pct
from .ledger import NOT_RECORDED, Ledger

ROTATION_ERROR_DEG = 0.5  # the summary counts the pairs placed further off than this


def place(job: dict) -> dict:
    """One pair's placement and candidates against its truth (a :func:`devtools.bench.fit.pair_jobs` job)."""
    started = time.perf_counter()
    photos = load_pair(job["reflection"], job["transmission"], size=DEFAULT_RIG.film_size)
    spectra = Spectra.of([photos.reflection, photos.transmission])
    (rotation, skew), found = placement.place(spectra, DEFAULT_RIG, FIT_PATTERNS, None,
                                                workers=torch.get_num_threads())
    truth, rig = job["truth"], job["rig"]
    own = [c for c in found if c.pattern == truth.pattern]  # best first within a pattern
    return {"kind": job["kind"], "name": job["name"], "rotation_deg": rotation, "skew_deg": skew,
            "true_rotation_deg": round(rig.sample_rotation_deg, 3), "true_skew_deg": round(rig.sample_skew_deg, 3),
            "rotation_error_deg": round(abs(rotation - rig.sample_rotation_deg), 3),
            "tiles_error_pct": round(tiles_error_pct(own[0].tiles, truth.tiles), 2) if own else None,
            "best_scored_is_true": max(found, key=lambda c: c.score).pattern == truth.pattern if found else False,
            "candidates": [[c.pattern, [round(t, 2) for t in c.tiles]] for c in found],
            "seconds": round(time.perf_counter() - started, 1)}


def summary(rows: list[dict]) -> dict:
    """Means, medians and counts over the pairs (a pair without a candidate of its pattern counts as
    off by more than the target)."""
    rotation = [r["rotation_error_deg"] for r in rows]
    tiles = [r["tiles_error_pct"] for r in rows if r["tiles_error_pct"] is not None]
    limit = TARGETS["photolike"]["tiles_error_pct_max"]
    return {"summary": "placement", "pairs": len(rows),
            "rotation_error_mean_deg": round(statistics.fmean(rotation), 3) if rows else None,
            "rotation_error_median_deg": round(statistics.median(rotation), 3) if rows else None,
            f"rotation_error_over_{ROTATION_ERROR_DEG}_deg": sum(e > ROTATION_ERROR_DEG for e in rotation),
            "tiles_error_mean_pct": round(statistics.fmean(tiles), 2) if tiles else None,
            "tiles_error_median_pct": round(statistics.median(tiles), 2) if tiles else None,
            f"tiles_error_over_{limit:g}_pct": sum(e > limit for e in tiles) + (len(rows) - len(tiles)),
            "seconds": round(sum(r["seconds"] for r in rows), 1)}


def bench_placement(synthetic: list[str], names: list[str] | None, as_json: bool,
                    ledger: Ledger = NOT_RECORDED) -> int:
    table = gates.table()
    if not as_json:
        print("gates:", *(f"  {name} = {value}: {guards}" for name, value, guards in table), sep="\n", flush=True)
    rows = []
    for job in pair_jobs(synthetic, [], names):
        row = place(job)
        rows.append(row)
        if as_json:
            print(json.dumps(row), flush=True)
        else:
            tiles = "none of its pattern" if row["tiles_error_pct"] is None else f"{row['tiles_error_pct']:.2f} %"
            print(f"{row['kind']} {row['name']}: rotation {row['rotation_deg']:+.2f} (true "
                  f"{row['true_rotation_deg']:+.2f}, off {row['rotation_error_deg']:.2f}) skew {row['skew_deg']:+.2f}; "
                  f"tiles of the true pattern off {tiles}; {row['seconds']:.1f} s", flush=True)
        ledger.row(row)
    result = summary(rows)
    measured_with = {**result, "gates": {name: value for name, value, _ in table}}
    # as JSON, the summary carries the gates it was measured with, as the ledger keeps it
    ledger.print_summary(measured_with, as_json, lambda _: "  ".join(f"{k}={v}" for k, v in result.items()))
    return 0
