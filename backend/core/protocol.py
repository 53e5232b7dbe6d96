"""The JSON-lines progress protocol between long backend commands and their callers.

With ``--json-progress`` a command writes one JSON object per line on stdout, nothing else
(human-readable logging goes to stderr). Every object has an ``event``:

``start``     {"event": "start", "command": "fit", "version": "0.1.0", "device": "cpu"}
``progress``  {"event": "progress", "stage": "optimise", "iteration": 12, "total": 300,
               "loss": 0.0312, "eta_s": 41.5, "elapsed_s": 7.9, "since_best": 3, "patience": 20}
              stage is one of: load, init, search, optimise, variation, render, report. loss and eta_s may
              be null.
              since_best and patience, the optimiser's (else null): the steps since its best loss last
              moved, and the steps without a new best after which it ends before its total (0: none
              now: a stall above its last learning rate lowers the rate instead);
              its event of iteration = total says it has ended, early or not.
``warning``   {"event": "warning", "message": "...", "file": "path or null"} (also a ``warning:`` line on
              the log, stderr, as in the terminal: a caller's log of the run holds it)
``result``    {"event": "result", "out_dir": "...", "params": ".../params.json",
               "files": {"reflection": ..., "transmission": ..., "report": ..., "metrics": ...},
               "metrics": {...}, "wall_s": 52.1}
``error``     {"event": "error", "kind": "input" | "internal" | "cancelled", "message": "...",
               "file": "path or null"}

A batch of fits (``python -m backend batch``) adds two events and ends with its own ``result``:

``pair``      {"event": "pair", "name": "denim", "status": "done", "attempt": 1, "reason": null,
               "out_dir": ".../denim", "wall_s": 61.2}
              status is one of: started, done, kept (complete from an earlier run, --resume),
              retrying (the reason says why; a second attempt follows), failed, cancelled.
``batch``     {"event": "batch", "total": 40, "done": 12, "running": 2, "failed": 1, "queued": 25,
               "eta_s": 930.0, "elapsed_s": 612.4}
              done counts kept pairs too; eta_s is null until a fit has finished.
``result``    {"event": "result", "out_dir": "...", "catalogue": ".../catalogue.json",
               "csv": ".../catalogue.csv", "done": 39, "failed": 1, "wall_s": 2710.3}

Exit codes: 0 success, 2 bad input (the error names the file and the problem), 1 internal error,
130 cancelled (the best parameters so far are kept in :data:`PARTIAL_PARAMS_FILE`, or, once the fit
has ended, in its params.json). A batch exits with the number of pairs that failed
(:func:`failed_exit_code`, capped at 125; the Blender batch counts the same way), 2 when it cannot
start, 130 when stopped. The last line of a run is always a ``result`` or an ``error``.

Photos that look swapped are a warning, or bad input with ``fit --strict``; either message holds
:data:`SWAPPED_PHOTOS`, which a caller looks for to offer the swap.

Stopping, the other way: SIGINT/SIGTERM from a terminal; a caller that cannot send a catchable
signal (Windows has none: ``Popen.terminate`` kills) starts ``fit --stop-on-stdin`` with a pipe on
stdin and writes :data:`STOP_REQUEST` and a newline; closing that pipe (the caller ended) stops the
fit too. This module is plain Python (the Blender add-on parses and writes the same lines).
"""
from __future__ import annotations

import json
import sys
import time
from typing import IO, Any

from .. import __version__

STAGES = ("load", "init", "search", "optimise", "variation", "render", "report")
PAIR_STATUSES = ("started", "done", "kept", "retrying", "failed", "cancelled")
EXIT_OK, EXIT_INTERNAL, EXIT_INPUT, EXIT_CANCELLED = 0, 1, 2, 130
STOP_REQUEST = "stop"  # a line on the stdin of ``fit --stop-on-stdin``
PARTIAL_PARAMS_FILE = "params.partial.json"  # a cancelled fit's best parameters so far, in its --out folder
SWAPPED_PHOTOS = "the photos may be swapped"  # in the warning or the error of a pair whose lighting reads reversed
MAX_FAILED_EXIT = 125  # exit codes above are the shell's (126: not executable, 128 + N: killed by signal N)


def failed_exit_code(failed: int) -> int:
    """A batch's exit code: the number of failed pairs, capped at :data:`MAX_FAILED_EXIT`."""
    return min(failed, MAX_FAILED_EXIT)


class ProtocolError(ValueError):
    pass


def encode(event: str, **fields: Any) -> str:
    return json.dumps({"event": event, **fields}, separators=(",", ":"), allow_nan=False)


