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
import json
import signal
import time
import traceback
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..core.params import FabricParams
from ..core.priors import PATTERNS
from ..core.protocol import EXIT_CANCELLED, EXIT_INPUT, EXIT_INTERNAL, Reporter
from ..core.rig import DEFAULT_RIG, MAX_CAMERA_BLUR_PX, CaptureRig, RigError
from ..fit.gram import GramWeightsError
from ..fit.pipeline import fit
from ..fit.report import write_report
from ..fit.settings import FitCancelled, FitSettings
from ..image.metrics import compare
from ..image.photos import PhotoError, load_pair
from ..image.png import write_png
from ..init.network import INIT_CHOICES, fit_initialiser
from ..model.memory import peak_memory_mb
from ..model.render import render_pair

EXAMPLE_PARAMS = ("twill1_R_0.72,0.55_S_1.3,1.6_T_2.4,2.9_N_0.0_UV_92.0,131.0_Kd_0.32,0.18,0.11,0.26,0.14,0.08"
                  "_G_0.88,0.9_Rm_0.7,0.45_Tm_2.2,2.6_W_0.6,0.9_Ks_0.62,0.38,0.25,0.55,0.33,0.22_Psi_-30.0,-30.0")
OUTPUT_SPP = 64
MIN_SIZE = 16  # the loss compares 16 x 16 colour grids


class FitInputError(ValueError):
    def __init__(self, message: str, file: str | None = None):
        super().__init__(message)
        self.file = file


def make_example(folder: Path, rig: CaptureRig = DEFAULT_RIG) -> tuple[Path, Path, FabricParams]:
    """Renders the bundled example fabric as a photo pair (8-bit, like a phone's) into ``folder``."""
    params = FabricParams.from_interchange(EXAMPLE_PARAMS)
    pair = render_pair(params, rig, size=rig.film_size, spp=16, seed=12345)
    folder.mkdir(parents=True, exist_ok=True)
    reflection = write_png(folder / "example_R.png", pair.reflection, bits=8)
    transmission = write_png(folder / "example_T.png", pair.transmission, bits=8)
    return reflection, transmission, params


def _prepare_out(out: Path, overwrite: bool) -> None:
    if out.exists() and not out.is_dir():
        raise FitInputError(f"{out}: exists and is not a folder", str(out))
    if (out / "params.json").exists() and not overwrite:
        raise FitInputError(f"{out}: already holds a fit (params.json); choose a new folder or pass --overwrite",
                            str(out / "params.json"))
    out.mkdir(parents=True, exist_ok=True)


def run_fit(args) -> int:
    """The command: signals stop the fit cleanly, every failure becomes one protocol error line."""
    reporter = Reporter(json_lines=args.json_progress)
    reporter.start("fit", device=args.device)
    stop = {"requested": False}

    def request_stop(signum, frame):
        stop["requested"] = True

    previous = {sig: signal.signal(sig, request_stop) for sig in (signal.SIGINT, signal.SIGTERM)}
    out = Path(args.out)
    try:
        return fit_to_folder(args, reporter, out, lambda: stop["requested"])
    except FitCancelled as cancelled:
        if cancelled.params is not None and out.is_dir():
            (out / "params.partial.json").write_text(cancelled.params.to_json(version=__version__, partial=True)
                                                     + "\n")
        reporter.error("cancelled", "the fit was cancelled; the best parameters so far are in params.partial.json"
                       if cancelled.params is not None else "the fit was cancelled before any result")
        return EXIT_CANCELLED
    except (FitInputError, PhotoError, RigError, GramWeightsError) as exc:
        reporter.error("input", str(exc), getattr(exc, "file", None))
        return EXIT_INPUT
    except Exception as exc:  # the caller gets a readable line, never a silent death
        traceback.print_exc()
        reporter.error("internal", f"{type(exc).__name__}: {exc}")
        return EXIT_INTERNAL
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def fit_to_folder(args, reporter: Reporter, out: Path, should_stop) -> int:
    """Loads the photos, fits them and writes the results folder (see the module docstring)."""
    started = time.perf_counter()
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        raise FitInputError(f"--device {args.device}: CUDA is not available in this PyTorch build or on this machine")
    rig = CaptureRig.load(args.rig) if args.rig else DEFAULT_RIG
    if not MIN_SIZE <= args.size <= rig.film_size:  # the photos are loaded at the rig's film size
        raise FitInputError(f"--size {args.size}: must be between {MIN_SIZE} and the photos' working size "
                            f"{rig.film_size} (the rig's film_size)")
    _prepare_out(out, args.overwrite)
    truth = None
    if args.example:
        reflection_path, transmission_path, truth = make_example(out / "example_photos", rig)
    else:
        if not args.reflection or not args.transmission:
            raise FitInputError("fit needs REFLECTION and TRANSMISSION photos (or --example)")
        reflection_path, transmission_path = Path(args.reflection), Path(args.transmission)
    reporter.progress("load", 0, 1)
    photos = load_pair(reflection_path, transmission_path, size=rig.film_size, crop=args.crop,
                       flat_field=args.flat_field, strict=args.strict)
    for warning in photos.warnings:
        reporter.warning(warning)
    reporter.progress("load", 1, 1)

    settings = FitSettings(pattern=args.pattern, iterations=args.iterations, size=args.size, seed=args.seed,
                           device=args.device, vgg_weights=args.vgg_weights,
                           camera_blur=_given_blur(args.camera_blur, rig))
    initial_for = fit_initialiser(args.init, photos.reflection, photos.transmission, rig, reporter.warning)
    result = fit(photos.reflection, photos.transmission, rig, settings,
                 progress=lambda stage, i, n, loss, eta: reporter.progress(stage, i, n, loss, eta),
                 initial_for=initial_for,
                 pattern_probabilities=initial_for.pattern_probabilities if initial_for is not None else None,
                 should_stop=should_stop)

    rig = dataclasses.replace(rig, camera_blur_px=round(result.camera_blur_px, 4))  # re-renders, params.json
    reporter.progress("render", 0, 1)

    def render_progress(done, total):
        if should_stop():
            raise FitCancelled(result.params)
        reporter.progress("render", done, total)

    renders = _final_renders(result.params, rig, settings.device, args.output_spp, render_progress)
    files = {"reflection": str(write_png(out / "reflection.png", renders[0])),
             "transmission": str(write_png(out / "transmission.png", renders[1]))}
    reporter.progress("report", 0, 1)
    metrics = {"reflection": compare(photos.reflection, renders[0]),
               "transmission": compare(photos.transmission, renders[1])}
    wall = time.perf_counter() - started
    peak_mb = peak_memory_mb(torch.device(settings.device))
    summary = {"metrics": metrics, "wall_s": round(wall, 2), "peak_mb": None if peak_mb is None else round(peak_mb, 1),
               "timings": {k: round(v, 2) for k, v in result.timings.items()},
               "loss": result.loss, "pattern": result.params.pattern, "tiles": list(result.params.tiles),
               "camera_blur_px": rig.camera_blur_px}
    if truth is not None:
        summary["example_truth"] = truth.to_dict()
    files["metrics"] = str(out / "metrics.json")
    (out / "metrics.json").write_text(json.dumps(summary, indent=2) + "\n")
    files["report"] = str(write_report(out / "report.png", (photos.reflection, photos.transmission), renders,
                                       metrics, result.params, wall))
    extra = {"interchange": result.params.to_interchange(), "version": __version__, "rig": rig.to_dict(),
             "fit": {"loss": result.loss, "terms": result.terms, "candidates": result.candidates,
                     "settings": {"pattern": settings.pattern, "iterations": settings.iterations,
                                  "size": settings.size, "spp": settings.spp, "seed": settings.seed}},
             "photos": photos.info}
    files["params"] = str(out / "params.json")
    (out / "params.json").write_text(result.params.to_json(**extra) + "\n")
    reporter.progress("report", 1, 1)
    reporter.info(f"wrote {out}: params.json, reflection.png, transmission.png, report.png, metrics.json")
    reporter.result(out_dir=str(out), params=files["params"], files=files, metrics=metrics)
    return 0


