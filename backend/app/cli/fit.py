"""``python -m backend fit``: photos in, parameters, re-renders, report and metrics out.

    fit REFLECTION TRANSMISSION --out DIR [--json-progress] [--stop-on-stdin] [options]
    fit --example --out DIR [options]     (renders a known fabric, then fits it)

The options (``--pattern``, ``--iterations``, ``--size``, ...) are declared once in
:mod:`backend.core.fit_options` (names, defaults, accepted values, help); argparse is built from
that declaration here, for ``fit`` and for ``batch``. The job itself, its outputs and its error
contract are :mod:`backend.app.folder`'s; this module adds the command line and the stop requests.
Progress goes to the terminal, or as JSON lines with --json-progress (:mod:`backend.core.protocol`).

Stopping: SIGINT/SIGTERM (a terminal), or with --stop-on-stdin a ``stop`` line on stdin or the end
of stdin (a caller that cannot send signals, e.g. on Windows, or that went away; the protocol's
control line). The best parameters so far go to DIR/params.partial.json (or, once params.json is
written, stay there) and the exit code is 130.
"""
from __future__ import annotations

import argparse
import dataclasses
import signal
import sys
import threading
from pathlib import Path

from ...core.fit_options import BOX, CHOICE, FIT_OPTIONS, FLAG, FitOption
from ...core.protocol import STOP_REQUEST, Reporter
from ..folder import FolderFitOptions, fit_reporting
from .common import folder_name


def watch_stop_requests(stream, stop: threading.Event) -> threading.Thread:
    """Sets ``stop`` when a ``stop`` line arrives on ``stream`` or the stream ends (the caller is gone)."""
    def watch():
        try:
            for line in stream:
                if line.strip() == STOP_REQUEST:
                    break
        except (OSError, ValueError):
            pass
        stop.set()

    thread = threading.Thread(target=watch, daemon=True, name="fit-stop-requests")
    thread.start()
    return thread


def run_fit(args) -> int:
    """The command: stop requests end the fit cleanly, every failure becomes one protocol error line."""
    reporter = Reporter(json_lines=args.json_progress)
    reporter.start("fit", device=args.device)
    stop = threading.Event()

    def request_stop(signum, frame):
        stop.set()

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    if args.stop_on_stdin:
        watch_stop_requests(sys.stdin, stop)
    options = FolderFitOptions(**{f.name: getattr(args, f.name) for f in dataclasses.fields(FolderFitOptions)})
    try:
        return fit_reporting(args.reflection, args.transmission, Path(args.out), options, reporter, stop.is_set,
                             example=args.example)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _argparse_type(option: FitOption):
    """argparse ``type`` of an option: its declared parse, whose complaint argparse prints after the flag."""
    def parse(text: str):
        try:
            return option.parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = option.name
    return parse


def add_fit_options(p, options: tuple[FitOption, ...]) -> None:
    """Adds ``options`` (of :data:`backend.core.fit_options.FIT_OPTIONS`) to the parser ``p``: the
    flag, default, accepted values, metavar and help each declares."""
    for option in options:
        help_text = option.help.replace("%", "%%")
        if option.kind == FLAG:
            p.add_argument(option.flag, action="store_true", help=help_text)
        elif option.kind == CHOICE:
            p.add_argument(option.flag, choices=option.choices, default=option.default, help=help_text)
        else:
            p.add_argument(option.flag, type=_argparse_type(option), default=option.default, metavar=option.metavar,
                           nargs=4 if option.kind == BOX else None, help=help_text)


def add_parser(sub) -> None:
    p = sub.add_parser("fit", help="fit fabric parameters to a reflection/transmission photo pair")
    p.add_argument("reflection", nargs="?", help="photo lit from the front")
    p.add_argument("transmission", nargs="?", help="photo lit from behind")
    p.add_argument("--out", type=folder_name, required=True, help="output folder (a new one, or --overwrite)")
    p.add_argument("--example", action="store_true", help="render the bundled example fabric and fit it")
    add_fit_options(p, FIT_OPTIONS)
    p.add_argument("--json-progress", action="store_true", help="JSON lines on stdout (see backend/core/protocol.py)")
    p.add_argument("--stop-on-stdin", action="store_true",
                   help="stop (keeping the best parameters) on a 'stop' line on stdin or when stdin ends: for callers "
                        "that cannot send signals")
    p.set_defaults(run=run_fit)
