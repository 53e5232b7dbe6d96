"""``python -m backend batch``: fit every photo pair of a folder on Ray, on this machine or a cluster.

    batch PHOTOS/ --out DIR [--workers N] [--cpus-per-fit K] [--gpus-per-fit G] [--memory-per-fit GB]
        [--ray-address ADDR] [--resume] [--timeout S] [--json-progress] [fit options]

Every ``<name>_R.* / <name>_T.*`` pair of PHOTOS (the Blender batch's rule, backend/core/pairs.py)
is fitted as ``fit`` fits it, with the same options (those backend/core/fit_options.py marks
``batch``: every pair gets them; the device follows ``--gpus-per-fit``), into ``DIR/<name>/``; ``DIR/catalogue.json``
and ``catalogue.csv`` list every pair (backend/app/batch/catalogue.py) and ``DIR/logs/<name>.log`` keeps
what each fit said. Without ``--ray-address`` a local Ray starts on this machine. ``--resume``
keeps the complete results of an earlier run and fits the rest; without it a DIR that holds
results is refused. Progress (pairs done, running, failed, time left) on the terminal, or as JSON
lines with ``--json-progress`` (backend/core/protocol.py).

Exit code: the number of failed pairs (capped at 125); 2 when the batch cannot start (no such
folder, no pairs, DIR holds results without --resume, Ray missing); 130 after Ctrl+C or SIGTERM
(finished pairs are kept; ``--resume`` fits the rest). The work is in backend/app/batch/.
"""
from __future__ import annotations

import argparse
import signal
from pathlib import Path

from ...core.fit_options import BATCH_OPTIONS
from ...core.protocol import EXIT_CANCELLED, EXIT_INPUT, Reporter, failed_exit_code
from ...core.rig import CaptureRig, RigError
from ..batch import scheduler
from ..batch.output import OutputError
from ..batch.ray_executor import DEFAULT_MEMORY_GB, FitResources, connect
from .common import folder_name, positive_int
from .fit import add_fit_options


def run_batch(args) -> int:
    reporter = Reporter(json_lines=args.json_progress)
    reporter.start("batch", device="cuda" if args.gpus_per_fit else "cpu")
    try:
        rig_text = _rig_text(args.rig)
        plan = scheduler.plan(args.photos, args.out, args.resume)
    except (scheduler.BatchError, OutputError, RigError) as exc:
        reporter.error("input", str(exc))
        return EXIT_INPUT
    for folder in plan.moved:
        reporter.warning(f"an incomplete results folder was moved to {folder}; its pair is fitted again")
    counts = {s: sum(r["status"] == s for r in plan.rows.values()) for s in ("kept", "failed")}
    if not plan.to_fit:  # nothing for Ray to do: the catalogue is still brought up to date
        reporter.info(f"nothing to fit: {counts['kept']} pair(s) kept from an earlier run, {counts['failed']} unusable")
        return _report(scheduler.run(plan, _options(args, 1, rig_text), None, reporter), plan, reporter)
    try:
        connection = connect(args.ray_address)
    except scheduler.BatchError as exc:
        reporter.error("input", str(exc))
        return EXIT_INPUT
    executor = None
    try:
        fit = FitResources(args.cpus_per_fit, args.gpus_per_fit, args.memory_per_fit)
        problem = connection.check_fits_on_a_machine(fit)
        if problem and connection.local:
            reporter.error("input", problem)
            return EXIT_INPUT
        if problem:
            reporter.warning(problem + "; the fits wait until the cluster has such a machine")
        workers = args.workers or connection.capacity(fit)
        reporter.info(f"{connection.describe()}; {len(plan.to_fit)} pair(s) to fit ({workers} at a time, "
                      f"{fit.describe()}), {counts['kept']} kept from an earlier run, {counts['failed']} unusable")
        executor = connection.executor(fit)
        summary = _run_until_stopped(plan, _options(args, workers, rig_text), executor, reporter)
    finally:
        if executor is not None:
            executor.abandon()
        connection.close()
    return _report(summary, plan, reporter)