def decode(line: str) -> dict:
    """Parses one protocol line; raises ProtocolError for anything that is not an event object."""
    try:
        obj = json.loads(line)
    except json.JSONDecodeError as exc:
        raise ProtocolError(f"not a JSON line: {line[:200]!r} ({exc})") from None
    if not isinstance(obj, dict) or not isinstance(obj.get("event"), str):
        raise ProtocolError(f"not a protocol event: {line[:200]!r}")
    return obj


class Reporter:
    """Writes progress either as JSON lines (machine callers) or as a terminal progress bar."""

    def __init__(self, json_lines: bool = False, stream: IO[str] | None = None, log: IO[str] | None = None):
        self.json_lines = json_lines
        self.stream = stream or sys.stdout
        self.log = log or sys.stderr
        self.started = time.monotonic()
        self._bar_open = False
        self._bar_width = 0

    def elapsed(self) -> float:
        return time.monotonic() - self.started

    def _emit(self, event: str, **fields):
        self.stream.write(encode(event, **fields) + "\n")
        self.stream.flush()

    def start(self, command: str, **fields):
        if self.json_lines:
            self._emit("start", command=command, version=__version__, **fields)

    def progress(self, stage: str, iteration: int, total: int, loss: float | None = None,
                 eta_s: float | None = None, since_best: int | None = None, patience: int | None = None):
        if stage not in STAGES:
            raise ProtocolError(f"unknown stage {stage!r}")
        loss = None if loss is None or loss != loss else float(loss)
        if self.json_lines:
            self._emit("progress", stage=stage, iteration=int(iteration), total=int(total), loss=loss,
                       eta_s=None if eta_s is None else round(float(eta_s), 2), elapsed_s=round(self.elapsed(), 2),
                       since_best=None if since_best is None else int(since_best),
                       patience=None if patience is None else int(patience))
            return
        text = f"{iteration}/{total}"
        if loss is not None:
            text += f" loss {loss:.4f}"
        if eta_s is not None:
            text += f" eta {eta_s:5.0f}s"
        self._bar(stage, iteration, total, text)

    def pair(self, name: str, status: str, attempt: int = 1, reason: str | None = None,
             out_dir: str | None = None, wall_s: float | None = None):
        """One pair of a batch changed state (on the terminal: finished and failing pairs only)."""
        if status not in PAIR_STATUSES:
            raise ProtocolError(f"unknown pair status {status!r}")
        wall_s = None if wall_s is None else round(float(wall_s), 2)
        if self.json_lines:
            self._emit("pair", name=name, status=status, attempt=int(attempt), reason=reason, out_dir=out_dir,
                       wall_s=wall_s)
        elif status not in ("started", "kept"):
            details = [f"attempt {attempt}"] if attempt > 1 else []
            details += [f"{wall_s:.0f} s"] if wall_s is not None else []
            text = f"{status:<9} {name}" + (f" ({', '.join(details)})" if details else "")
            self.info(text + (f": {reason}" if reason else f" -> {out_dir}" if out_dir else ""))

    def batch(self, total: int, done: int, running: int, failed: int, queued: int, eta_s: float | None = None):
        """The whole batch: pairs done (kept ones included), running, failed, waiting, and the time left."""
        eta_s = None if eta_s is None else round(float(eta_s), 1)
        if self.json_lines:
            self._emit("batch", total=int(total), done=int(done), running=int(running), failed=int(failed),
                       queued=int(queued), eta_s=eta_s, elapsed_s=round(self.elapsed(), 2))
            return
        text = f"{done}/{total} done, {running} running, {failed} failed"
        if eta_s is not None:
            text += f", eta {_duration(eta_s)}"
        self._bar("batch", done + failed, total, text)

    def _bar(self, label: str, done: int, total: int, text: str):
        width = 30
        filled = int(width * done / max(total, 1))
        line = f"{label:>8} [{'#' * filled}{'.' * (width - filled)}] {text}"
        self.log.write("\r" + line.ljust(self._bar_width))  # spaces cover the end of a longer earlier line
        self.log.flush()
        self._bar_open, self._bar_width = True, len(line)

    def _close_bar(self):
        if self._bar_open:
            self.log.write("\n")
            self._bar_open, self._bar_width = False, 0

    def info(self, message: str):
        self._close_bar()
        self.log.write(message + "\n")
        self.log.flush()

    def warning(self, message: str, file: str | None = None):
        if self.json_lines:
            self._emit("warning", message=message, file=file)
        self.info(f"warning: {message}")

    def result(self, **fields):
        self._close_bar()
        if self.json_lines:
            self._emit("result", wall_s=round(self.elapsed(), 2), **fields)

    def error(self, kind: str, message: str, file: str | None = None):
        self._close_bar()
        if self.json_lines:
            self._emit("error", kind=kind, message=message, file=file)
        self.log.write(f"error: {message}\n")
        self.log.flush()


def _duration(seconds: float) -> str:
    """``41s``, ``12m05s``, ``3h07m``: a time left for the terminal."""
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"
