"""Command line: ``python -m backend <command> ...`` (a stable contract other tools call).

    render PARAMS --out DIR [...]              (backend/cli/render.py)
    render-cases CASES.json --out DIR [...]    (backend/cli/render.py)
    fit REFLECTION TRANSMISSION --out DIR [...]  (backend/cli/fit.py)
    dataset --out DIR --per-pattern N [...]    (backend/cli/dataset.py)
    train DATASET --out WEIGHTS [...]          (backend/cli/train.py)
    evaluate-init [--heldout DIR] [--golden DIR] [...]  (backend/cli/evaluate_init.py)
    photolike --out DIR --count N [--seed S] [--moved]   (backend/cli/photolike.py)
    bench render|fit|batch [...]               (backend/cli/bench.py)
    batch PHOTOS/ --out DIR [...]              (backend/cli/batch.py; needs Ray, the cluster extra)

The development commands (dataset, train, evaluate-init, photolike, bench) and the batch are not part of
the Blender extension (``build.py`` leaves them out): where their modules are absent the commands are too.

Bad input (unreadable files, malformed or out-of-range parameters) ends with exit code 2 and a
one-line message naming the file and the problem, never a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from ..core.protocol import EXIT_CANCELLED, EXIT_INPUT
from . import fit, render
from .common import INPUT_ERRORS, input_error_message

# Modules of the development commands and the batch, in the order --help lists them.
DEVELOPMENT_COMMANDS = ("dataset", "train", "evaluate_init", "photolike", "bench", "batch")


def _development_modules():
    for name in DEVELOPMENT_COMMANDS:
        qualified = f"{__package__}.{name}"
        try:
            yield importlib.import_module(qualified)
        except ModuleNotFoundError as exc:
            if exc.name != qualified:  # a real missing dependency, not a command left out of the build
                raise


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m backend", description="Woven fabric capture backend")
    sub = parser.add_subparsers(dest="command", required=True)
    render.add_parsers(sub)
    fit.add_parser(sub)
    for module in _development_modules():
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except INPUT_ERRORS as exc:
        print(f"error: {input_error_message(exc)}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("cancelled", file=sys.stderr)
        return EXIT_CANCELLED
