"""``python -m devtools dataset``: synthetic training pairs for the initialisation network
(:mod:`devtools.dataset`)."""
from __future__ import annotations

import sys

from backend.app.cli.common import positive_int
from backend.app.environment import renderer_compiles
from backend.core import priors

from ..dataset import DatasetSettings, generate


def run_dataset(args) -> int:
    settings = DatasetSettings(size=args.size, spp=args.spp, seed=args.seed, photo_scale=args.photo_scale)
    try:
        generate(args.out, args.per_pattern, args.workers, settings,
                 compile={"auto": renderer_compiles(), "on": True, "off": False}[args.compile],
                 patterns=tuple(args.patterns))
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("dataset", help="render synthetic R/T pairs and network features from the dataset priors")
    p.add_argument("--out", required=True, help="dataset folder (created; an existing one is completed)")
    p.add_argument("--per-pattern", type=positive_int, required=True, help="items per weave preset")
    p.add_argument("--workers", type=positive_int, default=1, help="processes (one core each)")
    p.add_argument("--seed", type=int, default=0, help="dataset seed (use another for a held-out set)")
    p.add_argument("--size", type=positive_int, default=DatasetSettings.size, help="render size (default 256)")
    p.add_argument("--spp", type=positive_int, default=DatasetSettings.spp, help="samples per pixel (default 16)")
    p.add_argument("--photo-scale", type=int, default=0, metavar="K",
                   help="photo-like items: the sample turned and photographed by a phone at K phone pixels per "
                        "film pixel (default 0: clean renders)")
    p.add_argument("--patterns", nargs="+", default=list(priors.PATTERNS), choices=priors.PATTERNS,
                   help="presets to draw (default: all)")
    p.add_argument("--compile", choices=("auto", "on", "off"), default="auto",
                   help="torch.compile the renderer (auto: where a C++ compiler is found)")
    p.set_defaults(run=run_dataset)
