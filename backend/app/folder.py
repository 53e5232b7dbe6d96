"""One fit from photo files to a results folder: the job of ``python -m backend fit``, as a plain function.

:func:`fit_to_folder` loads the photos, fits them and writes the folder: ``params.json`` (spec
names, plus the interchange string, rig, fit details), ``reflection.png`` and ``transmission.png``
(16-bit re-renders of the fit at the rig's film size and ``output_spp`` samples, as the photos show
the fabric: their framing, each photo's own where the pair was registered, camera blur and fitted
light falloff), ``report.png`` and ``metrics.json`` (FLIP, 16 x 16 colour L1 and spectrum
correlation for both images over what the fit saw: :meth:`.PhotoPair.as_compared`; wall time);
:data:`backend.core.results.RESULT_FILES` names them. An existing fit in the folder is never
overwritten without ``overwrite``.

params.json is written as soon as the fit ends, before anything optional: a failure in the
re-renders, metrics or report afterwards is a warning (with its traceback on stderr) and loses
nothing; the run still ends with its result. Each file is written whole or not at all (a temporary
file renamed over it: :func:`backend.core.jsonfile.replacing`), so a fit killed midway leaves no
half-written file in the folder.

:func:`fit_reporting` is the command's contract around it: progress through a
:class:`~backend.core.protocol.Reporter`, every failure one protocol error line and an exit code (2
bad input, 1 internal, 130 cancelled: the best parameters so far go to ``params.partial.json``, or,
once params.json is written, stay there). The command line (cli/fit.py) adds argparse and stop
requests; the batch's Ray tasks call it in-process.

The options are a :class:`FolderFitOptions`: one field per option that backend.core.fit_options
declares, checked there (a bad value is bad input, exit 2); :func:`fit_settings` turns them into the
fit's :class:`~backend.fit.settings.FitSettings`.
"""
from __future__ import annotations

import dataclasses
import json
import time
import traceback
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..core.fit_options import FIT_OPTIONS, FitOptionError, check_values
from ..core.jsonfile import make_folder, replacing, write_whole
from ..core.params import PARAMETERS, FabricParams
from ..core.protocol import EXIT_CANCELLED, EXIT_INPUT, EXIT_INTERNAL, Reporter
from ..core.rig import DEFAULT_RIG, CaptureRig, RigError
from ..fit.gram import GramWeightsError
from ..fit.pipeline import fit
from ..fit.settings import FitCancelled, FitSettings
from ..image.metrics import compare
from ..image.photos import PhotoError, load_pair
from ..image.png import write_png
from ..init.network import fit_initialiser
from ..model.memory import peak_memory_mb
from ..model.photo_light import PhotoLight
from ..model.render import render_pair
from ..model.spacing_warp import SpacingWarp
from .cli.common import InputError, device
from .environment import renderer_compiles
from .report import write_report
from .warm_compile import start_warming

EXAMPLE_PARAMS = ("twill1_R_0.72,0.55_S_1.3,1.6_T_2.4,2.9_N_0.0_UV_92.0,131.0_Kd_0.32,0.18,0.11,0.26,0.14,0.08"
                  "_G_0.88,0.9_Rm_0.7,0.45_Tm_2.2,2.6_W_0.6,0.9_Ks_0.62,0.38,0.25,0.55,0.33,0.22_Psi_-30.0,-30.0")
FITTED = tuple(s.name for s in PARAMETERS if s.optimised or (s.searched and s.name != "tiles"))


class FitInputError(ValueError):
    def __init__(self, message: str, file: str | None = None):
        super().__init__(message)
        self.file = file


# exit code 2, one line naming the file or option
INPUT_ERRORS = (FitInputError, FitOptionError, PhotoError, RigError, GramWeightsError, InputError)


