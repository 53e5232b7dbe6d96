"""Running fuzz cases against the contract, each in a worker process under a time limit.

The contract (issue 91): every case ends in a result, or in exit code 2 with one line that names
the file or option and the problem; never a traceback, a hang, a crash or a result computed from
NaN. Each case's command line runs in the worker through ``backend.app.cli.main.main``, the
command's own argument checking, loading and error handling, up to where the work would start:
the fit and its initialiser (``backend.app.folder``) and the renders of ``render``
(``backend.app.cli.render``) are replaced by stand-ins that check what they were given (finite
working images in [0, 1] of the rig's film size, finite parameters, rig values and settings, a
device torch knows) and stop. Before it stops, the fit's stand-in reads the VGG weights the fit
would read (their errors are the fit's own input errors). Photo cases are also fed to
``load_pair`` directly (strict: order doubts are errors too).

The worker runs under a 4 GB address-space limit (a decompression bomb fails there instead of
taking the machine's memory) with its output descriptors on /dev/null (decoders' own chatter); a
case over its time limit is a hang and the worker is replaced.
"""
from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import traceback
from collections import Counter
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path

from .cases import FIT, REFUSE, Case

FITTED, REFUSED = "fitted", "refused"
CASE_TIMEOUT_S = 60.0      # a liveness bound (a case takes well under a second): beyond it, a hang
STARTUP_TIMEOUT_S = 300.0  # the worker imports torch and the backend before its first case
MEMORY_LIMIT = 4 << 30     # the worker's address space: room for torch and a full-size photo, not for a bomb
MAX_LINE = 1000            # an error line longer than this is no longer one readable line
# What a refusal for want of memory says (OpenCV, Python): under the worker's limit, a bomb got through.
_OUT_OF_MEMORY = ("Insufficient memory", "Failed to allocate", "MemoryError")


@dataclass(frozen=True)
class Outcome:
    kind: str
    label: str
    result: str        # FITTED, REFUSED, or what broke the contract
    detail: str = ""   # the refusal's line, or what happened

    @property
    def ok(self) -> bool:
        return self.result in (FITTED, REFUSED)


class ReachedTheWork(BaseException):
    """Raised by the stand-ins where the fit or the render would start: past every ``except``
    of the command, with what the stand-in found wrong in its inputs (empty: nothing)."""

    def __init__(self, problems: list[str]):
        super().__init__("; ".join(problems))
        self.problems = problems


# -- what the stand-ins check -------------------------------------------------------------------------

def _number_problems(where: str, values, lo=-math.inf, hi=math.inf) -> list[str]:
    flat = list(values) if isinstance(values, (list, tuple)) else [values]
    flat = [x for v in flat for x in (v if isinstance(v, (list, tuple)) else (v,))]
    bad = [x for x in flat if isinstance(x, bool) or not isinstance(x, (int, float)) or not lo <= x <= hi]
    return [f"{where} = {values!r}"] if bad else []


def image_problems(name: str, image, size: int) -> list[str]:
    import numpy as np

    if not isinstance(image, np.ndarray) or image.dtype != np.float32 or image.shape != (size, size, 3):
        return [f"{name}: {type(image).__name__} {getattr(image, 'dtype', '')} {getattr(image, 'shape', '')}, "
                f"expected float32 ({size}, {size}, 3)"]
    finite = np.isfinite(image)
    if not finite.all():
        return [f"{name}: {int((~finite).sum())} non-finite values"]
    if image.min() < 0 or image.max() > 1:
        return [f"{name}: values in [{image.min()}, {image.max()}], outside [0, 1]"]
    return []


def rig_problems(rig) -> list[str]:
    problems = []
    for field in dataclasses.fields(rig):
        value = getattr(rig, field.name)
        if value is not None:
            problems += _number_problems(f"rig.{field.name}", value)
    if not isinstance(rig.film_size, int) or rig.film_size < 8:
        problems.append(f"rig.film_size = {rig.film_size!r}")
    return problems


def settings_problems(settings, rig) -> list[str]:
    import torch

    from backend.core.priors import FIT_PATTERNS

    problems = []
    if settings.iterations is not None:
        problems += _number_problems("iterations", settings.iterations, 1)
    if settings.size is not None:
        problems += _number_problems("size", settings.size, 32, rig.film_size)
    problems += _number_problems("seed", settings.seed, 0, 2**32 - 1)
    for name in ("camera_blur", "sample_rotation"):
        if getattr(settings, name) is not None:
            problems += _number_problems(name, getattr(settings, name))
    if settings.pattern not in ("auto", *FIT_PATTERNS):
        problems.append(f"pattern = {settings.pattern!r}")
    try:
        if torch.device(settings.device).type not in ("cpu", "cuda"):
            problems.append(f"device = {settings.device!r}")
    except (RuntimeError, TypeError, ValueError) as exc:
        problems.append(f"device = {settings.device!r} ({exc})")
    return problems


