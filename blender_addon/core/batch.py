"""The batch fit (no bpy): every ``<name>_R.* / <name>_T.*`` pair of a folder into a material library.

The pairs are fitted one after another by the sidebar's executor (core/batch_queue.py, which runs
the backend's job model, core/pair_jobs.py), here in a blocking loop that writes a line per pair.
Each good pair is fitted in a new result folder (captures.new_fit) and handed to a *library*
(scene/materials.py's AssetLibrary: ``add(name, params, width_cm, fit_folder, description,
preview) -> material name`` and ``write(path)``), which makes one asset material per pair and
writes them all into one .blend. A pair with a missing partner (or two candidates for one side), or
whose fit fails, is reported and skipped. The exit code is the number of failed pairs (0: all
good; capped at 125). A problem that stops the batch before any fit (bad arguments, no folder, no
pairs at all, an unusable rig or backend) exits with 1; when the library cannot be written, every
fitted pair counts as failed.

The backend is chosen as for the panel: ``--python`` / ``--backend-script``, else the add-on
preferences (the extension's bundled backend when nothing is set), else ``WOVEN_FABRIC_PYTHON`` /
``WOVEN_FABRIC_BACKEND_SCRIPT``, else auto-detection.

``--from-results DIR`` builds the library from fits made elsewhere (``python -m backend batch`` on a
cluster, or ``fit``) without fitting and without a backend: every complete results folder in DIR
(or DIR itself, when it is one) becomes an asset material named after its folder; a folder that
holds some result files but not all (a copy cut short) counts as failed; other folders (``logs``,
names starting with a dot) are passed by.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from . import backend_bridge, backend_setup, batch_queue, captures, declarations, rig_settings
from .batch_queue import BatchOptions

CLI_COMMAND = "fabric_fit"
LIBRARY_NAME = "fabric_materials.blend"
POLL_S = 0.05  # how often the loop reads the running fit


@dataclass
class BatchReport:
    fitted: list[tuple[str, str, str]] = field(default_factory=list)   # (pair, material, result folder)
    failed: list[tuple[str, str]] = field(default_factory=list)        # (pair, reason)
    library: Path | None = None

    @property
    def exit_code(self) -> int:
        return declarations.protocol().failed_exit_code(len(self.failed))


def run_batch(folder: str | Path, library_path: str | Path | None = None, *, backend: backend_bridge.Backend,
              library, options: BatchOptions | None = None, fits_parent: str | Path | None = None,
              log=print) -> BatchReport:
    """Fits every pair of ``folder`` into ``library`` and writes it to ``library_path``; never raises
    for a pair."""
    options = options or BatchOptions()
    folder = Path(folder).resolve()
    report = BatchReport()
    try:
        jobs = batch_queue.folder_pairs(folder)
    except ValueError as exc:  # no photo named as a pair (main has checked that it is a folder)
        report.failed.append(("", str(exc)))
        log(f"ERROR {exc}")
        return report
    skipped = [job for job in jobs if job.finished]
    for job in skipped:
        log(f"SKIP {job.name}: {job.reason}")
    report.failed += [(job.name, job.reason) for job in skipped]
    if len(skipped) == len(jobs):
        return report

    rig_values = _rig_file(options.rig_json)
    if options.width_cm:
        rig_values["width_cm"] = options.width_cm
    queue = _fit_all(folder, jobs, backend, library, rig_settings.rig_dict(rig_values), options,
                     Path(fits_parent) if fits_parent else folder / "fabric_fits", log)
    report.fitted += [(job.name, job.material, job.out_dir) for job in queue.jobs if job.state == batch_queue.DONE]
    report.failed += [(job.name, job.reason) for job in queue.failures() if job.reflection is not None]
    _write_library(report, library, Path(library_path) if library_path else folder / LIBRARY_NAME, options.overwrite,
                   log)
    return report


def _fit_all(folder: Path, jobs: list, backend, library, rig: dict, options: BatchOptions, fits_parent: Path,
             log) -> batch_queue.BatchQueue:
    """Fits the pairs one after another (the sidebar's queue, polled until it is done), a line each."""
    lines = _PairLines(jobs, log)

    def add(job, params, description, preview):
        return library.add(job.name, params, rig.get("width_cm"), Path(job.out_dir), description, preview)

    queue = batch_queue.BatchQueue(folder, backend, fits_parent, rig, add, options, jobs=jobs, on_event=lines.event,
                                   on_end=lines.end).start()
    try:
        while not queue.done:
            queue.poll()
            time.sleep(POLL_S)
    except KeyboardInterrupt:  # Ctrl+C: the backend runs in its own session and must be stopped here
        queue.cancel()
        raise
    return queue


class _PairLines:
    """The headless batch's lines about the pairs being fitted: each phase of the fit (in the words
    and with the time left of the panel's bar, backend/core/progress.py), warnings, how each ended."""

    def __init__(self, jobs: list, log):
        fitted = [job for job in jobs if not job.finished]
        self.prefix = {job.name: f"[{number}/{len(fitted)}] {job.name}" for number, job in enumerate(fitted, 1)}
        self.progress: dict[str, object] = {}   # pair -> its FitProgress
        self.log = log

    def event(self, job, event: dict) -> None:
        now = time.monotonic()
        progress = self.progress.setdefault(job.name, declarations.fit_progress().FitProgress(started=now))
        before = progress.phase
        progress.update(event, now)
        if event["event"] == "progress" and progress.phase is not before:
            self.log(f"     {self.prefix[job.name]}: {progress.describe(now)}")
        elif event["event"] == "warning":
            self.log(f"WARN {self.prefix[job.name]}: {event.get('message')}")

    def end(self, job, fit) -> None:
        if job.state == batch_queue.DONE:
            self.log(f"OK   {self.prefix[job.name]}: material {job.material} ({job.out_dir})")
            return
        if fit is not None and fit.details:
            self.log(fit.details)
        self.log(f"FAIL {self.prefix[job.name]}: {job.reason}")


def import_results(results: str | Path, library_path: str | Path | None = None, *, library,
                   width_cm: float | None = None, overwrite: bool = False, log=print) -> BatchReport:
    """Adds every complete results folder of ``results`` to ``library`` (no fit; see the module
    docstring) and writes it to ``library_path``; never raises for a folder."""
    results = Path(results).resolve()
    report = BatchReport()
    if not declarations.missing_result_files(results):
        folders = [results]
    else:
        folders = [f for f in sorted(results.iterdir()) if f.is_dir() and not f.name.startswith(".")]
    expected = declarations.result_files()
    for folder in folders:
        missing = declarations.missing_result_files(folder)
        if len(missing) == len(expected):
            continue  # not a results folder (logs/, anything else)
        try:
            if missing:
                raise ValueError(f"incomplete results folder {folder}: no {', '.join(missing)}")
            params = captures.read_fit_params({"out_dir": str(folder)})
            material = library.add(folder.name, params, width_cm, folder, _description(params, folder),
                                   folder / "reflection.png")
        except Exception as exc:  # one folder's trouble never stops the library
            report.failed.append((folder.name, str(exc) or type(exc).__name__))
            log(f"FAIL {folder.name}: {report.failed[-1][1]}")
            continue
        report.fitted.append((folder.name, material, str(folder)))
        log(f"OK   {folder.name}: material {material}")
    if not report.fitted and not report.failed:
        report.failed.append(("", f"{results}: no fit results (folders with {', '.join(expected)})"))
        log(f"ERROR {report.failed[-1][1]}")
    _write_library(report, library, Path(library_path) if library_path else results / LIBRARY_NAME, overwrite, log)
    return report


def _description(params: dict, folder: Path) -> str:
    photos = params.get("photos") if isinstance(params.get("photos"), dict) else {}
    names = [Path(str((photos.get(side) or {}).get("path") or "")).name for side in ("reflection", "transmission")]
    source = f" from {names[0]} and {names[1]}" if all(names) else ""
    return f"Woven fabric fitted{source} ({folder})"


def _write_library(report: BatchReport, library, target: Path, overwrite: bool, log) -> None:
    """Writes the fitted materials (when there are any) to ``target``, or a new name beside it; when it
    cannot, every fitted pair counts as failed."""
    if not report.fitted:
        return
    target = target if overwrite else captures.unused_path(target)
    try:
        library.write(target)
    except (OSError, RuntimeError) as exc:
        log(f"ERROR cannot write {target}: {exc}")
        report.failed.extend((name, f"not saved: {exc}") for name, _, _ in report.fitted)
        report.fitted.clear()
        return
    report.library = target
    log(f"Wrote {len(report.fitted)} material(s) to {target}")


def _rig_file(path: Path | None) -> dict:
    """The rig's settings from ``--rig RIG.json`` over the spec's defaults."""
    if not path:
        return rig_settings.defaults()
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"--rig {path}: cannot read ({exc})") from None
    return {**rig_settings.defaults(), **data}