# The fit command's options: one field per option of backend.core.fit_options (its name, type and default).
FolderFitOptions = dataclasses.make_dataclass(
    "FolderFitOptions", [(option.name, option.annotation, option.default) for option in FIT_OPTIONS],
    frozen=True, namespace={"__module__": __name__,
                            "__doc__": "The fit command's options (its ``--flags``: FIT_OPTIONS' names and defaults)."})


def fit_settings(options: FolderFitOptions, rig: CaptureRig) -> FitSettings:
    """The FitSettings of ``options``: each option's value as the setting FIT_OPTIONS names for it;
    a capture value left at auto (camera blur, sample rotation) takes a rig file's non-zero value
    (the same camera and holder again), else the fit reads it from the photos; the renderer compiles
    where this machine can (:func:`.environment.renderer_compiles`)."""
    values = {o.setting: o.setting_value(getattr(options, o.name)) for o in FIT_OPTIONS if o.setting}
    for name, rig_value in (("camera_blur", rig.camera_blur_px), ("sample_rotation", rig.sample_rotation_deg)):
        if values[name] is None and rig_value != 0:
            values[name] = rig_value
    return FitSettings(**values, compile=renderer_compiles(device=values["device"]))


def make_example(folder: Path, rig: CaptureRig = DEFAULT_RIG) -> tuple[Path, Path, FabricParams]:
    """Renders the bundled example fabric as a photo pair (8-bit, like a phone's) into ``folder``."""
    params = FabricParams.from_interchange(EXAMPLE_PARAMS)
    pair = render_pair(params, rig, size=rig.film_size, spp=16, seed=12345)
    folder.mkdir(parents=True, exist_ok=True)
    reflection = write_png(folder / "example_R.png", pair.reflection, bits=8)
    transmission = write_png(folder / "example_T.png", pair.transmission, bits=8)
    return reflection, transmission, params


def fit_reporting(reflection: str | Path | None, transmission: str | Path | None, out: Path,
                  options: FolderFitOptions, reporter: Reporter, should_stop: Callable[[], bool],
                  example: bool = False) -> int:
    """:func:`fit_to_folder` with the command's error contract; returns the exit code."""
    written: dict[str, str] = {}
    try:
        return fit_to_folder(reflection, transmission, out, options, reporter, should_stop, example, written)
    except FitCancelled as cancelled:
        if "params" in written:
            message = (f"the fit was cancelled after it ended: its parameters are in {written['params']}; "
                       "the re-renders, metrics or report may be missing")
        elif cancelled.params is not None and out.is_dir():
            write_whole(out / "params.partial.json", cancelled.params.to_json(version=__version__, partial=True) + "\n")
            message = "the fit was cancelled; the best parameters so far are in params.partial.json"
        else:
            message = "the fit was cancelled before any result"
        reporter.error("cancelled", message)
        return EXIT_CANCELLED
    except INPUT_ERRORS as exc:
        reporter.error("input", str(exc), getattr(exc, "file", None))
        return EXIT_INPUT
    except Exception as exc:  # the caller gets a readable line, never a silent death
        traceback.print_exc()
        reporter.error("internal", f"{type(exc).__name__}: {exc}")
        return EXIT_INTERNAL


def _prepare_out(out: Path, overwrite: bool) -> None:
    if out.exists() and not out.is_dir():
        raise FitInputError(f"{out}: exists and is not a folder", str(out))
    if (out / "params.json").exists() and not overwrite:
        raise FitInputError(f"{out}: already holds a fit (params.json); choose a new folder or pass --overwrite",
                            str(out / "params.json"))
    make_folder(out, FitInputError)


def _checked_rig(options: FolderFitOptions) -> CaptureRig:
    """The fit's rig, once the options are known good: each option's value (backend.core.fit_options),
    the device there, the working size within the rig's film size."""
    check_values(dataclasses.asdict(options))
    device(options.device)
    rig = CaptureRig.load(options.rig) if options.rig else DEFAULT_RIG
    if options.size is not None and options.size > rig.film_size:
        raise FitInputError(f"--size {options.size}: larger than the photos' working size ({rig.film_size} px, the "
                            "rig's film size); the loss cannot see more than the photos hold")
    return rig


