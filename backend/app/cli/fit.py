"""``python -m backend fit``: photos in, parameters, re-renders, report and metrics out.

    fit REFLECTION TRANSMISSION --out DIR [--pattern auto|plain|twill0|twill1|satin0|satin1|twill0m|...|satin1m]
        [--iterations N] [--size N] [--device cpu|cuda] [--json-progress] [--rig RIG.json]
        [--crop X Y W H] [--flat-field PATH] [--strict] [--seed S] [--init network|prior]
        [--vgg-weights PATH] [--camera-blur auto|PX] [--sample-rotation auto|DEG] [--output-spp N] [--overwrite]
        [--stop-on-stdin]
    fit --example --out DIR      (renders a known fabric, then fits it)

The job itself, its outputs and its error contract are :mod:`backend.app.folder`'s; this module
adds the command line and the stop requests. Progress goes to the terminal, or as JSON lines with
--json-progress (:mod:`backend.core.protocol`).

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

from ...core.priors import FIT_PATTERNS
from ...core.protocol import STOP_REQUEST, Reporter
from ...core.rig import MAX_CAMERA_BLUR_PX, MAX_SAMPLE_ROTATION_DEG
from ...fit.settings import FitSettings
from ...init.network import INIT_CHOICES
from ...model.render import AUTO_SUBPIXEL_BELOW_PX
from ..folder import BLUR_ON, FolderFitOptions, fit_reporting


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


def _working_size(text: str) -> int:
    """argparse type of --size: an integer from 32 up to the film size (checked again against the rig)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of pixels, got {text!r}") from None
    if value < 32:
        raise argparse.ArgumentTypeError(f"must be at least 32 pixels, got {value}")
    return value


def _auto_or_number(limit: float, unit: str, low: float | None = None):
    """argparse type of an 'auto'-or-number option in [low, limit] (low defaults to -limit)."""
    low = -limit if low is None else low

    def parse(text: str) -> str:
        if text == "auto":
            return text
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected 'auto' or a number of {unit}, got {text!r}") from None
        if not low <= value <= limit:
            raise argparse.ArgumentTypeError(f"must be in [{low:g}, {limit:g}] {unit}, got {text}")
        return text

    return parse


# The options of the fit itself, which a batch passes on to every pair's fit (FolderFitOptions' names).
BATCH_FIT_OPTIONS = ("pattern", "iterations", "size", "rig", "strict", "seed", "camera_blur", "sample_rotation",
                     "light_falloff", "spacing_warp", "blur_on", "init", "output_spp")


def add_fit_options(p) -> None:
    """Adds the options of :data:`BATCH_FIT_OPTIONS` (the fit and the batch command share them)."""
    p.add_argument("--pattern", default=FolderFitOptions.pattern, choices=("auto",) + FIT_PATTERNS,
                   help="the weave: auto (chosen from the photos, default), one of the paper's five, or the "
                        "mirror image of a twill or satin (its name + m: the diagonal running the other way)")
    p.add_argument("--iterations", type=int, default=FolderFitOptions.iterations,
                   help="Adam steps of the winner's optimisation at most (default: 150 at 256 px, 100 at a larger "
                        f"working size); it ends sooner once its best loss has not moved for {FitSettings.patience} "
                        "steps")
    p.add_argument("--size", type=_working_size, default=FolderFitOptions.size, metavar="N",
                   help="working size of the loss in pixels, 32 up to the photos' working size (the rig's film "
                        "size, 512); default: 256, or 512 where the yarns are too dense for 256 (the search still runs "
                        "at 256)")
    p.add_argument("--rig", help="capture rig JSON (default: the paper's rig)")
    p.add_argument("--strict", action="store_true", help="refuse (not just warn) photos that look swapped")
    p.add_argument("--seed", type=int, default=FolderFitOptions.seed)
    p.add_argument("--camera-blur", default=FolderFitOptions.camera_blur,
                   type=_auto_or_number(MAX_CAMERA_BLUR_PX, "pixels", 0.0), metavar="auto|PX",
                   help="the camera's blur in film pixels: estimated with the fit (auto, default; a rig file's "
                        "non-zero camera_blur_px is kept) or fixed")
    p.add_argument("--sample-rotation", default=FolderFitOptions.sample_rotation,
                   type=_auto_or_number(MAX_SAMPLE_ROTATION_DEG, "degrees"), metavar="auto|DEG",
                   help="how far the sample is turned in the holder (counter-clockwise, degrees): read from the "
                        "photos with its skew (auto, default; a rig file's non-zero sample_rotation_deg is kept) or "
                        "fixed (then the rig file's sample_skew_deg, 0 by default, is kept too)")
    p.add_argument("--light-falloff", choices=("fit", "none"), default=FolderFitOptions.light_falloff,
                   help="the photos' smooth light falloff (a tilt and a bowl per photo, which the rig's point lamps "
                        "do not make): solved with the fit and kept out of the material (fit, default), or none")
    p.add_argument("--spacing-warp", choices=("fit", "none"), default=FolderFitOptions.spacing_warp,
                   help="the photos' uneven yarn spacing (a smooth warp of the lattice, read from the phase of its "
                        "harmonics against the fit's renders): read with the fit and kept out of the material (fit, "
                        "default), or none (the renders' yarns evenly spaced)")
    p.add_argument("--blur-on", choices=tuple(BLUR_ON), default=FolderFitOptions.blur_on,
                   help="where the camera blur acts in the fit's own renders: on the pixel means (pixels, default), "
                        "on sub-pixels as the optics do before the sensor (subpixels), or on sub-pixels only where "
                        f"the blur is under {AUTO_SUBPIXEL_BELOW_PX:g} render pixels (auto). Measured with auto: "
                        "dense plain weaves fit closer (photo-like plains' thickness error 1.14 -> 0.30), the dev "
                        "real twills' fits no better and up to 40 %% slower")
    p.add_argument("--init", choices=INIT_CHOICES, default=FolderFitOptions.init,
                   help="starting parameters: the shipped network's prediction (default) or the pattern's prior")
    p.add_argument("--output-spp", type=int, default=FolderFitOptions.output_spp,
                   help=f"samples per pixel of the re-renders (default {FolderFitOptions.output_spp}; a square "
                        "of an even side, k x k, lets the camera blur act on sub-pixels)")


def add_parser(sub) -> None:
    p = sub.add_parser("fit", help="fit fabric parameters to a reflection/transmission photo pair")
    p.add_argument("reflection", nargs="?", help="photo lit from the front")
    p.add_argument("transmission", nargs="?", help="photo lit from behind")
    p.add_argument("--out", required=True, help="output folder (a new one, or --overwrite)")
    p.add_argument("--example", action="store_true", help="render the bundled example fabric and fit it")
    add_fit_options(p)
    p.add_argument("--device", default=FolderFitOptions.device)
    p.add_argument("--json-progress", action="store_true", help="JSON lines on stdout (see backend/core/protocol.py)")
    p.add_argument("--crop", type=int, nargs=4, metavar=("X", "Y", "W", "H"), help="square crop box in photo pixels")
    p.add_argument("--flat-field", help="photo of a uniform target under the same light (vignetting)")
    p.add_argument("--vgg-weights", help="a VGG-19 features state dict: adds the paper's Gram loss (slow on a CPU)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier fit in --out")
    p.add_argument("--stop-on-stdin", action="store_true",
                   help="stop (keeping the best parameters) on a 'stop' line on stdin or when stdin ends: for callers "
                        "that cannot send signals")
    p.set_defaults(run=run_fit)
