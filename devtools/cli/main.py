"""Command line: ``python -m devtools <command> ...`` (developers only; not in the extension).

    dataset --out DIR --per-pattern N [...]              (devtools/cli/dataset.py)
    train DATASET --out WEIGHTS [...]                    (devtools/cli/train.py)
    evaluate-init [--heldout DIR] [--golden DIR] [...]   (devtools/cli/evaluate_init.py)
    photolike --out DIR --count N [--seed S] [--moved]   (devtools/cli/photolike.py)
    bench render|fit|placement|batch|fit-speed [...]     (devtools/cli/bench.py)
    signatures                                           (devtools/cli/signatures.py)
    fuzz [--photos N] [--options N] [--seed S]           (devtools/cli/fuzz.py)
    gpu-check [--out DIR] [--budget-s S] [--device D]    (devtools/cli/gpu_check.py)

Bad input ends as the backend's commands do: exit code 2 and one line naming the file and the problem.
"""
from __future__ import annotations

import argparse
import sys

from backend.app.cli.main import run

from . import bench, dataset, evaluate_init, fuzz, gpu_check, photolike, signatures, train


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m devtools", description="Woven fabric capture: developer tools")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in (dataset, train, evaluate_init, photolike, bench, signatures, fuzz, gpu_check):
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    args.argv = argv  # the command line, for the results ledger
    return run(args)