# -- command line -------------------------------------------------------------------------------

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=f"blender --command {CLI_COMMAND}",
        description="Fit every <name>_R.* / <name>_T.* photo pair of a folder and save one asset material "
                    "per pair in a .blend. Exit code: the number of failed pairs.")
    parser.add_argument("folder", nargs="?", help="folder with the photo pairs")
    parser.add_argument("--from-results", metavar="DIR", help="no fitting: make the materials from the results "
                        "folders in DIR (python -m backend batch --out DIR, or fit --out folders)")
    parser.add_argument("--out", help="the .blend to write (default: FOLDER/fabric_materials.blend or "
                                      "DIR/fabric_materials.blend; an existing file is kept and a new name chosen "
                                      "unless --overwrite)")
    parser.add_argument("--fits", help="parent of the per-pair result folders (default: FOLDER/fabric_fits)")
    _add_fit_options(parser)
    parser.add_argument("--rig", type=Path, help="RIG.json (CaptureRig settings; default: the spec's rig)")
    parser.add_argument("--width-cm", type=float, help="real width of the photographed square in centimetres")
    parser.add_argument("--timeout", type=float, help="seconds allowed per pair (default: no limit)")
    parser.add_argument("--python", default="", help="interpreter for the backend (default: preferences, "
                                                     "$WOVEN_FABRIC_PYTHON, auto-detection)")
    parser.add_argument("--backend-script", default="", help="script run instead of 'python -m backend'")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    return parser


