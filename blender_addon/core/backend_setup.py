"""Which Python runs the backend, and whether it can (no bpy, no torch).

:func:`resolve_backend` applies the precedence: explicit setting (add-on preference, batch flag) >
environment (``WOVEN_FABRIC_PYTHON``, ``WOVEN_FABRIC_BACKEND_SCRIPT``) > the extension's bundled
backend (:func:`bundled_backend`: Blender's own Python, isolated, with the wheels a platform zip
installed, and the GPU route's CUDA PyTorch first when chosen) > auto-detection
(:func:`find_interpreter`: the project's ``.venv`` beside the backend, an active virtual
environment, then the running Python, i.e. Blender's own, whichever first imports torch).

:func:`check_backend` runs a probe in the interpreter, with the backend's own flags and path, that
imports every runtime dependency (backend/core/dependencies.py) and the fit command's module, and
answers in words: the interpreter is missing, the Python version is wrong, a dependency is missing
(what it is for, and how to get it: reinstall the platform zip for the bundled backend, the pip
command for an external Python), the backend or its fit command does not import, CUDA is selected
but absent (a script standing in for the backend is asked for ``fit --help`` instead). It also
says which interpreter runs, its PyTorch version and where that comes from, and the device.
"""
from __future__ import annotations

import dataclasses
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


def bundled_backend(python: str, site_packages: str | Path, gpu_packages: str | Path | None = None) -> Backend:
    """Blender's Python running the extension's backend with exactly the extension's installed wheels
    (``site_packages``), and a CUDA PyTorch folder before them when the GPU route is chosen."""
    if gpu_packages:
        return Backend(python, packages=(str(gpu_packages), str(site_packages)),
                       label="Blender's Python with the GPU (CUDA) PyTorch and the extension's packages")
    return Backend(python, packages=(str(site_packages),), label="Blender's Python with the extension's packages")


def resolve_backend(python: str = "", script: str = "", detect: bool = True, bundled: Backend | None = None) -> Backend:
    """The backend to run: explicit values, else the environment, else ``bundled``, else auto-detection.

    Raises BackendError when no interpreter can be found.
    """
    script = script or os.environ.get(ENV_BACKEND_SCRIPT, "")
    if python:
        return Backend(python, script, label="External Python set in the preferences")
    if os.environ.get(ENV_PYTHON):
        return Backend(os.environ[ENV_PYTHON], script, label=f"External Python from {ENV_PYTHON}")
    if bundled is not None:
        return dataclasses.replace(bundled, script=script)
    found = find_interpreter() if detect else None
    if not found:
        raise BackendError("No Python with PyTorch was found for the fabric backend. Install the extension zip "
                           "made for your platform (it brings PyTorch), or set the backend's Python interpreter "
                           "in the add-on preferences (Edit > Preferences > Add-ons > Woven Fabric Capture) and "
                           "press Check Backend.")
    return Backend(found, script, label="Detected Python with PyTorch")


# -- checking an interpreter ------------------------------------------------------------------

# Runs inside the candidate interpreter (argv[1]: the modules to import); prints one JSON object.
_PROBE = r"""
import importlib, json, sys
out = {"python": list(sys.version_info[:3]), "modules": {}, "files": {}, "errors": {}}
for name in json.loads(sys.argv[1]):
    try:
        module = importlib.import_module(name)
        out["modules"][name] = getattr(module, "__version__", "?")
        out["files"][name] = getattr(module, "__file__", "") or ""
    except Exception as exc:
        out["errors"][name] = f"{type(exc).__name__}: {exc}"
try:
    import backend
    out["backend"] = getattr(backend, "__version__", "?")
    if not out["errors"]:  # the fit command's module imports everything a fit runs (an old backend has none)
        import backend.app.cli.fit
        out["fit"] = True
except Exception as exc:
    out["errors"]["backend"] = f"{type(exc).__name__}: {exc}"
if "torch" in out["modules"]:
    import torch
    out["cuda"] = bool(torch.cuda.is_available())
    out["cuda_name"] = torch.cuda.get_device_name(0) if out["cuda"] else ""
print(json.dumps(out))
"""


@dataclass
class BackendCheck:
    """What a check of a backend found: problems (the backend cannot run), notes, and what runs."""

    python: str
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    label: str = ""            # which backend (Backend.label)
    torch_version: str = ""    # "" when PyTorch does not import
    torch_file: str = ""
    device: str = ""           # "CPU", or "CUDA: <GPU name>"

    @property
    def ok(self) -> bool:
        return not self.problems

    def summary(self) -> str:
        head = "The backend is ready." if self.ok else "The backend cannot run yet:"
        return "\n".join([head, *(f"- {p}" for p in self.problems), *(f"- {n}" for n in self.notes)])


