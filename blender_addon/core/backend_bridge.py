"""The backend as a subprocess, read through the JSON-lines progress protocol (no bpy, no torch).

A fit is ``<python> -m backend fit REFLECTION TRANSMISSION --out DIR --json-progress ...`` run with
``PYTHONPATH`` pointing at the folder that holds the ``backend`` package (see paths.py). Blender
must never wait on it, so :class:`FitProcess` reads stdout and stderr on two daemon threads; the
caller (a modal operator's timer, the batch loop) calls :meth:`FitProcess.poll` as often as it
likes and gets the new events without blocking, and the bar over the whole fit
(backend/core/progress.py) in ``progress`` and ``status``.

Outcomes, each with a message a person can read:

- ``succeeded``: a ``result`` event and exit code 0;
- ``failed``: an ``error`` event (its message, and the file it names), or a crash (a non-zero exit
  without an error event: the exit code or signal and the last lines of stderr), or an exit
  without a result, or a process that could not be started at all;
- ``cancelled``: :meth:`FitProcess.request_cancel` writes the protocol's stop line on the
  backend's stdin (``fit --stop-on-stdin``: it then keeps its best parameters, the protocol's
  partial file); unlike SIGTERM, that works on Windows too. Still alive after a grace period, the
  process is killed (on POSIX its whole session), and always reaped. Should Blender end without
  cancelling, the pipe closes and the backend stops the same way.

A stdout line that is not a protocol event (a library printing on stdout) becomes a ``warning``
event saying so, and is quoted in the error if the run then ends badly.

Which backend runs is a :class:`Backend` (an interpreter, optionally a script replacing ``-m
backend``, and the bundled backend's package folders); backend_setup.py chooses and checks it.
"""
from __future__ import annotations

import atexit
import collections
import os
import queue
import signal
import subprocess
import threading
import time
import weakref
from dataclasses import dataclass, field
from pathlib import Path

from . import declarations, paths

DEVICES = ("cpu", "cuda")

# The stop line, then a kill after this long: an iteration (or a render tile) in progress ends first,
# and the best parameters are written.
CANCEL_GRACE_S = 10.0
EXIT_WITHOUT_EOF_S = 2.0   # a grandchild may hold stdout open after the backend exited
STDERR_LINES = 200


class BackendError(RuntimeError):
    """The backend cannot be used (interpreter missing, wrong settings); the message says why."""


# -- which backend ----------------------------------------------------------------------------

@dataclass(frozen=True)
class Backend:
    """How to start the backend: an interpreter and, optionally, a script replacing ``-m backend``.

    With ``packages`` the interpreter runs isolated (``-S``: none of its own site-packages, no user
    site; ``-P``: not the working folder) and imports from the backend's folder, these folders and
    its standard library, nothing else: Blender's own Python with the extension's installed wheels
    (and, for the GPU route, the CUDA PyTorch folder first). Without, it runs with its own
    environment (an external Python that has PyTorch). ``label`` says in words which backend this
    is (for the preferences); it is not part of the identity.
    """

    python: str
    script: str = ""
    packages: tuple[str, ...] = ()
    label: str = field(default="", compare=False)

    def python_command(self, arguments: list[str]) -> list[str]:
        """The interpreter with its isolation flags, then ``arguments``."""
        return [self.python, *(("-S", "-P") if self.packages else ()), *arguments]

    def command(self, arguments: list[str]) -> list[str]:
        entry = [self.script] if self.script else ["-m", "backend"]
        return self.python_command([*entry, *arguments])

    def environment(self) -> dict[str, str]:
        """The caller's environment with the backend package first on PYTHONPATH (and with ``packages``
        nothing else), unbuffered output."""
        env = dict(os.environ)
        root = str(paths.backend_root())
        if self.packages:
            env["PYTHONPATH"] = os.pathsep.join([root, *self.packages])
            env["PYTHONNOUSERSITE"] = "1"
        else:
            env["PYTHONPATH"] = os.pathsep.join([root, *([env["PYTHONPATH"]] if env.get("PYTHONPATH") else [])])
        env["PYTHONUNBUFFERED"] = "1"
        # A PYTHONHOME meant for Blender's bundled Python would break any other interpreter.
        env.pop("PYTHONHOME", None)
        return env


# -- the fit command --------------------------------------------------------------------------

