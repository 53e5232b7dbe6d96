"""The JSON-lines progress protocol between long backend commands and their callers.

With ``--json-progress`` a command writes one JSON object per line on stdout, nothing else
(human-readable logging goes to stderr). Every object has an ``event``:

``start``     {"event": "start", "command": "fit", "version": "0.1.0", "device": "cpu"}
``progress``  {"event": "progress", "stage": "optimise", "iteration": 12, "total": 300,
               "loss": 0.0312, "eta_s": 41.5, "elapsed_s": 7.9}
              stage is one of: load, init, search, optimise, render, report. loss and eta_s may be null.
``warning``   {"event": "warning", "message": "...", "file": "path or null"}
``result``    {"event": "result", "out_dir": "...", "params": ".../params.json",
               "files": {"reflection": ..., "transmission": ..., "report": ..., "metrics": ...},
               "metrics": {...}, "wall_s": 52.1}
``error``     {"event": "error", "kind": "input" | "internal" | "cancelled", "message": "...",
               "file": "path or null"}

Exit codes: 0 success, 2 bad input (the error names the file and the problem), 1 internal error,
130 cancelled (partial results are kept, see the fit command). The last line of a run is always a
``result`` or an ``error``.

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

STAGES = ("load", "init", "search", "optimise", "render", "report")
EXIT_OK, EXIT_INTERNAL, EXIT_INPUT, EXIT_CANCELLED = 0, 1, 2, 130
STOP_REQUEST = "stop"  # a line on the stdin of ``fit --stop-on-stdin``


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

    def elapsed(self) -> float:
        return time.monotonic() - self.started

    def _emit(self, event: str, **fields):
        self.stream.write(encode(event, **fields) + "\n")
        self.stream.flush()

    def start(self, command: str, **fields):
        if self.json_lines:
            self._emit("start", command=command, version=__version__, **fields)

    def progress(self, stage: str, iteration: int, total: int, loss: float | None = None,
                 eta_s: float | None = None):
        if stage not in STAGES:
            raise ProtocolError(f"unknown stage {stage!r}")
        loss = None if loss is None or loss != loss else float(loss)
        if self.json_lines:
            self._emit("progress", stage=stage, iteration=int(iteration), total=int(total), loss=loss,
                       eta_s=None if eta_s is None else round(float(eta_s), 2), elapsed_s=round(self.elapsed(), 2))
            return
        width = 30
        done = int(width * iteration / max(total, 1))
        text = f"\r{stage:>8} [{'#' * done}{'.' * (width - done)}] {iteration}/{total}"
        if loss is not None:
            text += f" loss {loss:.4f}"
        if eta_s is not None:
            text += f" eta {eta_s:5.0f}s"
        self.log.write(text)
        self.log.flush()
        self._bar_open = True

    def _close_bar(self):
        if self._bar_open:
            self.log.write("\n")
            self._bar_open = False

    def info(self, message: str):
        self._close_bar()
        self.log.write(message + "\n")
        self.log.flush()

    def warning(self, message: str, file: str | None = None):
        if self.json_lines:
            self._emit("warning", message=message, file=file)
        else:
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