def _runtime_dependencies():
    return paths.backend_module("core.dependencies").RUNTIME


def _missing(dependency, found: dict, backend: Backend) -> str:
    """One sentence: which dependency is missing or broken, what for, and how to get it."""
    reason = found["errors"].get(dependency.module, "")
    what = f"{dependency.label} ({dependency.module}), which {dependency.role},"
    if backend.packages:
        where = " and ".join(backend.packages)
        state = "is missing from" if "No module named" in reason else f"cannot be imported ({reason}) from"
        return (f"{what} {state} the extension's packages in {where}: reinstall the extension zip made for this "
                "platform, or choose an external Python with PyTorch in the preferences.")
    state = "is not installed" if "No module named" in reason else f"cannot be imported ({reason})"
    return (f"{what} {state} for {backend.python}: install it with "
            f"\"{backend.python}\" -m pip install \"{dependency.requirement}\"")


def check_backend(backend: Backend, device: str | None = None, timeout: float = 120.0) -> BackendCheck:
    """Runs the backend's interpreter as a fit would and reports, in words, what is missing for a fit."""
    check = BackendCheck(backend.python, label=backend.label)
    found, problem = _probe(backend, timeout)
    if problem:
        check.problems.append(problem)
        return check
    _read_packages(check, found, backend)
    _read_device(check, found, device)
    if backend.script:
        _check_fit_command(backend, check, timeout)
    return check


def _probe(backend: Backend, timeout: float) -> tuple[dict | None, str | None]:
    """What the interpreter reports of itself and the runtime dependencies (_PROBE), or why it cannot."""
    python = backend.python
    if not python:
        return None, "No Python interpreter is set for the backend."
    if not Path(python).exists():
        return None, f"The Python interpreter {python} does not exist."
    modules = json.dumps([d.module for d in _runtime_dependencies()])
    try:
        done = subprocess.run(backend.python_command(["-c", _PROBE, modules]), capture_output=True, text=True,
                              timeout=timeout, env=backend.environment())
    except subprocess.TimeoutExpired:
        return None, f"{python} did not answer within {timeout:.0f} s."
    except OSError as exc:
        return None, f"{python} could not be started: {exc.strerror or exc}."
    try:
        return json.loads(done.stdout.strip().splitlines()[-1]), None
    except (json.JSONDecodeError, IndexError):
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
        return None, f"{python} is not a working Python interpreter ({tail[0]})."


def _read_packages(check: BackendCheck, found: dict, backend: Backend) -> None:
    """The Python version, the missing dependencies, PyTorch and the backend package, from the probe."""
    python, version = backend.python, tuple(found["python"])
    if version[:2] != (3, 11):
        check.problems.append(f"{python} is Python {'.'.join(map(str, version))}; the backend needs Python 3.11.")
    check.problems += [_missing(d, found, backend) for d in _runtime_dependencies()
                       if d.module not in found["modules"]]
    check.torch_version = found["modules"].get("torch", "")
    check.torch_file = found["files"].get("torch", "")
    if "backend" in found and not check.problems and not found.get("fit"):
        check.problems.append(f"The backend's fit command cannot be imported: {found['errors'].get('backend')}.")
    if "backend" in found:
        check.notes.append(f"Backend {found['backend']} from {paths.backend_root()}, Python "
                           f"{'.'.join(map(str, version))}, PyTorch {check.torch_version or '-'}"
                           + (f" from {Path(check.torch_file).parent}" if check.torch_file else "") + ".")
    elif check.torch_version:
        check.problems.append(f"The backend package cannot be imported: {found['errors'].get('backend')}.")


def _read_device(check: BackendCheck, found: dict, device: str | None) -> None:
    """The device PyTorch sees there, and whether the selected one is among them."""
    if found.get("cuda"):
        check.device = f"CUDA: {found.get('cuda_name')}"
        check.notes.append(f"CUDA is available ({found.get('cuda_name')}).")
    elif check.torch_version:
        check.device = "CPU"
        if device == "cuda":
            check.problems.append("The CUDA device is selected but PyTorch sees no CUDA GPU here; choose CPU.")


def _check_fit_command(backend: Backend, check: BackendCheck, timeout: float):
    """A script standing in for the backend must know the fit command."""
    try:
        done = subprocess.run(backend.command(["fit", "--help"]), capture_output=True, text=True,
                              timeout=timeout, env=backend.environment())
    except (OSError, subprocess.TimeoutExpired) as exc:
        check.problems.append(f"The backend's fit command could not be run: {exc}.")
        return
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no message"])[-1]
        check.problems.append(f"The backend has no working fit command ({last}).")