def params_problems(params) -> list[str]:
    from backend.core.params import PARAMETERS

    problems = []
    for spec in PARAMETERS:
        problems += _number_problems(spec.name, params.flat(spec.name), spec.lo, spec.hi)
    return problems


def _fit_stand_in(reflection, transmission, rig, settings, **unused):
    if settings.vgg_weights:  # the fit reads them first of its inputs; their errors are its input errors
        from backend.fit.gram import GramDescriptor

        GramDescriptor.load(settings.vgg_weights)
    raise ReachedTheWork(image_problems("reflection", reflection, rig.film_size)
                         + image_problems("transmission", transmission, rig.film_size)
                         + rig_problems(rig) + settings_problems(settings, rig))


def _initialiser_stand_in(init, reflection, transmission, rig, warn):
    problems = image_problems("reflection", reflection, rig.film_size) + image_problems(
        "transmission", transmission, rig.film_size)
    if problems:
        raise ReachedTheWork(problems)
    return None


def _render_stand_in(params, out, names, rig, options, size, spp, seed, dev):
    raise ReachedTheWork(params_problems(params) + rig_problems(rig))


def stand_ins() -> list[tuple[object, str, object]]:
    """(module, name, stand-in) of each replacement: the fit and its initialiser, render's renders."""
    from backend.app import folder
    from backend.app.cli import render

    return [(folder, "fit", _fit_stand_in), (folder, "fit_initialiser", _initialiser_stand_in),
            (render, "render_and_save", _render_stand_in)]


# -- one case, in the worker ------------------------------------------------------------------------------

@dataclass
class CommandRun:
    code: object = None        # the exit code, or "reached" where a stand-in stopped it
    stdout: str = ""
    stderr: str = ""
    problems: tuple = ()       # what a stand-in found wrong
    raised: str = ""           # an exception that escaped the command: its traceback


def run_command(argv: list[str]) -> CommandRun:
    from backend.app.cli.main import main

    out, err, run = io.StringIO(), io.StringIO(), CommandRun()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            run.code = main(argv)
        except SystemExit as exc:  # argparse
            run.code = exc.code
        except ReachedTheWork as reached:
            run.code, run.problems = "reached", tuple(reached.problems)
        except BaseException:  # noqa: B036 - whatever escapes the command is the finding
            run.raised = traceback.format_exc()
    run.stdout, run.stderr = out.getvalue(), err.getvalue()
    return run


def _error_lines(run: CommandRun) -> list[str]:
    return [line for line in run.stderr.splitlines() if "error:" in line]


def _json_error_problem(run: CommandRun) -> str:
    """A JSON error event whose message runs over more than one line (--json-progress cases)."""
    for line in run.stdout.splitlines():
        try:
            event = json.loads(line)
        except json.JSONDecodeError:
            return f"a stdout line that is not JSON: {line[:200]!r}"
        if event.get("event") == "error" and "\n" in event.get("message", ""):
            return "an error message of several lines"
    return ""


def judge(case: Case, run: CommandRun) -> tuple[str, str]:
    """(result, detail) of a command run against the case's contract."""
    if run.raised or "Traceback" in run.stderr:
        trace = run.raised or run.stderr
        return "traceback", trace.strip().splitlines()[-1][:300]
    if run.code == "reached":
        return _judge_reached(case, run)
    if run.code != 2:
        return f"exit {run.code}", (_error_lines(run) or run.stderr.strip().splitlines() or [""])[-1][:300]
    return _judge_refusal(case, run)


def _judge_reached(case: Case, run: CommandRun) -> tuple[str, str]:
    """A run that reached the work: clean inputs, and a case that may be fitted."""
    if run.problems:
        return "bad inputs reached the work", "; ".join(run.problems)[:300]
    if case.expect == REFUSE:
        return "bad input accepted", ""
    return FITTED, ""


def _judge_refusal(case: Case, run: CommandRun) -> tuple[str, str]:
    """A run that ended with exit code 2: one readable line naming a suspect, for a case that may be refused."""
    lines = _error_lines(run)
    if any(word in line for line in lines for word in _OUT_OF_MEMORY):
        return "ran out of memory", lines[0][:300]
    if len(lines) != 1:
        return "not one error line", " | ".join(lines)[:300]
    line, multi = lines[0], _json_error_problem(run)
    if multi:
        return "not one error line", multi
    if len(line) > MAX_LINE:
        return "overlong error line", f"{len(line)} characters: {line[:200]}"
    if not any(suspect in line for suspect in case.suspects):
        return "refusal names none of " + ", ".join(case.suspects), line[:300]
    if case.expect == FIT:
        return "good input refused", line[:300]
    return REFUSED, line