def _final_renders(params: FabricParams, rig: CaptureRig, device, spp: int, progress) -> tuple[np.ndarray, np.ndarray]:
    pair = render_pair(params, rig, size=rig.film_size, spp=spp, seed=1, device=device, progress=progress)
    return pair.reflection.cpu().numpy(), pair.transmission.cpu().numpy()


def _given_blur(option: str, rig: CaptureRig) -> float | None:
    """The fixed camera blur: --camera-blur PX, else a rig file's non-zero ``camera_blur_px`` (the
    same camera again); None (estimate it) otherwise."""
    if option != "auto":
        return float(option)
    return rig.camera_blur_px if rig.camera_blur_px > 0 else None


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


def add_parser(sub) -> None:
    p = sub.add_parser("fit", help="fit fabric parameters to a reflection/transmission photo pair")
    p.add_argument("reflection", nargs="?", help="photo lit from the front")
    p.add_argument("transmission", nargs="?", help="photo lit from behind")
    p.add_argument("--out", required=True, help="output folder (a new one, or --overwrite)")
    p.add_argument("--example", action="store_true", help="render the bundled example fabric and fit it")
    p.add_argument("--pattern", default="auto", choices=("auto",) + PATTERNS)
    p.add_argument("--iterations", type=int, default=FitSettings.iterations)
    p.add_argument("--size", type=int, default=FitSettings.size, help="working size of the loss (default 256)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--json-progress", action="store_true", help="JSON lines on stdout (see backend/core/protocol.py)")
    p.add_argument("--rig", help="capture rig JSON (default: the paper's rig)")
    p.add_argument("--crop", type=int, nargs=4, metavar=("X", "Y", "W", "H"), help="square crop box in photo pixels")
    p.add_argument("--flat-field", help="photo of a uniform target under the same light (vignetting)")
    p.add_argument("--strict", action="store_true", help="refuse (not just warn) photos that look swapped")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--camera-blur", default="auto", type=_camera_blur, metavar="auto|PX",
                   help="the camera's blur in film pixels: estimated with the fit (auto, default; a rig file's "
                        "non-zero camera_blur_px is kept) or fixed")
    p.add_argument("--init", choices=INIT_CHOICES, default="network",
                   help="starting parameters: the shipped network's prediction (default) or the pattern's prior")
    p.add_argument("--vgg-weights", help="a VGG-19 features state dict: adds the paper's Gram loss (slow on a CPU)")
    p.add_argument("--output-spp", type=int, default=OUTPUT_SPP,
                   help="samples per pixel of the re-renders (default 64)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier fit in --out")
    p.set_defaults(run=run_fit)
