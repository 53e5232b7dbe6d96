"""``python -m devtools bench render|fit|placement|fit-speed|addon-fit|batch``: performance figures (never timed tests).

    bench render [--json] [--size N] [--spp N] [--runs N] [--device D]
    bench fit [--synthetic DIR ...] [--real DIR ...] [--cases ...] [--iterations N] [--keep DIR] [--json]
        [--no-novel-light] [--device D] [--fit-args "EXTRA FIT ARGUMENTS"]
    bench placement --synthetic DIR ... [--cases ...] [--json]     (the fit's placement and lattice only)
    bench fit-speed [--pair REFLECTION TRANSMISSION] [--rounds N] [--iterations N] [--fit-size N] [--json]
    bench addon-fit [--pair REFLECTION TRANSMISSION] [--rounds N] [--iterations N] [--fit-size N] [--json]
        (the add-on's Fit against the fit command: needs the bpy module, the blender extra)
    bench batch [--pairs N] [--iterations N] [--size N] [--film N] [--cpus-per-fit C] [--workers W]
        [--sequential-threads T] [--subprocess] [--rounds R] [--json]      (needs Ray, the cluster extra)

Each appends what it prints to the results ledger, ``devtools/bench/results/<bench>.jsonl``
(:mod:`devtools.bench.ledger`); ``--no-record`` does not.
"""
from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from backend.app.batch.scheduler import BatchError
from backend.app.cli.common import InputError, device, positive_int
from backend.app.folder import FolderFitOptions

from ..bench.addon_fit import bench_addon_fit
from ..bench.batch import bench_batch
from ..bench.fit import bench_fit
from ..bench.fit_speed import bench_fit_speed
from ..bench.ledger import add_record_option, open_ledger
from ..bench.placement import bench_placement
from ..bench.render import bench_render


def run_bench(args) -> int:
    return {"render": _render, "fit": _fit, "placement": _placement, "fit-speed": _fit_speed,
            "addon-fit": _addon_fit, "batch": _batch, "profile": _profile}[args.what](args)


def _fit(args) -> int:
    synthetic = args.synthetic + args.golden
    if not synthetic and not args.real:
        raise InputError("bench fit: give --synthetic DIR (golden or photo-like) and/or --real DIR")
    extra = _iterations(args) + shlex.split(args.fit_args) + _device(args)
    ledger = open_ledger(args, "fit", synthetic + args.real, fit_device(extra))
    return bench_fit(synthetic, args.real, args.cases, extra, args.json, keep=args.keep,
                     novel_light=not args.no_novel_light, ledger=ledger)


def _placement(args) -> int:
    synthetic = args.synthetic + args.golden
    if not synthetic:
        raise InputError("bench placement: give --synthetic DIR (golden or photo-like: the truth is needed)")
    return bench_placement(synthetic, args.cases, args.json, ledger=open_ledger(args, "placement", synthetic))


def _fit_speed(args) -> int:
    extra = _iterations(args) + (["--size", str(args.fit_size)] if args.fit_size else [])
    reflection, transmission = args.pair or (None, None)
    ledger = open_ledger(args, "fit-speed", _pair_folders(args))
    return bench_fit_speed(reflection, transmission, args.rounds or 2, extra, args.json, ledger=ledger)


def _pair_folders(args) -> list[str]:
    """The folders of ``--pair``'s photos, once each (the ledger's data sets)."""
    return list(dict.fromkeys(str(Path(p).parent) for p in args.pair or ()))


def _addon_fit(args) -> int:
    reflection, transmission = args.pair or (None, None)
    ledger = open_ledger(args, "addon-fit", _pair_folders(args))
    return bench_addon_fit(reflection, transmission, args.rounds or 2, args.iterations or 0, args.fit_size or 0,
                           args.json, ledger=ledger)


def _batch(args) -> int:
    try:
        return bench_batch(args.pairs, args.iterations or 20, args.size or 64, args.film, args.cpus_per_fit,
                           args.workers, args.sequential_threads, args.subprocess, args.rounds or 1, args.json,
                           ledger=open_ledger(args, "batch"))
    except BatchError as exc:  # no Ray
        raise InputError(f"bench batch: {exc}") from None


def _profile(args) -> int:
    from ..bench.profile import bench_profile
    extra = _iterations(args) + shlex.split(args.fit_args) + _device(args)
    ledger = open_ledger(args, "profile", _pair_folders(args), fit_device(extra))
    return bench_profile(tuple(args.pair) if args.pair else None, extra, args.top, args.json, args.operators,
                         ledger=ledger)