# The fit options the batch passes on to every pair: their flags, help and checks are the backend's
# declaration's (backend/core/fit_options.py), so a value the backend would refuse is refused here.
FIT_FLAGS = ("pattern", "iterations", "size", "device", "output_spp", "strict")


def _add_fit_options(parser: argparse.ArgumentParser) -> None:
    declared = declarations.fit_options()
    for name in FIT_FLAGS:
        option = declared.OPTIONS[name]
        if option.kind == declared.FLAG:
            parser.add_argument(option.flag, action="store_true", help=option.help)
            continue

        def parse(text: str, option=option):
            try:
                return option.parse(text)
            except ValueError as exc:
                raise argparse.ArgumentTypeError(str(exc)) from None

        parse.__name__ = name
        parser.add_argument(option.flag, type=parse, metavar=option.metavar, help=option.help,
                            choices=backend_bridge.DEVICES if name == "device" else None)


def _fit_options(args) -> dict:
    """The fit options given on the command line (the others stay the backend's defaults)."""
    return {name: getattr(args, name) for name in FIT_FLAGS if getattr(args, name) not in (None, False)}


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
        if bool(args.folder) == bool(args.from_results):
            raise ValueError("give either the folder of photo pairs or --from-results DIR")
        if args.from_results:
            if not Path(args.from_results).is_dir():
                raise ValueError(f"{args.from_results}: not a folder")
            report = import_results(args.from_results, args.out, library=library, width_cm=args.width_cm,
                                    overwrite=args.overwrite)
            return _summary(report, "imported", started)
        backend = _backend(args, preferred_backend())
        options = BatchOptions(_fit_options(args), args.rig, args.width_cm, args.timeout, args.overwrite)
        if not Path(args.folder).is_dir():
            raise ValueError(f"{args.folder}: not a folder")
        report = run_batch(args.folder, args.out, backend=backend, library=library, options=options,
                           fits_parent=args.fits)
    except (backend_bridge.BackendError, ValueError, OSError) as exc:
        print(f"ERROR {exc}", file=sys.stderr)
        return 1
    return _summary(report, "fitted", started)


def _summary(report: BatchReport, done: str, started: float) -> int:
    """Prints the batch's last lines and returns its exit code."""
    print(f"{len(report.fitted)} {done}, {len(report.failed)} failed in {time.monotonic() - started:.1f} s"
          + (f"; library {report.library}" if report.library else ""))
    for name, reason in report.failed:
        print(f"  failed {name or '(folder)'}: {reason}")
    return report.exit_code


def _backend(args, preferred: backend_bridge.Backend | None) -> backend_bridge.Backend:
    """Flags first, then the preferences (the bundled backend with its packages included), then the
    environment and auto-detection."""
    python, script = args.python, args.backend_script
    if preferred is not None and not python:
        return dataclasses.replace(preferred, script=script or preferred.script)
    return backend_setup.resolve_backend(python, script or (preferred.script if preferred else ""))
