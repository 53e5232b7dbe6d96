"""The optional GPU route: a CUDA build of PyTorch installed into the extension's user folder (no bpy).

The platform zips bundle PyTorch's CPU build. An artist with an NVIDIA card adds a CUDA build with
one button: :class:`TorchInstall` runs Blender's own Python isolated like the bundled backend
(``-S -P``, the extension's packages on its path, which hold pip) as::

    python -S -P -m pip install --target FOLDER.partial torch==<the backend's version>
        [--index-url <CUDA index>] --progress-bar raw --no-compile ...

in a subprocess that Blender never waits on: two threads read its output, :meth:`TorchInstall.poll`
turns the lines into a status and a progress fraction (pip's ``Progress N of M`` lines of the file
being downloaded), :meth:`TorchInstall.request_cancel` stops it: a job like a fit, which the
add-on's modal operator follows (ui/modal_job.py). It refuses to start unless Blender allows
online access. When pip succeeds the ``.partial`` folder replaces FOLDER (an older one is moved
aside first and deleted after), so an interrupted or failed install never leaves a half
environment that the backend would pick up; :func:`installed` is what the add-on checks before it
puts FOLDER before the extension's packages (backend_setup.bundled_backend). ``--no-compile``:
PyTorch has thousands of modules and compiling them all would double the install time; Python
compiles those it imports on first use.
"""
from __future__ import annotations

import collections
import os
import re
import shutil
import signal
import subprocess
import threading
from dataclasses import dataclass, field
from pathlib import Path

from . import paths
from .backend_bridge import Backend

# PyTorch's package index of CUDA builds (PyPI's Windows wheels are CPU-only; its Linux ones are CUDA
# builds already). A preference may name another (a newer CUDA, a mirror).
CUDA_INDEX = "https://download.pytorch.org/whl/cu130"
FOLDER_NAME = "gpu_torch"
OUTPUT_LINES = 400
_PROGRESS = re.compile(r"^Progress (\d+) of (\d+)$")

RUNNING, SUCCEEDED, FAILED, CANCELLED = "running", "succeeded", "failed", "cancelled"


class InstallRefused(RuntimeError):
    """The install cannot start; the message says why in words."""


def torch_requirement() -> str:
    """The backend's PyTorch version (backend/core/dependencies.py): the CUDA build of the same release."""
    return paths.backend_module("core.dependencies").TORCH.requirement


def installed(folder: str | Path) -> bool:
    """Whether ``folder`` holds a finished install (PyTorch inside)."""
    return (Path(folder) / "torch" / "__init__.py").is_file()


def pip_arguments(target: Path, requirement: str, index_url: str | None) -> list[str]:
    arguments = ["-m", "pip", "install", "--target", str(target), "--no-input", "--disable-pip-version-check",
                 "--no-compile", "--progress-bar", "raw", requirement]
    return arguments + (["--index-url", index_url] if index_url else [])


