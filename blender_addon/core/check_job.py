"""The backend check as a job (no bpy): "Check Backend" runs it, the preferences show it.

Checking an interpreter imports PyTorch there, which takes seconds, so :meth:`BackendCheckJob.start`
runs backend_setup.check_backend on a daemon thread; the job keeps the outcome of the last check
(not saved with the preferences) and says whether one is running. :data:`backend_check` is the
add-on's one job: the operator starts it and the preferences draw it, and neither imports the other.
"""
from __future__ import annotations

import threading

from . import backend_setup
from .backend_bridge import Backend


class BackendCheckJob:
    """Runs a check of a backend (at most one at a time) and keeps the last outcome."""

    def __init__(self, check=backend_setup.check_backend, log=print):
        self._check, self._log = check, log
        self._thread: threading.Thread | None = None
        self.last: backend_setup.BackendCheck | None = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def run(self, backend: Backend, device: str | None = None) -> backend_setup.BackendCheck:
        """Checks ``backend`` now (blocking), keeps the outcome and writes it to the console."""
        check = self._check(backend, device=device)
        self.last = check
        self._log(f"Woven Fabric: {check.python}: {check.summary()}")
        return check

    def start(self, backend: Backend, device: str | None = None) -> bool:
        """Starts a check on a thread; False (and nothing started) while one is still running."""
        if self.running:
            return False
        self._thread = threading.Thread(target=self.run, args=(backend, device), daemon=True,
                                        name="fabric-backend-check")
        self._thread.start()
        return True

    def wait(self, timeout: float | None = None) -> None:
        """Blocks until the running check (if any) ends."""
        if self._thread is not None:
            self._thread.join(timeout)


backend_check = BackendCheckJob()
