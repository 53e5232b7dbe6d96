"""Command line: ``python -m backend <command> ...`` (a stable contract other tools call).

    render PARAMS --out DIR [...]                (backend/app/cli/render.py)
    render-cases CASES.json --out DIR [...]      (backend/app/cli/render.py)
    fit REFLECTION TRANSMISSION --out DIR [...]  (backend/app/cli/fit.py)
    batch PHOTOS/ --out DIR [...]                (backend/app/cli/batch.py; needs Ray, the cluster extra)
    warm-compile                                 (backend/app/warm_compile.py; the fit command starts it)

The developer commands (dataset, train, photolike, bench, ...) are ``python -m devtools``'s.

Bad input (unreadable files, malformed or out-of-range parameters) ends with exit code 2 and a
one-line message naming the file and the problem, never a traceback.
"""
from __future__ import annotations

import argparse
import sys

from ...core.protocol import EXIT_CANCELLED, EXIT_INPUT
from .. import warm_compile
from . import batch, fit, render
from .common import INPUT_ERRORS, input_error_message


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m backend", description="Woven fabric capture backend")
    sub = parser.add_subparsers(dest="command", required=True)
    render.add_parsers(sub)
    fit.add_parser(sub)
    batch.add_parser(sub)
    warm_compile.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    return run(build_parser().parse_args(argv))


def run(args) -> int:
    """Run a parsed command line: bad input is one line on stderr and exit code 2, Ctrl+C exit code 130."""
    try:
        return args.run(args)
    except INPUT_ERRORS as exc:
        print(f"error: {input_error_message(exc)}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("cancelled", file=sys.stderr)
        return EXIT_CANCELLED
