"""Ray as the batch's engine: a local Ray on this machine, or a running cluster given its address.

:func:`connect` imports Ray (only here: it is the optional ``cluster`` extra, so a missing Ray is a
one-line :class:`~.scheduler.BatchError` saying how to install it) and starts or joins Ray with the
driver's own ``backend`` package as a ``py_modules`` runtime environment: every worker imports the
same code as the driver, and a cluster's machines need only the dependencies (the project's, same
versions, and Ray). A Ray already started in this process (a test, a notebook) is used as it is
and left running.

:class:`RayExecutor` makes each pair a task of :func:`~.job.run_fit_job` that asks for
``--cpus-per-fit`` CPUs, ``--gpus-per-fit`` GPUs and ``--memory-per-fit`` GB
(:class:`FitResources`; Ray places it on a machine that has them; fractions of a GPU share one),
with Ray's own retries off (``max_retries=0``: the driver retries once and says why) and a worker
replaced after :data:`MAX_FITS_PER_WORKER` fits, so that nothing a fit leaves in memory piles up.
A cancelled task becomes a ``cancelled`` outcome; any other Ray error (the worker or its machine
died, Ray's out-of-memory killer, an exception outside the fit) becomes
:class:`~.scheduler.TaskLost` with Ray's own first line as the reason.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from ...core.pair_jobs import CANCELLED
from .job import FitJob, FitOutcome, run_fit_job
from .scheduler import BatchError, TaskLost

INSTALL_HINT = "pip install -e '.[cluster]' (or pip install ray)"
MAX_FITS_PER_WORKER = 20  # then a fresh worker: nothing a fit leaves in memory piles up
# A default fit's peak memory (metrics.json's peak_mb): reserving it keeps a many-core, little-memory
# machine from running more fits than it can hold.
DEFAULT_MEMORY_GB = 2.0
_BACKEND = Path(__file__).resolve().parents[1]  # the backend package the workers import


@dataclass(frozen=True)
class FitResources:
    """What Ray reserves for one fit: CPUs (also its threads), GPUs (fractions share one), memory."""

    cpus: float = 1.0
    gpus: float = 0.0
    memory_gb: float = DEFAULT_MEMORY_GB

    def ray_options(self) -> dict:
        return {"num_cpus": self.cpus, "num_gpus": self.gpus, "memory": int(self.memory_gb * 2**30)}

    def fits_in(self, resources: dict) -> int:
        """How many such fits ``resources`` (Ray's: CPU, GPU, memory in bytes) hold at once."""
        limits = [resources.get("CPU", 0) / self.cpus]
        if self.gpus:
            limits.append(resources.get("GPU", 0) / self.gpus)
        if self.memory_gb:
            limits.append(resources.get("memory", 0) / (self.memory_gb * 2**30))
        return int(min(limits))

    def describe(self) -> str:
        return f"{self.cpus:g} CPU(s), {self.gpus:g} GPU(s), {self.memory_gb:g} GB each"


@dataclass
class RayConnection:
    ray: object
    started_here: bool   # this process started or joined Ray (and so shuts it down)
    local: bool          # Ray runs on this machine only (no address given)

    def resources(self) -> dict:
        return self.ray.cluster_resources()

    def machines(self) -> list[dict]:
        return [n.get("Resources", {}) for n in self.ray.nodes() if n.get("Alive")]

    def capacity(self, fit: FitResources) -> int:
        """How many fits the machines can run at once (at least 1)."""
        return max(1, sum(fit.fits_in(machine) for machine in self.machines()))

    def check_fits_on_a_machine(self, fit: FitResources) -> str | None:
        """None when some machine has what one fit asks for; else the problem (an error on a local Ray,
        a warning on a cluster, whose autoscaler may still add such a machine)."""
        if any(fit.fits_in(machine) for machine in self.machines()):
            return None
        largest = max(self.machines(), key=lambda m: (m.get("CPU", 0), m.get("memory", 0)), default={})
        return (f"a fit asks for {fit.describe()} (--cpus-per-fit, --gpus-per-fit, --memory-per-fit): no machine "
                f"of this Ray has that much (the largest: {largest.get('CPU', 0):g} CPUs, {largest.get('GPU', 0):g} "
                f"GPUs, {largest.get('memory', 0) / 2**30:.1f} GB for tasks)")

    def describe(self) -> str:
        total = self.resources()
        where = "local Ray" if self.local else "Ray cluster"
        return (f"{where}: {len(self.machines())} machine(s), {total.get('CPU', 0):g} CPUs, {total.get('GPU', 0):g} "
                f"GPUs, {total.get('memory', 0) / 2**30:.1f} GB for tasks")

    def executor(self, fit: FitResources) -> RayExecutor:
        return RayExecutor(self.ray, fit)

    def close(self) -> None:
        if self.started_here:
            self.ray.shutdown()


def connect(address: str | None) -> RayConnection:
    """Starts a new local Ray (``address`` None) or joins the cluster at ``address`` (``auto``: the one
    ``ray start`` runs on this machine, ``HOST:6379``, ``ray://HOST:10001``); BatchError when Ray is
    missing or cannot be reached."""
    try:
        import ray  # the optional cluster extra: imported where the batch runs, nowhere else
    except ImportError:
        raise BatchError(f"the batch runs on Ray, which is not installed: {INSTALL_HINT}") from None
    if ray.is_initialized():
        return RayConnection(ray, started_here=False, local=address is None)
    try:
        # "local": a new Ray on this machine, even where `ray start` left a cluster running here
        ray.init(address=address or "local", runtime_env={"py_modules": [str(_BACKEND)]}, include_dashboard=False,
                 log_to_driver=False, logging_level=logging.WARNING)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        where = f"the Ray cluster at {address}" if address else "a local Ray"
        raise BatchError(f"cannot start or reach {where}: {str(exc).splitlines()[0] if str(exc) else exc}") from None
    return RayConnection(ray, started_here=True, local=address is None)


class RayExecutor:
    """The scheduler's Executor on Ray: handles are ObjectRefs."""

    def __init__(self, ray, fit: FitResources, task=run_fit_job):
        self.ray = ray
        self.task = ray.remote(**fit.ray_options(), max_retries=0, max_calls=MAX_FITS_PER_WORKER)(task)
        self.unfinished: set = set()

    def submit(self, job: FitJob):
        ref = self.task.remote(job)
        self.unfinished.add(ref)
        return ref

    def wait(self, handles: list, timeout: float) -> list:
        if not handles:
            return []
        ready, _ = self.ray.wait(handles, num_returns=len(handles), timeout=timeout)
        return ready

    def outcome(self, handle) -> FitOutcome:
        self.unfinished.discard(handle)
        exceptions = self.ray.exceptions
        try:
            return self.ray.get(handle)
        except exceptions.TaskCancelledError:
            return FitOutcome("", CANCELLED, "cancelled before it started")
        except exceptions.RayError as exc:
            first_line = next((line for line in str(exc).splitlines() if line.strip()), "")
            raise TaskLost(f"{type(exc).__name__}: {first_line}"[:500]) from None

    def cancel(self, handle) -> None:
        self.ray.cancel(handle)

    def abandon(self) -> None:
        """Ends every task still running (kills its worker): the driver is leaving."""
        for ref in self.unfinished:
            self.ray.cancel(ref, force=True)
        self.unfinished.clear()
