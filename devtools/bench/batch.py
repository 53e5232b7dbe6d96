"""Batch throughput: ``python -m devtools bench batch [--pairs N] [--iterations K] [--size S] [--film F]
[--cpus-per-fit C] [--workers W] [--sequential-threads T] [--subprocess] [--rounds R] [--json]``.

Renders N small synthetic pairs (drawn from the patterns' priors in turn, fixed seeds) with a rig
whose film is F pixels, then fits all of them, in one run, in two or three ways:

1. ``sequential``: one after another in this process with T threads each (default: every core, as
   one ``fit`` uses them), through the batch's own driver with an engine that runs each job at
   once: a loop over the fit without starting Python again;
2. ``ray``: the batch command on a local Ray on this machine, W fits at once with C threads each
   (default: C = 1, W = cores / C). Ray's start is timed apart: a batch pays it once;
3. with ``--subprocess``: one ``python -m backend fit`` process per pair, one after another (what a
   shell loop over the command costs: each process imports torch and renders the lattice search's
   weave signatures again).

With ``--rounds R`` the ways take turns R times (a shared machine's load changes over minutes and
would otherwise favour whichever way ran in a quiet spell). Prints each round's wall time, pairs
per hour and ratio to the sequential way, then the totals. Ray runs its workers at nice 15 (its
default): on a machine busy with other work, ``RAY_worker_niceness=0`` makes the ways like for
like. The fits'
options are the same in all ways (``--size``, ``--iterations``, ``--output-spp 4``, ``--pattern
auto``); small fits make a fit's fixed costs (the signatures: five renders at 512 x 512 per
process) a larger share than in a real one.
"""
from __future__ import annotations

import dataclasses
import json
import os
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from backend.app.batch import scheduler
from backend.app.batch.job import FitJob, FitOutcome, run_fit_job
from backend.app.batch.ray_executor import FitResources, connect
from backend.core.params import FabricParams
from backend.core.priors import PATTERNS, sample
from backend.core.protocol import Reporter
from backend.core.rig import DEFAULT_RIG, CaptureRig
from backend.image.png import write_png
from backend.model.render import render_pair

from .ledger import NOT_RECORDED, Ledger

OUTPUT_SPP = 4


class InlineExecutor:
    """Runs each job in this process when it is submitted (the sequential way; one at a time)."""

    def __init__(self):
        self.outcomes: dict[int, FitOutcome] = {}

    def submit(self, job: FitJob) -> int:
        handle = len(self.outcomes)
        self.outcomes[handle] = run_fit_job(job)
        return handle

    def wait(self, handles: list, timeout: float) -> list:
        return list(handles)

    def outcome(self, handle) -> FitOutcome:
        return self.outcomes[handle]

    def cancel(self, handle) -> None:
        pass


def make_pairs(folder: Path, count: int, film: int, seed: int = 0) -> Path:
    """``count`` synthetic pairs ``bench<i>_R.png / _T.png`` and their ``rig.json``; returns the rig file."""
    rig = small_rig(film)
    folder.mkdir(parents=True, exist_ok=True)
    for index in range(count):
        params = small_fabric(sample(PATTERNS[index % len(PATTERNS)], random.Random(seed + index)), film)
        pair = render_pair(params, rig, size=film, spp=4, seed=seed + index)
        write_png(folder / f"bench{index:03d}_R.png", pair.reflection, bits=8)
        write_png(folder / f"bench{index:03d}_T.png", pair.transmission, bits=8)
    rig_path = folder.parent / "rig.json"
    rig_path.write_text(json.dumps(rig.to_dict(), indent=2) + "\n")
    return rig_path


def small_rig(film: int) -> CaptureRig:
    """The paper's rig on a ``film``-pixel film (the vignette and the glow scaled with it)."""
    scale = film / DEFAULT_RIG.film_size
    return dataclasses.replace(DEFAULT_RIG, film_size=film, vignette_sigma_px=DEFAULT_RIG.vignette_sigma_px * scale,
                               glow_sigma_px=DEFAULT_RIG.glow_sigma_px * scale)


def small_fabric(params: FabricParams, film: int) -> FabricParams:
    """``params`` with its tiles scaled to a ``film``-pixel film: the yarns keep their size in pixels
    (at 128 px the priors' 100-200 tiles would be finer than the pixels, and no photo shows a weave)."""
    scale = film / DEFAULT_RIG.film_size
    return dataclasses.replace(params, tiles=tuple(t * scale for t in params.tiles))