@dataclass(eq=False)
class TorchInstall:
    """One install of PyTorch into ``folder`` with ``backend``'s interpreter and packages (pip among
    them). ``index_url`` None: pip's own configuration (its index, find-links)."""

    backend: Backend
    folder: Path
    requirement: str
    index_url: str | None = CUDA_INDEX
    state: str = "new"
    status: str = "Not started"
    progress: float = 0.0
    error: str = ""
    output: collections.deque = field(default_factory=lambda: collections.deque(maxlen=OUTPUT_LINES))

    def __post_init__(self):
        self.folder = Path(self.folder)
        self._process: subprocess.Popen | None = None
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()
        self._cancelled = False

    @property
    def partial(self) -> Path:
        return self.folder.with_name(self.folder.name + ".partial")

    @property
    def done(self) -> bool:
        return self.state in (SUCCEEDED, FAILED, CANCELLED)

    def start(self, online: bool) -> "TorchInstall":
        """Starts pip; raises InstallRefused (nothing started) when Blender is offline or pip cannot run."""
        if not online:
            raise InstallRefused("Blender is not allowed to go online: turn on Allow Online Access in Edit > "
                                 "Preferences > System > Network, then install the GPU PyTorch again.")
        if not self.backend.packages:
            raise InstallRefused("The GPU PyTorch is installed beside the extension's bundled packages; this "
                                 "installation has none (install the extension zip made for your platform).")
        _remove(self.partial)
        self.partial.parent.mkdir(parents=True, exist_ok=True)
        kwargs = {"start_new_session": True} if os.name == "posix" else {
            "creationflags": getattr(subprocess, "CREATE_NEW_PROCESS_GROUP", 0)}
        command = self.backend.python_command(pip_arguments(self.partial, self.requirement, self.index_url))
        try:
            self._process = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                             stderr=subprocess.STDOUT, env=self.backend.environment(), text=True,
                                             encoding="utf-8", errors="replace", bufsize=1, **kwargs)
        except OSError as exc:
            raise InstallRefused(f"{self.backend.python} could not be started: {exc.strerror or exc}.") from None
        self.state, self.status = RUNNING, f"Installing {self.requirement}"
        thread = threading.Thread(target=self._read, daemon=True, name="fabric-gpu-install")
        thread.start()
        self._threads.append(thread)
        return self

    def _read(self):
        for line in self._process.stdout:
            line = line.rstrip()
            if not line:
                continue
            with self._lock:
                match = _PROGRESS.match(line)
                if match:
                    done, total = int(match.group(1)), int(match.group(2))
                    self.progress = done / total if total else 0.0
                    continue
                self.output.append(line)
                if line.lstrip().startswith(("Collecting", "Downloading", "Processing", "Installing",
                                             "Successfully")):
                    self.status = line.strip()[:200]
                    self.progress = 0.0 if not line.startswith("Successfully") else 1.0

    def poll(self) -> None:
        """Updates the state (never blocks); the last step moves the finished folder into place."""
        if self.state != RUNNING or self._process.poll() is None:
            return
        for thread in self._threads:
            thread.join(timeout=1.0)
        code = self._process.returncode
        if self._cancelled:
            self._end(CANCELLED, "The GPU PyTorch install was cancelled; nothing was changed.")
        elif code != 0 or not installed(self.partial):
            last = next((line for line in reversed(self.output) if line.startswith("ERROR")),
                        self.output[-1] if self.output else f"exit code {code}")
            self._end(FAILED, f"pip could not install {self.requirement}: {last}")
        else:
            self._replace_folder()

    def _replace_folder(self):
        old = self.folder.with_name(self.folder.name + ".old")
        try:
            _remove(old)
            if self.folder.exists():
                self.folder.rename(old)
            self.partial.rename(self.folder)
        except OSError as exc:
            self._end(FAILED, f"The GPU PyTorch was downloaded but could not be moved to {self.folder}: {exc}.")
            return
        _remove_later(old)
        self.state, self.status, self.progress = SUCCEEDED, f"Installed {self.requirement} in {self.folder}", 1.0

    def _end(self, state: str, error: str):
        self.state, self.error, self.status = state, error, error
        _remove_later(self.partial)

    def request_cancel(self) -> None:
        """Stops pip (the poll after it ends says cancelled) and removes what it had written."""
        if self.state != RUNNING or self._process.poll() is not None:
            return
        self._cancelled = True
        self.status = "Cancelling"
        try:
            if os.name == "posix":
                os.killpg(self._process.pid, signal.SIGTERM)
            else:
                self._process.terminate()
        except (ProcessLookupError, PermissionError):
            pass

    def cancel(self) -> str:
        """Stops pip and waits until it has ended."""
        self.request_cancel()
        return self.wait()

    def wait(self, timeout: float | None = None) -> str:
        """Blocks until pip ends (for scripts and tests); past ``timeout`` seconds it is cancelled."""
        try:
            self._process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.request_cancel()
            self._process.wait()
        self.poll()
        return self.state


def _remove(path: Path):
    if path.is_dir():
        shutil.rmtree(path, ignore_errors=True)


def _remove_later(path: Path):
    """Deletes a (possibly gigabytes large) folder on a thread: Blender never waits for it."""
    if path.exists():
        threading.Thread(target=_remove, args=(path,), daemon=True, name="fabric-gpu-cleanup").start()
