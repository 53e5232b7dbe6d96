"""The batch fit (no bpy): every ``<name>_R.* / <name>_T.*`` pair of a folder into a material library.

Each good pair is fitted in a new result folder (captures.new_fit) and handed to a *library*
(scene/materials.py's AssetLibrary: ``add(name, params, width_cm, fit_folder, description,
preview) -> material name`` and ``write(path)``), which makes one asset material per pair and
writes them all into one .blend. A pair with a missing partner (or two candidates for one side), or
whose fit fails, is reported and skipped. The exit code is the number of failed pairs (0: all
good; capped at 125). A problem that stops the batch before any fit (bad arguments, no folder, no
pairs at all, an unusable rig or backend) exits with 1; when the library cannot be written, every
fitted pair counts as failed.

The backend is chosen as for the panel: ``--python`` / ``--backend-script``, else the add-on
preferences, else ``WOVEN_FABRIC_PYTHON`` / ``WOVEN_FABRIC_BACKEND_SCRIPT``, else auto-detection.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from . import backend_bridge, backend_setup, captures, declarations, rig_settings

CLI_COMMAND = "fabric_fit"
MAX_EXIT = 125


@dataclass
class BatchReport:
    fitted: list[tuple[str, str, str]] = field(default_factory=list)   # (pair, material, result folder)
    failed: list[tuple[str, str]] = field(default_factory=list)        # (pair, reason)
    library: Path | None = None

    @property
    def exit_code(self) -> int:
        return min(len(self.failed), MAX_EXIT)


@dataclass
class BatchOptions:
    pattern: str = declarations.AUTO_PATTERN
    iterations: int | None = None
    size: int | None = None
    device: str | None = None
    rig_json: Path | None = None
    width_cm: float | None = None
    timeout_s: float | None = None
    overwrite: bool = False
    output_spp: int | None = None


def run_batch(folder: str | Path, library_path: str | Path | None = None, *, backend: backend_bridge.Backend,
              library, options: BatchOptions | None = None, fits_parent: str | Path | None = None,
              log=print) -> BatchReport:
    """Fits every pair of ``folder`` into ``library`` and writes it to ``library_path``; never raises
    for a pair."""
    options = options or BatchOptions()
    folder = Path(folder).resolve()
    report = BatchReport()
    pairs, problems = declarations.find_pairs(folder)
    for problem in problems:
        log(f"SKIP {problem.name}: {problem.message}")
        report.failed.append((problem.name, problem.message))
    if not pairs:
        if not problems:
            report.failed.append(("", f"{folder}: no <name>_R.* / <name>_T.* photo pairs"))
            log(f"ERROR {report.failed[-1][1]}")
        return report

    fits_parent = Path(fits_parent) if fits_parent else folder / "fabric_fits"
    rig_values = _rig_file(options.rig_json)
    if options.width_cm:
        rig_values["width_cm"] = options.width_cm
    rig = rig_settings.rig_dict(rig_values)
    for number, pair in enumerate(pairs, 1):
        prefix = f"[{number}/{len(pairs)}] {pair.name}"
        try:
            material, out_dir = _fit_pair(pair, backend, library, options, rig, fits_parent, prefix, log)
        except Exception as exc:  # one pair's trouble never stops the batch
            reason = str(exc) or type(exc).__name__
            log(f"FAIL {prefix}: {reason}")
            report.failed.append((pair.name, reason))
            continue
        report.fitted.append((pair.name, material, str(out_dir)))
        log(f"OK   {prefix}: material {material} ({out_dir})")

    if report.fitted:
        target = Path(library_path) if library_path else folder / "fabric_materials.blend"
        target = target if options.overwrite else captures.unused_path(target)
        try:
            library.write(target)
        except (OSError, RuntimeError) as exc:
            log(f"ERROR cannot write {target}: {exc}")
            report.failed.extend((name, f"not saved: {exc}") for name, _, _ in report.fitted)
            report.fitted.clear()
            return report
        report.library = target
        log(f"Wrote {len(report.fitted)} material(s) to {target}")
    return report


def _rig_file(path: Path | None) -> dict:
    """The rig's settings from ``--rig RIG.json`` over the spec's defaults."""
    if not path:
        return rig_settings.defaults()
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"--rig {path}: cannot read ({exc})") from None
    return {**rig_settings.defaults(), **data}


def _fit_pair(pair, backend, library, options, rig, fits_parent, prefix, log) -> tuple[str, Path]:
    fit = captures.new_fit(backend, pair.reflection, pair.transmission, fits_parent, pair.name, rig,
                           pattern=options.pattern, iterations=options.iterations, size=options.size,
                           device=options.device, output_spp=options.output_spp).start()
    out_dir = fit.request.out_dir
    last_stage = [None]

    def show(event):
        if event["event"] == "progress" and event.get("stage") != last_stage[0]:
            last_stage[0] = event.get("stage")
            log(f"     {prefix}: {backend_bridge.describe_progress(event)}")
        elif event["event"] == "warning":
            log(f"WARN {prefix}: {event.get('message')}")

    try:
        fit.wait(timeout=options.timeout_s, on_event=show)
    except KeyboardInterrupt:  # Ctrl+C: the backend runs in its own session and must be stopped here
        fit.cancel()
        raise
    if fit.state != backend_bridge.SUCCEEDED:
        if fit.details:
            log(fit.details)
        raise RuntimeError(fit.error or f"fit {fit.state}")
    params, description, preview = fitted_asset(pair, fit.result, out_dir)
    material = library.add(pair.name, params, rig.get("width_cm"), out_dir, description, preview)
    return material, out_dir


def fitted_asset(pair, result: dict, out_dir: Path) -> tuple[dict, str, Path]:
    """(params, asset description, preview image) of a pair's successful fit (its ``result`` event)."""
    params = captures.read_fit_params(result)
    preview = Path((result.get("files") or {}).get("reflection") or pair.reflection)
    description = (f"Woven fabric fitted from {pair.reflection.name} and {pair.transmission.name} "
                   f"({out_dir})")
    return params, description, preview


