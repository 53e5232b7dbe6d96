"""Which Python runs the backend, and whether it can (no bpy, no torch).

:func:`resolve_backend` applies the precedence: explicit setting (add-on preference, batch flag) >
environment (``WOVEN_FABRIC_PYTHON``, ``WOVEN_FABRIC_BACKEND_SCRIPT``) > auto-detection
(:func:`find_interpreter`: the project's ``.venv`` beside the backend, an active virtual
environment, then the running Python, i.e. Blender's own, whichever first imports torch).

:func:`check_backend` runs a probe in the interpreter and answers in words: the interpreter is
missing, the Python version is wrong, PyTorch/NumPy/OpenCV are not installed (with the pip command
that installs them), the backend package does not import, CUDA is selected but absent, the backend
has no ``fit`` command.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from . import paths
from .backend_bridge import Backend, BackendError

ENV_PYTHON = "WOVEN_FABRIC_PYTHON"
ENV_BACKEND_SCRIPT = "WOVEN_FABRIC_BACKEND_SCRIPT"


def interpreter_candidates() -> list[str]:
    """Interpreters worth trying, best first: the project's environment, then the running Python."""
    candidates = []
    try:
        root = paths.backend_root()
    except FileNotFoundError:
        root = None
    if root is not None:
        for folder in (root, root.parent):
            for rel in (".venv/bin/python", ".venv/Scripts/python.exe", "venv/bin/python"):
                if (folder / rel).is_file():
                    candidates.append(str(folder / rel))
    if os.environ.get("VIRTUAL_ENV"):
        candidates.append(str(Path(os.environ["VIRTUAL_ENV"]) / "bin" / "python"))
    candidates.append(sys.executable)  # Blender's own Python (or the bpy module's interpreter)
    unique = []
    for path in candidates:
        if path and path not in unique and Path(path).is_file():
            unique.append(path)
    return unique


_detected: dict[tuple[str, ...], str] = {}


def find_interpreter(timeout: float = 60.0) -> str | None:
    """The first candidate in which ``import torch`` works, or None (a success is remembered)."""
    candidates = tuple(interpreter_candidates())
    if candidates in _detected:
        return _detected[candidates]
    for python in candidates:
        try:
            done = subprocess.run([python, "-c", "import torch"], capture_output=True, timeout=timeout,
                                  env=Backend(python).environment())
        except (OSError, subprocess.TimeoutExpired):
            continue
        if done.returncode == 0:
            _detected[candidates] = python
            return python
    return None


def resolve_backend(python: str = "", script: str = "", detect: bool = True) -> Backend:
    """The backend to run: explicit values, else the environment, else auto-detection.

    Raises BackendError when no interpreter can be found.
    """
    script = script or os.environ.get(ENV_BACKEND_SCRIPT, "")
    python = python or os.environ.get(ENV_PYTHON, "")
    if not python and detect:
        python = find_interpreter() or ""
    if not python:
        raise BackendError("No Python with PyTorch was found for the fabric backend. Set the backend's "
                           "Python interpreter in the add-on preferences (Edit > Preferences > Add-ons > "
                           "Woven Fabric Capture) and press Check Backend.")
    return Backend(python=python, script=script)


# -- checking an interpreter ------------------------------------------------------------------

# Runs inside the candidate interpreter; prints one JSON object.
_PROBE = r"""
import importlib, json, sys
out = {"python": list(sys.version_info[:3]), "modules": {}, "errors": {}}
for name in ("numpy", "torch", "cv2", "rawpy"):
    try:
        out["modules"][name] = getattr(importlib.import_module(name), "__version__", "?")
    except Exception as exc:
        out["errors"][name] = f"{type(exc).__name__}: {exc}"
try:
    import backend
    out["backend"] = getattr(backend, "__version__", "?")
except Exception as exc:
    out["errors"]["backend"] = f"{type(exc).__name__}: {exc}"
if "torch" in out["modules"]:
    import torch
    out["cuda"] = bool(torch.cuda.is_available())
    out["cuda_name"] = torch.cuda.get_device_name(0) if out["cuda"] else ""
print(json.dumps(out))
"""

_REQUIRED = {
    "torch": ("PyTorch", "torch"),
    "numpy": ("NumPy", "'numpy<2'"),
    "cv2": ("OpenCV", "opencv-python-headless"),
}


@dataclass
class BackendCheck:
    """What a check of an interpreter found: problems (the backend cannot run) and notes."""

    python: str
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems

    def summary(self) -> str:
        head = "The backend is ready." if self.ok else "The backend cannot run yet:"
        return "\n".join([head, *(f"- {p}" for p in self.problems), *(f"- {n}" for n in self.notes)])


def check_backend(backend: Backend, device: str | None = None, timeout: float = 120.0) -> BackendCheck:
    """Runs the interpreter and reports, in words, what is missing for the fit command."""
    check = BackendCheck(backend.python)
    python = backend.python
    if not python:
        check.problems.append("No Python interpreter is set for the backend.")
        return check
    if not Path(python).exists():
        check.problems.append(f"The Python interpreter {python} does not exist.")
        return check
    try:
        done = subprocess.run([python, "-c", _PROBE], capture_output=True, text=True, timeout=timeout,
                              env=backend.environment())
    except subprocess.TimeoutExpired:
        check.problems.append(f"{python} did not answer within {timeout:.0f} s.")
        return check
    except OSError as exc:
        check.problems.append(f"{python} could not be started: {exc.strerror or exc}.")
        return check
    try:
        found = json.loads(done.stdout.strip().splitlines()[-1])
    except (json.JSONDecodeError, IndexError):
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
        check.problems.append(f"{python} is not a working Python interpreter ({tail[0]}).")
        return check

    version = tuple(found["python"])
    if version[:2] != (3, 11):
        check.problems.append(f"{python} is Python {'.'.join(map(str, version))}; the backend needs Python 3.11.")
    for module, (label, package) in _REQUIRED.items():
        if module not in found["modules"]:
            reason = found["errors"].get(module, "")
            hint = "not installed" if "No module named" in reason else f"cannot be imported ({reason})"
            check.problems.append(f"{label} ({module}) is {hint} for {python}: install it with "
                                  f"\"{python}\" -m pip install {package}")
    if "rawpy" not in found["modules"]:
        check.notes.append("rawpy is not installed: RAW photos (.dng, .cr2, ...) cannot be read; "
                           "PNG, JPEG, TIFF and EXR work.")
    if "backend" in found:
        check.notes.append(f"Backend {found['backend']} from {paths.backend_root()}, Python "
                           f"{'.'.join(map(str, version))}, PyTorch {found['modules'].get('torch', '-')}.")
    elif "torch" in found["modules"]:
        check.problems.append(f"The backend package cannot be imported: {found['errors'].get('backend')}.")
    if found.get("cuda"):
        check.notes.append(f"CUDA is available ({found.get('cuda_name')}).")
    elif device == "cuda" and "torch" in found["modules"]:
        check.problems.append("The CUDA device is selected but PyTorch sees no CUDA GPU here; choose CPU.")
    if check.ok or backend.script:
        _check_fit_command(backend, check, timeout)
    return check


def _check_fit_command(backend: Backend, check: BackendCheck, timeout: float):
    """The backend must know the fit command (an older backend has only render)."""
    try:
        done = subprocess.run(backend.command(["fit", "--help"]), capture_output=True, text=True,
                              timeout=timeout, env=backend.environment())
    except (OSError, subprocess.TimeoutExpired) as exc:
        check.problems.append(f"The backend's fit command could not be run: {exc}.")
        return
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        check.problems.append(f"The backend has no working fit command ({last}).")
