"""``python -m backend bench render|fit|fit-speed``: performance figures (never timed tests).

    bench render [--json] [--size N] [--spp N] [--runs N] [--device D]
    bench fit --golden DIR --real DIR [--cases ...] [--iterations N] [--json]
    bench fit-speed [--pair REFLECTION TRANSMISSION] [--rounds N] [--iterations N] [--fit-size N] [--json]
"""
from __future__ import annotations

from ..bench.fit import bench_fit
from ..bench.fit_speed import bench_fit_speed
from ..bench.render import bench_render
from .common import InputError, device, positive_int


def run_bench(args) -> int:
    extra = ["--iterations", str(args.iterations)] if args.iterations else []
    if args.what == "fit":
        if not args.golden and not args.real:
            raise InputError("bench fit: give --golden DIR and/or --real DIR")
        return bench_fit(args.golden, args.real, args.cases, extra, args.json)
    if args.what == "fit-speed":
        if args.fit_size:
            extra += ["--size", str(args.fit_size)]
        reflection, transmission = args.pair or (None, None)
        return bench_fit_speed(reflection, transmission, args.rounds, extra, args.json)
    return bench_render(size=args.size, spp=args.spp, runs=args.runs, as_json=args.json, device=device(args.device))


def add_parser(sub) -> None:
    p = sub.add_parser("bench", help="print performance figures")
    p.add_argument("what", choices=["render", "fit", "fit-speed"])
    p.add_argument("--json", action="store_true", help="JSON lines")
    p.add_argument("--golden", help="fit: a folder with cases.json and <name>_R/_T.png synthetic targets")
    p.add_argument("--real", help="fit: a folder of <name>_R.* / <name>_T.* photo pairs")
    p.add_argument("--cases", nargs="*", help="fit: only these names")
    p.add_argument("--iterations", type=positive_int,
                   help="fit, fit-speed: iterations per fit (default: the fit's default)")
    p.add_argument("--pair", nargs=2, metavar=("REFLECTION", "TRANSMISSION"),
                   help="fit-speed: the photo pair (default: the bundled example)")
    p.add_argument("--rounds", type=positive_int, default=2, help="fit-speed: compiled + eager rounds (default 2)")
    p.add_argument("--fit-size", type=positive_int, help="fit-speed: the fit's --size (default: the fit's default)")
    p.add_argument("--size", type=positive_int, default=512)
    p.add_argument("--spp", type=positive_int, default=4)
    p.add_argument("--runs", type=positive_int, default=5)
    p.add_argument("--device", default="cpu")
    p.set_defaults(run=run_bench)