def bench_batch(pairs: int, iterations: int, size: int, film: int, cpus_per_fit: int, workers: int | None,
                sequential_threads: int | None, with_subprocess: bool, rounds: int, as_json: bool,
                ledger: Ledger = NOT_RECORDED) -> int:
    cores = os.cpu_count() or 1
    workers = workers or max(1, cores // cpus_per_fit)
    sequential_threads = sequential_threads or cores
    fit_options = {"iterations": iterations, "size": size, "output_spp": OUTPUT_SPP}
    rows = []
    with tempfile.TemporaryDirectory(prefix="batch-bench-") as tmp:
        tmp = Path(tmp)
        rig_path = make_pairs(tmp / "photos", pairs, film)
        rig_text = rig_path.read_text()

        def through_driver(way: str, executor, fits_at_once: int, threads: int, out: Path) -> dict:
            plan = scheduler.plan(tmp / "photos", out, resume=False)
            options = scheduler.BatchOptions(workers=fits_at_once, fit_options=fit_options, rig_text=rig_text,
                                             threads=threads)
            started = time.perf_counter()
            summary = scheduler.run(plan, options, executor, Reporter(json_lines=True, stream=open(os.devnull, "w")))
            return {"way": way, "fits_at_once": fits_at_once, "threads": threads,
                    "wall_s": time.perf_counter() - started, "failed": summary.failed}

        ray_started = time.perf_counter()
        connection = connect(None)
        ray_start_s = time.perf_counter() - ray_started
        try:
            for number in range(1, rounds + 1):  # the ways take turns: a machine's changing load hits them alike
                on_ray = connection.executor(FitResources(cpus_per_fit, 0.0, 0.0))
                ways = [through_driver("sequential", InlineExecutor(), 1, sequential_threads, tmp / f"seq{number}"),
                        through_driver("ray", on_ray, workers, cpus_per_fit, tmp / f"ray{number}")]
                if with_subprocess:
                    ways.append(_subprocess_loop(tmp, rig_path, fit_options, sequential_threads, tmp / f"sub{number}"))
                for row in ways:
                    row.update(round=number, pairs_per_hour=round(3600 * pairs / row["wall_s"], 1),
                               vs_sequential=round(ways[0]["wall_s"] / row["wall_s"], 2))
                    _show(row, as_json, ledger)
                rows += ways
        finally:
            connection.close()
    totals = {}
    for row in rows:
        total = totals.setdefault(row["way"], {"way": row["way"], "wall_s": 0.0, "failed": 0})
        total["wall_s"] += row["wall_s"]
        total["failed"] += row["failed"]
    for total in totals.values():
        total.update(pairs_per_hour=round(3600 * pairs * rounds / total["wall_s"], 1),
                     vs_sequential=round(totals["sequential"]["wall_s"] / total["wall_s"], 2))
    summary = {"pairs": pairs, "rounds": rounds, "film": film, "size": size, "iterations": iterations,
               "output_spp": OUTPUT_SPP, "cores": cores, "ray_start_s": round(ray_start_s, 1),
               "totals": list(totals.values())}
    ledger.print_summary(summary, as_json, _summary_text)
    return 1 if any(t["failed"] for t in totals.values()) else 0


def _show(row: dict, as_json: bool, ledger: Ledger) -> None:
    ledger.print_row({**row, "wall_s": round(row["wall_s"], 1)}, as_json, _row_text)


def _row_text(row: dict) -> str:
    return (f"round {row['round']}: {row['way']:<10} {row['fits_at_once']} at a time x {row['threads']} thread(s): "
            f"{row['wall_s']:7.1f} s  {row['pairs_per_hour']:7.1f} pairs/hour  {row['vs_sequential']:.2f}x "
            f"sequential  ({row['failed']} failed)")


def _summary_text(summary: dict) -> str:
    head = (f"bench batch: {summary['pairs']} pairs x {summary['rounds']} round(s), film {summary['film']} px, "
            f"--size {summary['size']} --iterations {summary['iterations']} --output-spp {summary['output_spp']}; "
            f"{summary['cores']} cores; Ray's start {summary['ray_start_s']:.1f} s (not counted)")
    return "\n".join([head] + [f"  {total['way']:<10} {total['wall_s']:8.1f} s  {total['pairs_per_hour']:7.1f} "
                               f"pairs/hour  {total['vs_sequential']:.2f}x sequential  ({total['failed']} failed)"
                               for total in summary["totals"]])


def _subprocess_loop(tmp: Path, rig_path: Path, fit_options: dict, threads: int, out: Path) -> dict:
    """One ``python -m backend fit`` per pair, one after another, ``threads`` threads each."""
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    flags = [f"--{key.replace('_', '-')}={value}" for key, value in fit_options.items()]
    photos = sorted((tmp / "photos").glob("*_R.png"))
    started, failed = time.perf_counter(), 0
    for reflection in photos:
        transmission = reflection.with_name(reflection.name.replace("_R.png", "_T.png"))
        done = subprocess.run([sys.executable, "-m", "backend", "fit", str(reflection), str(transmission),
                               "--out", str(out / reflection.stem), "--rig", str(rig_path), *flags],
                              env=env, capture_output=True, text=True)
        failed += done.returncode != 0
    return {"way": "subprocess", "fits_at_once": 1, "threads": threads, "wall_s": time.perf_counter() - started,
            "failed": failed}
