"""``python -m backend fit``: photos in, parameters, re-renders, report and metrics out.

    fit REFLECTION TRANSMISSION --out DIR [--pattern auto|plain|twill0|twill1|satin0|satin1]
        [--iterations N] [--size N] [--device cpu|cuda] [--json-progress] [--rig RIG.json]
        [--crop X Y W H] [--flat-field PATH] [--strict] [--seed S] [--init network|prior]
        [--vgg-weights PATH] [--camera-blur auto|PX] [--output-spp N] [--overwrite]
    fit --example --out DIR      (renders a known fabric, then fits it)

Writes DIR/params.json (spec names, plus the interchange string, rig, fit details), DIR/reflection.png
and DIR/transmission.png (16-bit re-renders of the fit at the rig's film size (512) and 64 spp, the
photos' framing), DIR/report.png and DIR/metrics.json (FLIP, 16 x 16 colour L1 and spectrum
correlation for both images, wall time). Progress goes to the terminal, or as JSON lines with
--json-progress (:mod:`backend.core.protocol`). SIGINT/SIGTERM stop the fit: the best parameters so
far are written to DIR/params.partial.json and the exit code is 130. An existing fit in DIR is never
overwritten without --overwrite.
"""
from __future__ import annotations

import argparse
import dataclasses
import signal
from pathlib import Path

from ..core.priors import PATTERNS
from ..core.protocol import Reporter
from ..core.rig import MAX_CAMERA_BLUR_PX
from ..fit.folder import FolderFitOptions, fit_reporting
from ..init.network import INIT_CHOICES


def run_fit(args) -> int:
    """The command: signals stop the fit cleanly, every failure becomes one protocol error line."""
    reporter = Reporter(json_lines=args.json_progress)
    reporter.start("fit", device=args.device)
    stop = {"requested": False}

    def request_stop(signum, frame):
        stop["requested"] = True

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    options = FolderFitOptions(**{f.name: getattr(args, f.name) for f in dataclasses.fields(FolderFitOptions)})
    try:
        return fit_reporting(args.reflection, args.transmission, Path(args.out), options, reporter,
                             lambda: stop["requested"], example=args.example)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _camera_blur(text: str) -> str:
    """argparse type of --camera-blur: 'auto' or a number in the rig's range."""
    if text == "auto":
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or a number of pixels, got {text!r}") from None
    if not 0.0 <= value <= MAX_CAMERA_BLUR_PX:
        raise argparse.ArgumentTypeError(f"must be in [0, {MAX_CAMERA_BLUR_PX}] pixels, got {text}")
    return text


# The options of the fit itself, which a batch passes on to every pair's fit (FolderFitOptions' names).
BATCH_FIT_OPTIONS = ("pattern", "iterations", "size", "rig", "strict", "seed", "camera_blur", "init", "output_spp")


def add_fit_options(p) -> None:
    """Adds the options of :data:`BATCH_FIT_OPTIONS` (the fit and the batch command share them)."""
    p.add_argument("--pattern", default=FolderFitOptions.pattern, choices=("auto",) + PATTERNS)
    p.add_argument("--iterations", type=int, default=FolderFitOptions.iterations)
    p.add_argument("--size", type=int, default=FolderFitOptions.size, help="working size of the loss (default 256)")
    p.add_argument("--rig", help="capture rig JSON (default: the paper's rig)")
    p.add_argument("--strict", action="store_true", help="refuse (not just warn) photos that look swapped")
    p.add_argument("--seed", type=int, default=FolderFitOptions.seed)
    p.add_argument("--camera-blur", default=FolderFitOptions.camera_blur, type=_camera_blur, metavar="auto|PX",
                   help="the camera's blur in film pixels: estimated with the fit (auto, default; a rig file's "
                        "non-zero camera_blur_px is kept) or fixed")
    p.add_argument("--init", choices=INIT_CHOICES, default=FolderFitOptions.init,
                   help="starting parameters: the shipped network's prediction (default) or the pattern's prior")
    p.add_argument("--output-spp", type=int, default=FolderFitOptions.output_spp,
                   help="samples per pixel of the re-renders (default 64)")


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
    p.set_defaults(run=run_fit)