def _options(args, workers: int, rig_text: str | None) -> scheduler.BatchOptions:
    fit_options = _fit_options(args)
    return scheduler.BatchOptions(
        workers=workers, fit_options=fit_options, rig_text=rig_text, threads=max(1, round(args.cpus_per_fit)),
        timeout_s=args.timeout,
        settings={"fit": fit_options, "rig": args.rig, "workers": workers, "cpus_per_fit": args.cpus_per_fit,
                  "gpus_per_fit": args.gpus_per_fit, "memory_per_fit": args.memory_per_fit,
                  "ray_address": args.ray_address})


def _run_until_stopped(plan, options, executor, reporter) -> scheduler.BatchSummary:
    """Runs the batch; SIGINT/SIGTERM stop it (the finished pairs are kept)."""
    stop = {"requested": False}

    def request_stop(signum, frame):
        stop["requested"] = True

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        return scheduler.run(plan, options, executor, reporter, lambda: stop["requested"])
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _report(summary: scheduler.BatchSummary, plan: scheduler.BatchPlan, reporter: Reporter) -> int:
    done, kept, failed = summary.count("done"), summary.count("kept"), summary.failed
    reporter.info(f"{done + kept} of {len(summary.rows)} pair(s) done ({kept} kept from an earlier run), "
                  f"{failed} failed, {summary.count('cancelled')} cancelled: {summary.csv}")
    for name, row in sorted(summary.rows.items()):
        if row["status"] == "failed":
            reporter.info(f"  failed {name}: {row['reason']}")
    if summary.cancelled:
        reporter.error("cancelled", f"the batch was stopped; {done + kept} finished pair(s) are in {plan.out}, "
                                    "--resume fits the rest")
        return EXIT_CANCELLED
    reporter.result(out_dir=str(plan.out), catalogue=str(summary.catalogue), csv=str(summary.csv),
                    done=done + kept, failed=failed)
    return failed_exit_code(failed)


def _rig_text(path: str | None) -> str | None:
    """The rig file's text, checked here so that a bad rig fails before any fit."""
    if not path:
        return None
    CaptureRig.load(path)
    return Path(path).read_text()


def _fit_options(args) -> dict:
    options = {option.name: getattr(args, option.name) for option in BATCH_OPTIONS if option.name != "rig"}
    return {**options, "device": "cuda" if args.gpus_per_fit else "cpu"}


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be at least 0, got {text}")
    return value


def _positive(text: str) -> float:
    value = _non_negative(text)
    if value == 0:
        raise argparse.ArgumentTypeError("must be more than 0")
    return value


def add_parser(sub) -> None:
    p = sub.add_parser("batch", help="fit every <name>_R.* / <name>_T.* pair of a folder on Ray (local or cluster)")
    p.add_argument("photos", help="folder of photo pairs")
    p.add_argument("--out", type=folder_name, required=True,
                   help="results folder: DIR/<name>/ per pair, DIR/catalogue.json and .csv")
    p.add_argument("--workers", type=positive_int,
                   help="fits handed to Ray at once (default: as many as the machines' CPUs, GPUs and memory "
                        "allow; more only wait in Ray's queue)")
    p.add_argument("--cpus-per-fit", type=_positive, default=1.0,
                   help="CPUs Ray reserves for each fit, and its torch threads (default 1)")
    p.add_argument("--gpus-per-fit", type=_non_negative, default=0.0,
                   help="GPUs for each fit (fractions share one; default 0: fit on the CPU)")
    p.add_argument("--memory-per-fit", type=_non_negative, default=DEFAULT_MEMORY_GB, metavar="GB",
                   help=f"memory Ray reserves for each fit (default {DEFAULT_MEMORY_GB:g}: a default fit's peak; "
                        "0: none)")
    p.add_argument("--ray-address", help="a running Ray cluster (auto, HOST:6379 or ray://HOST:10001); "
                                         "default: start a local Ray on this machine")
    p.add_argument("--resume", action="store_true", help="keep the complete results in DIR and fit the rest")
    p.add_argument("--timeout", type=_positive, help="seconds one fit may take before it is stopped (and retried once)")
    p.add_argument("--json-progress", action="store_true", help="JSON lines on stdout (see backend/core/protocol.py)")
    add_fit_options(p, BATCH_OPTIONS)
    p.set_defaults(run=run_batch)