def _photo_paths(reflection: str | Path | None, transmission: str | Path | None, out: Path, rig: CaptureRig,
                 example: bool) -> tuple[Path, Path, FabricParams | None]:
    """(reflection, transmission, the fabric they show where known): the given photos, or the
    example fabric's, rendered into ``out``."""
    if example:
        return make_example(out / "example_photos", rig)
    if not reflection or not transmission:
        raise FitInputError("fit needs REFLECTION and TRANSMISSION photos (or --example)")
    return Path(reflection), Path(transmission), None


def _blur_at_ceiling(result) -> list[str]:
    """The camera blur, in the style of :meth:`FabricParams.at_bounds`, where the fit left it at the
    most the photos allow (``FitResult.camera_blur_range``): the loss wanted a softer render there."""
    allowed = result.camera_blur_range
    if allowed is None or result.camera_blur_px < allowed[1]:
        return []
    return [f"camera_blur_px = {result.camera_blur_px:g} (upper bound: the photos' blur reading + "
            f"{allowed[1] - allowed[0]:g} px)"]


def fit_to_folder(reflection: str | Path | None, transmission: str | Path | None, out: Path,
                  options: FolderFitOptions, reporter: Reporter, should_stop: Callable[[], bool],
                  example: bool = False, written: dict[str, str] | None = None) -> int:
    """Loads the photos (or renders the example fabric's), fits them and writes the results folder
    (see the module docstring); raises on failure. Each file is recorded in ``written`` (name ->
    path) as soon as it exists."""
    written = {} if written is None else written
    started = time.perf_counter()
    rig = _checked_rig(options)
    _prepare_out(out, options.overwrite)
    reflection_path, transmission_path, truth = _photo_paths(reflection, transmission, out, rig, example)
    reporter.progress("load", 0, 1)
    photos = load_pair(reflection_path, transmission_path, size=rig.film_size, crop=options.crop,
                       flat_field=options.flat_field, strict=options.strict, workers=torch.get_num_threads())
    for warning in photos.warnings:
        reporter.warning(warning)
    reporter.progress("load", 1, 1)

    settings = fit_settings(options, rig)
    initial_for = fit_initialiser(options.init, photos.reflection, photos.transmission, rig, reporter.warning)
    result = fit(photos.reflection, photos.transmission, rig, settings,
                 progress=reporter.progress,
                 initial_for=initial_for,
                 pattern_probabilities=initial_for.pattern_probabilities if initial_for is not None else None,
                 should_stop=should_stop)

    # the placement the fit read from the photos: the re-renders and params.json's rig use it
    rig = dataclasses.replace(rig, camera_blur_px=round(result.camera_blur_px, 4), glow_strength=result.glow_strength,
                              sample_rotation_deg=round(result.sample_rotation_deg, 4),
                              sample_skew_deg=round(result.sample_skew_deg, 4))
    at_bounds = result.params.at_bounds(FITTED) + _blur_at_ceiling(result)
    extra = {"interchange": result.params.to_interchange(), "version": __version__, "rig": rig.to_dict(),
             "fit": {"loss": result.loss, "terms": result.terms, "candidates": result.candidates,
                     "at_bounds": at_bounds, "light_falloff": result.light.to_dict(),
                     "spacing_warp": None if result.warp is None else result.warp.to_dict(),
                     "camera_blur_range_px": result.camera_blur_range,
                     "variation": result.variation,
                     "settings": {"pattern": settings.pattern, "iterations": result.iterations, "steps": result.steps,
                                  "size": result.size, "spp": result.spp, "seed": settings.seed}},
             "photos": photos.info}
    write_whole(out / "params.json", result.params.to_json(**extra) + "\n")
    written["params"] = str(out / "params.json")

    # Everything below is optional: a failure is a warning, params.json stays.
    reporter.progress("render", 0, 1)

    def render_progress(done, total):
        if should_stop():
            raise FitCancelled(result.params)
        reporter.progress("render", done, total)

    def optional(what: str, make):
        try:
            return make()
        except FitCancelled:
            raise
        except Exception as exc:
            traceback.print_exc()
            reporter.warning(f"{what} could not be written ({type(exc).__name__}: {exc}); the fitted parameters "
                             f"are in {written['params']}")
            return None

    def write_renders():
        images = _final_renders(result.params, rig, result.light, result.warp, settings.device, options.output_spp,
                                render_progress)
        framed = photos.in_own_framing(images)  # (photos, re-renders), each in its photo's framing
        for name, image in zip(("reflection", "transmission"), framed[1]):
            with replacing(out / f"{name}.png") as temporary:
                write_png(temporary, image)
            written[name] = str(out / f"{name}.png")
        return framed

    framed = optional("the re-renders (and so the metrics and report)", write_renders)
    metrics = None
    if framed is not None:
        reporter.progress("report", 0, 1)
        metrics = optional("metrics.json (and so report.png)",
                           lambda: _write_metrics(out, photos, framed, result, rig, settings, started, truth,
                                                  at_bounds))
    if metrics is not None:
        written["metrics"] = str(out / "metrics.json")
        report = optional("report.png", lambda: write_report(
            out / "report.png", *framed, metrics, result.params, rig,
            time.perf_counter() - started, at_bounds, result.light, photos.info.get("registration"),
            photos.seen_boxes(), result.warp))
        if report is not None:
            written["report"] = str(report)
    reporter.progress("report", 1, 1)
    if not settings.compile:  # where only the kernels' being cold kept it eager, they are made for later fits,
        start_warming(device=settings.device)  # after this one: beside a fit the warm-up slowed it more than a compile
    reporter.info(f"wrote {out}: {', '.join(Path(path).name for path in written.values())}")
    reporter.result(out_dir=str(out), params=written["params"], files=dict(written), metrics=metrics or {})
    return 0


