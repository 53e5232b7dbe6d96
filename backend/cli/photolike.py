"""``python -m backend photolike --out DIR --count N [--seed S]``: photo-like synthetic pairs with
ground truth for the fit benchmark (:mod:`backend.bench.photolike`)."""
from __future__ import annotations

from ..bench.photolike import generate
from .common import positive_int


def run_photolike(args) -> int:
    generate(args.out, args.count, args.seed)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("photolike", help="photo-like synthetic pairs with ground truth (fit benchmark)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--count", type=positive_int, required=True, help="pairs (patterns in turn)")
    p.add_argument("--seed", type=int, default=0, help="set seed (another seed: another set)")
    p.set_defaults(run=run_photolike)