@dataclass(frozen=True)
class FitRequest:
    """The arguments of one ``fit`` run. None means: the backend's default."""

    reflection: Path
    transmission: Path
    out_dir: Path
    pattern: str = "auto"
    iterations: int | None = None
    size: int | None = None
    device: str | None = None
    rig_json: Path | None = None
    output_spp: int | None = None   # samples per pixel of the fit's re-renders (None: the backend's default)
    strict: bool = False            # refuse photos that look swapped (instead of a warning)

    def arguments(self) -> list[str]:
        patterns = declarations.fit_patterns()
        if self.pattern not in patterns:
            raise BackendError(f"Unknown weave pattern {self.pattern!r}; expected one of {', '.join(patterns)}")
        if self.device is not None and self.device not in DEVICES:
            raise BackendError(f"Unknown device {self.device!r}; expected one of {', '.join(DEVICES)}")
        options = declarations.fit_options()  # the backend's flags and checks for these values
        values = {"pattern": self.pattern, "iterations": self.iterations, "size": self.size, "device": self.device,
                  "rig": self.rig_json, "output_spp": self.output_spp, "strict": self.strict}
        try:
            flags = options.command_line(values)
        except options.FitOptionError as exc:
            raise BackendError(str(exc)) from None
        return ["fit", str(self.reflection), str(self.transmission), "--out", str(self.out_dir), *flags,
                "--json-progress", "--stop-on-stdin"]


def describe_exit(code: int) -> str:
    if code < 0:
        try:
            return f"killed by signal {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


RUNNING, SUCCEEDED, FAILED, CANCELLED = "running", "succeeded", "failed", "cancelled"