def check_loader(case: Case, folder: Path) -> tuple[str, str] | None:
    """A contract failure of ``load_pair`` on the case's photos, or None."""
    from backend.image.photos import PhotoError, load_pair

    from .images import FILM

    paths = [folder / name for name in case.loader]
    try:
        pair = load_pair(*paths, size=FILM, strict=True)
    except PhotoError as exc:
        message = str(exc)
        if "\n" in message or len(message) > MAX_LINE:
            return "loader: not one error line", message[:300]
        if not any(suspect in message for suspect in case.suspects):
            return "loader: names none of " + ", ".join(case.suspects), message[:300]
        return None
    except Exception as exc:  # noqa: BLE001 - any other exception is the finding
        return f"loader raised {type(exc).__name__}", str(exc).splitlines()[0][:300] if str(exc) else ""
    problems = image_problems("reflection", pair.reflection, FILM) + image_problems(
        "transmission", pair.transmission, FILM)
    return ("loader: bad working images", "; ".join(problems)) if problems else None


def run_case(case: Case, scratch: Path) -> Outcome:
    folder = Path(tempfile.mkdtemp(dir=scratch))
    try:
        for name, data in case.files:
            (folder / name).parent.mkdir(parents=True, exist_ok=True)
            (folder / name).write_bytes(data)
        failed = check_loader(case, folder) if case.loader else None
        result, detail = judge(case, run_command([word.replace("{dir}", str(folder)) for word in case.command]))
        if failed and result in (FITTED, REFUSED):
            result, detail = failed
        return Outcome(case.kind, case.label, result, detail.replace(str(folder), "{dir}"))
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def serve(descriptor: int, scratch: str) -> None:
    """The worker (``python -c``, :class:`Worker`): runs the cases it receives on the socket
    ``descriptor``, one at a time, until it receives None."""
    import resource

    connection = Connection(descriptor)
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    quiet = os.open(os.devnull, os.O_WRONLY)
    os.dup2(quiet, 1)
    os.dup2(quiet, 2)
    import torch

    torch.set_num_threads(1)
    for module, name, stand_in in stand_ins():
        setattr(module, name, stand_in)
    connection.send("ready")
    while (case := connection.recv()) is not None:
        connection.send(run_case(case, Path(scratch)))


# -- the runner, in the caller's process ------------------------------------------------------------------

_ROOT = Path(__file__).resolve().parents[2]
_SERVE = "import sys; from devtools.fuzz.runner import serve; serve(int(sys.argv[1]), sys.argv[2])"


class Worker:
    """A worker process (a fresh interpreter, on a socket pair); replaced after a hang or a crash."""

    def __init__(self, scratch: Path):
        self.scratch = scratch
        self.process = None
        self._start()

    def _start(self) -> None:
        ours, theirs = socket.socketpair()
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(_ROOT), os.environ.get("PYTHONPATH")])),
               "WFC_COMPILE": "0"}
        self.process = subprocess.Popen([sys.executable, "-c", _SERVE, str(theirs.fileno()), str(self.scratch)],
                                        pass_fds=(theirs.fileno(),), env=env, stdin=subprocess.DEVNULL)
        theirs.close()
        self.connection = Connection(ours.detach())
        if not self.connection.poll(STARTUP_TIMEOUT_S) or self.connection.recv() != "ready":
            raise RuntimeError("the fuzz worker did not start")

    def run(self, case: Case, timeout_s: float) -> Outcome:
        self.connection.send(case)
        try:
            if self.connection.poll(timeout_s):
                return self.connection.recv()
            result, detail = "hang", f"no end within {timeout_s:g} s"
        except EOFError:
            result, detail = "crash", f"the worker died (exit code {self.process.poll()})"
        self._stop()
        self._start()
        return Outcome(case.kind, case.label, result, detail)

    def _stop(self) -> None:
        self.process.kill()
        self.process.wait()
        self.connection.close()

    def close(self) -> None:
        try:
            self.connection.send(None)
            self.process.wait(10)
        except (OSError, subprocess.TimeoutExpired):
            pass
        self._stop()


@contextlib.contextmanager
def worker():
    scratch = Path(tempfile.mkdtemp(prefix="fuzz-"))
    running = Worker(scratch)
    try:
        yield running
    finally:
        running.close()
        shutil.rmtree(scratch, ignore_errors=True)


def run_cases(cases: list[Case], timeout_s: float = CASE_TIMEOUT_S, progress=None) -> list[Outcome]:
    """Every case's outcome, in order (one worker; ``progress(done, total, outcome)`` after each)."""
    outcomes = []
    with worker() as running:
        for case in cases:
            outcomes.append(running.run(case, timeout_s))
            if progress is not None:
                progress(len(outcomes), len(cases), outcomes[-1])
    return outcomes


def counts(outcomes: list[Outcome]) -> dict[str, Counter]:
    """kind -> Counter of results."""
    table: dict[str, Counter] = {}
    for outcome in outcomes:
        table.setdefault(outcome.kind, Counter())[outcome.result] += 1
    return table