def _render(args) -> int:
    chosen = device(args.device or "cpu")
    return bench_render(size=args.size or 512, spp=args.spp, runs=args.runs, as_json=args.json, device=chosen,
                        ledger=open_ledger(args, "render", device=str(chosen)))


def _iterations(args) -> list[str]:
    """The fit's ``--iterations`` where the bench was given one."""
    return ["--iterations", str(args.iterations)] if args.iterations else []


def _device(args) -> list[str]:
    """The fits' ``--device`` where the bench was given one (fit, profile); ``--fit-args`` may not
    name a device too."""
    if not args.device:
        return []
    if "--device" in shlex.split(args.fit_args):
        raise InputError("bench: --device and --fit-args \"--device ...\": give the device once")
    device(args.device)  # refused here, not in every fit, where there is no such device
    return ["--device", args.device]


def fit_device(fit_args: list[str]) -> str:
    """The device the benchmark's fits run on: their ``--device``, else the fit's default."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--device", default=FolderFitOptions.device)
    return parser.parse_known_args(fit_args)[0].device


def add_parser(sub) -> None:
    p = sub.add_parser("bench", help="print performance figures")
    p.add_argument("what", choices=["render", "fit", "placement", "fit-speed", "addon-fit", "batch", "profile"])
    p.add_argument("--json", action="store_true", help="JSON lines")
    p.add_argument("--synthetic", nargs="*", default=[],
                   help="fit, placement: folders with cases.json and <name>_R/_T images (golden renders, "
                        "photo-like sets)")
    p.add_argument("--golden", nargs="*", default=[], help="fit, placement: the same as --synthetic")
    p.add_argument("--real", nargs="*", default=[], help="fit: folders of <name>_R.* / <name>_T.* photo pairs")
    p.add_argument("--keep", help="fit: keep every fit's results in this folder (<kind>_<name>/)")
    p.add_argument("--no-novel-light", action="store_true", help="fit: skip the novel-light renders")
    p.add_argument("--fit-args", default="", help='fit, profile: extra arguments of every fit, one string '
                                                  '("--size 512")')
    p.add_argument("--cases", nargs="*", help="fit, placement: only these names")
    p.add_argument("--iterations", type=positive_int,
                   help="iterations per fit (fit, fit-speed, addon-fit: the fit's default; batch: 20)")
    p.add_argument("--pair", nargs=2, metavar=("REFLECTION", "TRANSMISSION"),
                   help="fit-speed, addon-fit, profile: the photo pair (default: the bundled example)")
    p.add_argument("--top", type=positive_int, default=12, help="profile: the top operators and functions shown")
    p.add_argument("--operators", action="store_true", help="profile: also torch's operators, forward and backward "
                                                            "(keeps every event in memory: a short fit)")
    p.add_argument("--fit-size", type=positive_int,
                   help="fit-speed, addon-fit: the fit's --size (default: the fit's default)")
    p.add_argument("--rounds", type=positive_int,
                   help="fit-speed: compiled + eager rounds, addon-fit: add-on + command-line rounds (default 2); "
                        "batch: how often the ways take turns "
                        "(default 1)")
    p.add_argument("--size", type=positive_int, help="render: image size (default 512); batch: the fits' working "
                                                     "size (default 64)")
    p.add_argument("--spp", type=positive_int, default=4)
    p.add_argument("--runs", type=positive_int, default=5)
    p.add_argument("--device", help="render: the device rendered on (default cpu); fit, profile: the fits' --device")
    p.add_argument("--pairs", type=positive_int, default=4, help="batch: synthetic pairs (default 4)")
    p.add_argument("--film", type=positive_int, default=128, help="batch: the pairs' film size (default 128)")
    p.add_argument("--cpus-per-fit", type=positive_int, default=1, help="batch: threads of each Ray fit (default 1)")
    p.add_argument("--workers", type=positive_int, help="batch: Ray fits at once (default: cores / cpus-per-fit)")
    p.add_argument("--sequential-threads", type=positive_int, help="batch: threads of each sequential fit "
                                                                   "(default: every core)")
    p.add_argument("--subprocess", action="store_true", help="batch: also one python -m backend fit per pair")
    add_record_option(p)
    p.set_defaults(run=run_bench)