@dataclass(eq=False)  # identity semantics: a run is hashable (kept in a WeakSet)
class FitProcess:
    """One backend run. Call start(), then poll() until ``done``; request_cancel() at any time."""

    backend: Backend
    arguments: list[str]
    log_path: Path | None = None  # the whole stderr is written here when the run ends
    request: FitRequest | None = None  # what was asked, when started through fit()
    state: str = "new"
    progress: float = 0.0
    status: str = "Not started"
    result: dict | None = None
    error: str = ""
    details: str = ""             # stderr tail or the malformed lines, for the console and the log
    warnings: list[str] = field(default_factory=list)
    returncode: int | None = None

    def __post_init__(self):
        self._process: subprocess.Popen | None = None
        self._lines: queue.Queue = queue.Queue()
        self._stderr: collections.deque = collections.deque(maxlen=STDERR_LINES)
        self._stderr_all: list[str] = []
        self._threads: list[threading.Thread] = []
        self._eof = False
        self._exited_at: float | None = None
        self._cancel_deadline: float | None = None
        self._error_event: dict | None = None
        self._malformed: list[str] = []
        self._timed_out: float | None = None
        self._whole = None  # the bar over all stages (backend/core/progress.py), from start()

    @classmethod
    def fit(cls, backend: Backend, request: FitRequest, log_path: Path | None = None) -> "FitProcess":
        return cls(backend, request.arguments(), log_path=log_path, request=request)

    # -- life cycle ---------------------------------------------------------------------------
    @property
    def done(self) -> bool:
        return self.state in (SUCCEEDED, FAILED, CANCELLED)

    @property
    def pid(self) -> int | None:
        return self._process.pid if self._process else None

    def start(self) -> "FitProcess":
        """Starts the process; a failure to start is a ``failed`` state, not an exception."""
        command = self.backend.command(self.arguments)
        kwargs = {"start_new_session": True} if os.name == "posix" else {
            "creationflags": getattr(subprocess, "CREATE_NEW_PROCESS_GROUP", 0)}
        try:
            self._process = subprocess.Popen(
                command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                env=self.backend.environment(), text=True, encoding="utf-8", errors="replace", bufsize=1,
                **kwargs)
        except FileNotFoundError:
            return self._finish(FAILED, f"Could not start the backend: {self.backend.python} does not exist. "
                                        "Check the Python interpreter in the add-on preferences.")
        except OSError as exc:
            return self._finish(FAILED, f"Could not start the backend with {self.backend.python}: "
                                        f"{exc.strerror or exc}.")
        self.state, self.status = RUNNING, "Starting the backend"
        self._whole = declarations.fit_progress().FitProgress(started=time.monotonic())
        _live.add(self)
        for target, stream in ((self._read_stdout, self._process.stdout), (self._read_stderr, self._process.stderr)):
            thread = threading.Thread(target=target, args=(stream,), daemon=True, name="fabric-backend-reader")
            thread.start()
            self._threads.append(thread)
        return self

    def _read_stdout(self, stream):
        try:
            for line in stream:
                self._lines.put(line)
        except (OSError, ValueError):
            pass
        finally:
            self._lines.put(None)

    def _read_stderr(self, stream):
        try:
            for line in stream:
                self._stderr.append(line.rstrip("\n"))
                self._stderr_all.append(line)
        except (OSError, ValueError):
            pass

    def poll(self) -> list[dict]:
        """The events read since the last call (never blocks); finishes the run once the process ended."""
        if self.state != RUNNING:
            return []
        events = []
        while True:
            try:
                line = self._lines.get_nowait()
            except queue.Empty:
                break
            if line is None:
                self._eof = True
                continue
            event = self._parse(line)
            if event is not None:
                self._apply(event)
                events.append(event)
        self._follow_progress()
        self._escalate_cancel()
        self._check_exit()
        return events

    def _follow_progress(self):
        """The bar and its words at this moment: they move between events too (a phase without a count)."""
        now = time.monotonic()
        if self._whole.phase is not None and self._cancel_deadline is None:
            self.progress = max(self.progress, self._whole.fraction(now))
            self.status = self._whole.describe(now)

    def _parse(self, line: str) -> dict | None:
        line = line.strip()
        if not line:
            return None
        proto = declarations.protocol()
        try:
            return proto.decode(line)
        except proto.ProtocolError:
            self._malformed.append(line[:300])
            return {"event": "warning", "file": None,
                    "message": f"The backend wrote a line that is not part of its progress protocol: {line[:200]!r}"}

    def _apply(self, event: dict):
        kind = event["event"]
        if kind == "start":
            self.status = f"Backend started ({event.get('device') or 'default device'})"
        elif kind == "progress":
            self._whole.update(event, time.monotonic())
        elif kind == "warning":
            message = str(event.get("message", ""))
            if event.get("file"):
                message += f" ({event['file']})"
            self.warnings.append(message)
        elif kind == "result":
            self.result = event
            self._whole.update(event, time.monotonic())
            self.progress, self.status = 1.0, "Fit finished, reading the result"
        elif kind == "error":
            self._error_event = event

    def _check_exit(self):
        code = self._process.poll()
        if code is None:
            return
        now = time.monotonic()
        if self._exited_at is None:
            self._exited_at = now
        if not self._eof and now - self._exited_at < EXIT_WITHOUT_EOF_S:
            return  # the reader thread has not reached the end of stdout yet
        self.returncode = code
        self._finish(*self._outcome(code))

    def _outcome(self, code: int) -> tuple[str, str]:
        event = self._error_event
        if self._timed_out is not None:
            return FAILED, f"The fit took longer than {self._timed_out:g} s and was stopped."
        if self._cancel_deadline is not None or (event and event.get("kind") == "cancelled"):
            return CANCELLED, "Fit cancelled; the partial results stay in the output folder."
        if event is not None:
            return FAILED, self._error_message(event)
        if code == declarations.protocol().EXIT_OK and self.result is not None:
            return SUCCEEDED, ""
        return FAILED, self._unexpected_end(code)

    def _error_message(self, event: dict) -> str:
        """The backend's error event in words (bad input, internal error), naming its file."""
        kind = {"input": "Bad input", "internal": "Internal backend error"}.get(event.get("kind"), "Backend error")
        message = f"{kind}: {event.get('message', 'no message')}"
        if event.get("file") and str(event["file"]) not in message:
            message += f" (file: {event['file']})"
        if event.get("kind") != "input" and self._stderr:
            self.details = self.stderr_tail()
        return message

    def _unexpected_end(self, code: int) -> str:
        """A run that ended without an error event and without a result: a crash, or silence."""
        self.details = self.stderr_tail()
        if self._malformed:
            self.details += "\nLines that were not protocol events:\n" + "\n".join(self._malformed[-5:])
        if code != declarations.protocol().EXIT_OK:
            last = self._last_stderr_line()
            return (f"The backend stopped unexpectedly ({describe_exit(code)})"
                    + (f": {last}" if last else "") + ". See the console for its log.")
        wrote = f" (it wrote {len(self._malformed)} line(s) that were not progress events)" if self._malformed else ""
        return f"The backend ended without reporting a result{wrote}."

    @property
    def refused_swapped(self) -> bool:
        """Whether the backend refused the photos as swapped (``fit --strict``): the caller may offer the swap."""
        return (self.state == FAILED and (self._error_event or {}).get("kind") == "input"
                and declarations.protocol().SWAPPED_PHOTOS in self.error)

    @property
    def outcome(self) -> str | None:
        """How the run ended, in the batch job model's words (core/pair_jobs.py): done, input (the
        photos are bad), timeout, cancelled or internal (anything else); None while it runs."""
        jobs = declarations.pair_jobs()
        if not self.done:
            return None
        if self.state in (SUCCEEDED, CANCELLED):
            return jobs.DONE if self.state == SUCCEEDED else jobs.CANCELLED
        if self._timed_out is not None:
            return jobs.TIMEOUT
        return jobs.INPUT if (self._error_event or {}).get("kind") == "input" else jobs.INTERNAL

    def _last_stderr_line(self) -> str:
        for line in reversed(self._stderr):
            if line.strip():
                return line.strip()[:300]
        return ""

    def stderr_tail(self, lines: int = 30) -> str:
        return "\n".join(list(self._stderr)[-lines:])

    def _finish(self, state: str, error: str) -> "FitProcess":
        self.state, self.error = state, error
        self.status = {SUCCEEDED: "Fit finished", CANCELLED: "Fit cancelled"}.get(state, error)
        for thread in self._threads:
            thread.join(timeout=0.2)  # they are at the end of their streams; never hang the UI on them
        if self._process is not None and not any(thread.is_alive() for thread in self._threads):
            # Closing a pipe that a reader thread still blocks on could hang; a grandchild holding
            # stdout open only delays the closing until that thread ends on its own.
            for stream in (self._process.stdin, self._process.stdout, self._process.stderr):
                try:
                    stream.close()
                except OSError:
                    pass
        if self.log_path is not None and self._stderr_all:
            try:
                self.log_path.parent.mkdir(parents=True, exist_ok=True)
                paths.write_whole(self.log_path, "".join(self._stderr_all))
            except OSError:
                pass  # the log is a convenience; the error message already says what happened
        return self

    # -- cancelling ---------------------------------------------------------------------------
    def _ask_to_stop(self):
        """The protocol's stop line on the backend's stdin: a stop request every platform delivers."""
        try:
            self._process.stdin.write(declarations.protocol().STOP_REQUEST + "\n")
            self._process.stdin.flush()
        except (OSError, ValueError):
            pass  # the backend closed its input or has ended: nothing left to ask

    def _kill(self):
        if self._process is None or self._process.poll() is not None:
            return
        try:
            if os.name == "posix":
                os.killpg(self._process.pid, signal.SIGKILL)  # the process leads its own session
            else:
                self._process.kill()
        except (ProcessLookupError, PermissionError):
            pass

    def request_cancel(self, grace: float = CANCEL_GRACE_S):
        """Asks the backend to stop and returns at once; poll() kills it after ``grace`` s."""
        if self.state != RUNNING or self._cancel_deadline is not None:
            return
        self._cancel_deadline = time.monotonic() + grace
        self.status = "Cancelling"
        self._ask_to_stop()

    def _escalate_cancel(self):
        if self._cancel_deadline is not None and time.monotonic() > self._cancel_deadline:
            self._kill()

    def time_out(self, limit: float) -> None:
        """Stops a run that has gone on past ``limit`` seconds: it fails, saying so."""
        if self.state == RUNNING and self._cancel_deadline is None:
            self._timed_out = limit
            self.request_cancel()

    def wait(self, timeout: float | None = None, interval: float = 0.05) -> str:
        """Blocks until the run ends (batch mode); past ``timeout`` seconds the run is stopped (time_out)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self.done:
            self.poll()
            if deadline is not None and time.monotonic() > deadline:
                self.time_out(timeout)
            if not self.done:
                time.sleep(interval)
        return self.state

    def cancel(self, grace: float = CANCEL_GRACE_S) -> str:
        """Cancels and waits until the process is gone (at most about ``grace`` + 2 s)."""
        self.request_cancel(grace)
        return self.wait()


# Runs still going when Python exits (Blender quits) are stopped: the backend runs in its own
# session, so nothing else would end it.
_live: "weakref.WeakSet[FitProcess]" = weakref.WeakSet()


@atexit.register
def _stop_all_runs():
    for fit in list(_live):
        if not fit.done:
            fit.cancel(grace=1.0)
