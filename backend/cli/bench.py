"""``python -m backend bench render|fit``: performance figures (never timed tests).

    bench render [--json] [--size N] [--spp N] [--runs N] [--device D]
    bench fit [--synthetic DIR ...] [--real DIR ...] [--cases ...] [--iterations N] [--keep DIR] [--json]
        [--no-novel-light] [--fit-args "EXTRA FIT ARGUMENTS"]
"""
from __future__ import annotations

import shlex

from ..bench.fit import bench_fit
from ..bench.render import bench_render
from .common import InputError, device, positive_int


def run_bench(args) -> int:
    if args.what == "fit":
        synthetic = args.synthetic + args.golden
        if not synthetic and not args.real:
            raise InputError("bench fit: give --synthetic DIR (golden or photo-like) and/or --real DIR")
        extra = (["--iterations", str(args.iterations)] if args.iterations else []) + shlex.split(args.fit_args)
        return bench_fit(synthetic, args.real, args.cases, extra, args.json, keep=args.keep,
                         novel_light=not args.no_novel_light)
    return bench_render(size=args.size, spp=args.spp, runs=args.runs, as_json=args.json, device=device(args.device))


def add_parser(sub) -> None:
    p = sub.add_parser("bench", help="print performance figures")
    p.add_argument("what", choices=["render", "fit"])
    p.add_argument("--json", action="store_true", help="JSON lines")
    p.add_argument("--synthetic", nargs="*", default=[],
                   help="fit: folders with cases.json and <name>_R/_T images (golden renders, photo-like sets)")
    p.add_argument("--golden", nargs="*", default=[], help="fit: the same as --synthetic")
    p.add_argument("--real", nargs="*", default=[], help="fit: folders of <name>_R.* / <name>_T.* photo pairs")
    p.add_argument("--keep", help="fit: keep every fit's results in this folder (<kind>_<name>/)")
    p.add_argument("--no-novel-light", action="store_true", help="fit: skip the novel-light renders")
    p.add_argument("--fit-args", default="", help='fit: extra arguments of every fit, one string ("--size 512")')
    p.add_argument("--cases", nargs="*", help="fit: only these names")
    p.add_argument("--iterations", type=int, help="fit: iterations per pair (default: the fit's default)")
    p.add_argument("--size", type=positive_int, default=512)
    p.add_argument("--spp", type=positive_int, default=4)
    p.add_argument("--runs", type=positive_int, default=5)
    p.add_argument("--device", default="cpu")
    p.set_defaults(run=run_bench)
