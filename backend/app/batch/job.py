"""One pair's fit as a task: the photos in as bytes, the results folder's files out as bytes.

:func:`run_fit_job` is what a Ray worker runs for a pair. It writes the photos into a temporary
folder on whichever machine Ray chose, runs :func:`backend.app.folder.fit_reporting` there (the
function behind ``python -m backend fit``: the options, the files and the exit codes are the
command's) and returns a :class:`FitOutcome`. Only the driver writes DIR (output.py), so no machine
of a cluster needs to see the photo folder or DIR. The fit sees temporary copies of the photos; the
paths it records (params.json's ``photos``, warnings, errors) are mapped back to the originals.

``status`` of the outcome, one of the job model's outcomes (backend/core/pair_jobs.py): done (exit
code 0), input (2: the photos are bad), internal (1), cancelled (Ray cancelled the task: Ctrl+C on
the driver), timeout (no result after ``timeout_s``: the fit is stopped through its own
``should_stop``); lost is the driver's (the engine lost the task).

The fit runs in the worker process, not as a ``python -m backend fit`` subprocess, because a fresh
process pays again for what a worker keeps: importing torch, the five weave signatures the lattice
search renders once per process (``texture.candidates.signatures``) and the renderer's compiled
kernels. Isolation does not suffer: each worker is its own process, and a worker that dies (a
crash, an out-of-memory kill) is reported to the driver, which tries the pair again. Ray's cancel
raises KeyboardInterrupt in the worker, which stops the fit between two torch operations. Threads:
each task sets torch's and OpenCV's to its ``threads`` (``--cpus-per-fit``; Ray sets
OMP_NUM_THREADS to the task's CPUs when it starts the worker).
"""
from __future__ import annotations

import contextlib
import io
import json
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import torch

from ...core.pair_jobs import CANCELLED, DONE, INPUT, INTERNAL, TIMEOUT, PairJob
from ...core.protocol import EXIT_CANCELLED, EXIT_INPUT, EXIT_OK, ProtocolError, Reporter, decode
from ..folder import FolderFitOptions, fit_reporting


@dataclass(frozen=True)
class FitJob:
    name: str
    reflection: str                 # the photos' own paths (recorded in params.json and in messages)
    transmission: str
    reflection_bytes: bytes
    transmission_bytes: bytes
    options: dict = field(default_factory=dict)  # FolderFitOptions fields (except rig)
    rig_text: str | None = None     # a RIG.json's text
    threads: int = 1
    timeout_s: float | None = None
    out_dir: str = ""               # where the driver will put the results (named in the log)

    @classmethod
    def of(cls, pair: PairJob, out_dir: Path, options: dict, rig_text: str | None, threads: int,
           timeout_s: float | None) -> FitJob:
        """The job of a pair, its photos read (OSError when one cannot be)."""
        return cls(pair.name, str(pair.reflection), str(pair.transmission), pair.reflection.read_bytes(),
                   pair.transmission.read_bytes(), options, rig_text, threads, timeout_s, str(out_dir))


@dataclass
class FitOutcome:
    name: str
    status: str                                  # an outcome of core/pair_jobs.py (lost: the driver's)
    reason: str | None = None                    # the fit's error line, or why the task ended
    files: dict[str, bytes] = field(default_factory=dict)  # the results folder (done only)
    log: str = ""                                # warnings, the error, a traceback


def run_fit_job(job: FitJob) -> FitOutcome:
    """Fits one pair (see the module docstring); never raises for a failed fit."""
    torch.set_num_threads(job.threads)
    cv2.setNumThreads(job.threads)
    deadline = None if job.timeout_s is None else time.monotonic() + job.timeout_s
    with tempfile.TemporaryDirectory(prefix="fabric-batch-") as tmp:
        tmp = Path(tmp)
        photos, out = tmp / "photos", tmp / "out"
        photos.mkdir()
        reflection, transmission = photos / Path(job.reflection).name, photos / Path(job.transmission).name
        reflection.write_bytes(job.reflection_bytes)
        transmission.write_bytes(job.transmission_bytes)
        options = dict(job.options)
        if job.rig_text is not None:
            (tmp / "rig.json").write_text(job.rig_text)
            options["rig"] = str(tmp / "rig.json")
        events, log = io.StringIO(), io.StringIO()
        reporter = Reporter(json_lines=True, stream=events, log=log)
        moves = {photos: Path(job.reflection).parent, out: Path(job.out_dir or out)}
        restore = _path_restorer(moves)
        try:
            with contextlib.redirect_stderr(log):  # the traceback of an internal error goes to the log
                code = fit_reporting(reflection, transmission, out, FolderFitOptions(**options), reporter,
                                     lambda: deadline is not None and time.monotonic() > deadline)
        except KeyboardInterrupt:  # Ray's cancel
            return FitOutcome(job.name, CANCELLED, "cancelled while fitting", log=restore(log.getvalue()))
        error, text = _error_and_log(events.getvalue(), log.getvalue())
        if code == EXIT_OK:
            files = {path.name: path.read_bytes() for path in sorted(out.iterdir()) if path.is_file()}
            if "params.json" in files:
                files["params.json"] = _path_restorer(moves, json_escaped=True)(files["params.json"].decode()).encode()
            return FitOutcome(job.name, DONE, files=files, log=restore(text))
        if code == EXIT_CANCELLED and deadline is not None and time.monotonic() > deadline:
            status, error = TIMEOUT, f"no result after {job.timeout_s:g} s (--timeout)"
        else:
            status = {EXIT_INPUT: INPUT, EXIT_CANCELLED: CANCELLED}.get(code, INTERNAL)
        return FitOutcome(job.name, status, restore(error or f"the fit ended with exit code {code}"), log=restore(text))


def _error_and_log(event_lines: str, log_text: str) -> tuple[str | None, str]:
    """The fit's error message (if any) and a readable log: its warnings, then what it wrote to stderr."""
    error, lines = None, []
    for line in event_lines.splitlines():
        try:
            event = decode(line)
        except ProtocolError:
            continue
        if event["event"] == "warning":
            lines.append(f"warning: {event['message']}")
        elif event["event"] == "error":
            error = event["message"]
    return error, "\n".join(lines + [log_text.rstrip("\n")]).strip("\n") + "\n"


def _path_restorer(moves: dict[Path, Path], json_escaped: bool = False):
    """A function that puts the real folders for the temporary ones into a text (JSON-escaped in a JSON file).
    The temporary folders have random names, so nothing else in a text matches them."""
    def form(path: Path) -> str:
        return json.dumps(str(path))[1:-1] if json_escaped else str(path)

    pairs = [(form(temporary), form(real)) for temporary, real in moves.items()]

    def restore(text: str) -> str:
        for old, new in pairs:
            text = text.replace(old, new)
        return text

    return restore