# -- command line -------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=f"blender --command {CLI_COMMAND}",
        description="Fit every <name>_R.* / <name>_T.* photo pair of a folder and save one asset material "
                    "per pair in a .blend. Exit code: the number of failed pairs.")
    parser.add_argument("folder", help="folder with the photo pairs")
    parser.add_argument("--out", help="the .blend to write (default: FOLDER/fabric_materials.blend; an "
                                      "existing file is kept and a new name chosen unless --overwrite)")
    parser.add_argument("--fits", help="parent of the per-pair result folders (default: FOLDER/fabric_fits)")
    parser.add_argument("--pattern", choices=declarations.fit_patterns(), default=declarations.AUTO_PATTERN)
    parser.add_argument("--iterations", type=int)
    parser.add_argument("--size", type=int)
    parser.add_argument("--device", choices=backend_bridge.DEVICES)
    parser.add_argument("--output-spp", type=int, help="samples per pixel of each fit's re-renders "
                                                       "(default: the backend's, 64; fewer for quick previews)")
    parser.add_argument("--rig", type=Path, help="RIG.json (CaptureRig settings; default: the spec's rig)")
    parser.add_argument("--width-cm", type=float, help="real width of the photographed square in centimetres")
    parser.add_argument("--timeout", type=float, help="seconds allowed per pair (default: no limit)")
    parser.add_argument("--python", default="", help="interpreter for the backend (default: preferences, "
                                                     "$WOVEN_FABRIC_PYTHON, auto-detection)")
    parser.add_argument("--backend-script", default="", help="script run instead of 'python -m backend'")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    return parser


def main(argv: list[str] | None, *, library,
         preferred_backend: Callable[[], backend_bridge.Backend | None] = lambda: None) -> int:
    """Runs the batch from command-line arguments; returns the exit code (see the module docstring).

    ``preferred_backend`` gives the backend the add-on preferences name (None: none named).
    """
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help (0) or a usage error (1); argparse already printed why
        return 0 if not exc.code else 1
    started = time.monotonic()
    try:
        backend = _backend(args, preferred_backend())
        options = BatchOptions(args.pattern, args.iterations, args.size, args.device, args.rig, args.width_cm,
                               args.timeout, args.overwrite, args.output_spp)
        if not Path(args.folder).is_dir():
            raise ValueError(f"{args.folder}: not a folder")
        report = run_batch(args.folder, args.out, backend=backend, library=library, options=options,
                           fits_parent=args.fits)
    except (backend_bridge.BackendError, ValueError, OSError) as exc:
        print(f"ERROR {exc}", file=sys.stderr)
        return 1
    print(f"{len(report.fitted)} fitted, {len(report.failed)} failed in {time.monotonic() - started:.1f} s"
          + (f"; library {report.library}" if report.library else ""))
    for name, reason in report.failed:
        print(f"  failed {name or '(folder)'}: {reason}")
    return report.exit_code


def _backend(args, preferred: backend_bridge.Backend | None) -> backend_bridge.Backend:
    """Flags first, then the preferences, then the environment and auto-detection."""
    python, script = args.python, args.backend_script
    if preferred is not None:
        python, script = python or preferred.python, script or preferred.script
    return backend_setup.resolve_backend(python, script)