def _write_metrics(out: Path, photos, framed, result, rig: CaptureRig, settings: FitSettings, started: float,
                   truth: FabricParams | None, at_bounds: list[str]) -> dict:
    """metrics.json: the renders against the photos (``framed``: both in each photo's framing), wall
    time, peak memory, stage timings; the metrics."""
    (photo_r, render_r), (photo_t, render_t) = photos.as_compared(framed)
    metrics = {"reflection": compare(photo_r, render_r), "transmission": compare(photo_t, render_t)}
    peak_mb = peak_memory_mb(torch.device(settings.device))
    summary = {"metrics": metrics, "wall_s": round(time.perf_counter() - started, 2),
               "peak_mb": None if peak_mb is None else round(peak_mb, 1),
               "timings": {k: round(v, 2) for k, v in result.timings.items()},
               "loss": result.loss, "pattern": result.params.pattern, "tiles": list(result.params.tiles),
               "camera_blur_px": rig.camera_blur_px, "sample_rotation_deg": rig.sample_rotation_deg,
               "sample_skew_deg": rig.sample_skew_deg,
               "light_falloff": result.light.to_dict(), "at_bounds": at_bounds,
               "compared_region": dict(zip(("reflection", "transmission"), map(list, photos.seen_boxes())))}
    if truth is not None:
        summary["example_truth"] = truth.to_dict()
    write_whole(out / "metrics.json", json.dumps(summary, indent=2) + "\n")
    return metrics


def _final_renders(params: FabricParams, rig: CaptureRig, light: PhotoLight, warp: SpacingWarp | None, device,
                   spp: int, progress) -> tuple[np.ndarray, np.ndarray]:
    """The re-renders as the photos show the fabric: the fitted camera blur, rotation, light falloff and
    uneven yarn spacing."""
    pair = render_pair(params, rig, size=rig.film_size, spp=spp, seed=1, device=device, progress=progress,
                       light=light, warp=warp)
    return pair.reflection.cpu().numpy(), pair.transmission.cpu().numpy()

