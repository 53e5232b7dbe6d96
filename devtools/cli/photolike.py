"""``python -m devtools photolike --out DIR --count N [--seed S] [--moved] [--varied] [--forward]
[--without EFFECT ...]``: photo-like synthetic pairs with ground truth for the fit benchmark
(:mod:`devtools.bench.photolike`)."""
from __future__ import annotations

from backend.app.cli.common import positive_int

from ..bench.photolike import generate
from ..phone import EFFECTS


def run_photolike(args) -> int:
    generate(args.out, args.count, args.seed, moved=args.moved, without=tuple(args.without), varied=args.varied,
             forward=args.forward)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("photolike", help="photo-like synthetic pairs with ground truth (fit benchmark)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--count", type=positive_int, required=True, help="pairs (patterns in turn)")
    p.add_argument("--seed", type=int, default=0, help="set seed (another seed: another set)")
    p.add_argument("--moved", action="store_true",
                   help="the phone moves between the shots: the reflection photo shows the lattice 1-1.1 times as "
                        "dense and turned by up to 2 degrees (the transmission photos and the truth as without)")
    p.add_argument("--varied", action="store_true",
                   help="the samples' yarns vary (width, thickness, spacing, brightness, slubs, drawn from the "
                        "declared priors; the other draws as without)")
    p.add_argument("--forward", action="store_true",
                   help="the samples' yarns scatter forward (forward_scattering drawn from its declared prior; the "
                        "other draws as without)")
    p.add_argument("--without", nargs="+", choices=EFFECTS, default=[], metavar="EFFECT",
                   help=f"a phone without these effects ({', '.join(EFFECTS)}): the same set otherwise, so that "
                        "a fit benchmark of both tells what they cost")
    p.set_defaults(run=run_photolike)
