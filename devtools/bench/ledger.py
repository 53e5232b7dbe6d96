"""The results ledger: what a benchmark prints, appended as JSON lines to ``results/<bench>.jsonl``.

A figure quoted without the code, the machine and the data it came from cannot be checked again, so
every ``python -m devtools bench ...`` and ``evaluate-init`` run appends each row it prints and its
summary, each with the run's context: the commit and whether the tree differed from it, the date,
the command line and the environment variables that change a measurement, the machine and the data
sets' folders (the record format: ``devtools/bench/results/README.md``). ``--no-record`` runs
without appending.
"""
from __future__ import annotations

import json
import os
import platform
import shlex
import subprocess
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]  # the checkout holding devtools/
IN_CHECKOUT = "devtools/bench/results"  # the ledger's folder within the checkout
RESULTS = ROOT / IN_CHECKOUT
THREADS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")  # read by the OpenMP and MKL runtimes torch loads


@dataclass(frozen=True)
class Ledger:
    """Appends records to ``path`` (None: records nothing, as ``--no-record`` asks)."""

    path: Path | None = None
    context: dict = field(default_factory=dict)

    @classmethod
    def open(cls, bench: str, argv: list[str], datasets: list[str] = (), device: str = "cpu", record: bool = True,
             folder: Path | None = None, root: Path = ROOT) -> Ledger:
        """The ledger of one run of ``bench`` (``argv``: the arguments of ``python -m devtools``) in
        ``folder`` (default :data:`RESULTS`), its context read once, at the start: a commit made while
        it runs is not the one it measured."""
        if not record:
            return cls()
        return cls(Path(folder or RESULTS) / f"{bench}.jsonl", run_context(bench, argv, datasets, device, root))

    def row(self, data: dict) -> None:
        """One row the benchmark printed (a pair, a fit, a round)."""
        self._append("row", data)

    def summary(self, data: dict) -> None:
        """The summary the benchmark printed last."""
        self._append("summary", data)

    def print_row(self, data: dict, as_json: bool, text: Callable[[dict], str]) -> None:
        """Prints a row (as JSON, or ``text(data)``) and records it: the ledger keeps what was shown."""
        print(json.dumps(data) if as_json else text(data), flush=True)
        self.row(data)

    def print_summary(self, data: dict, as_json: bool, text: Callable[[dict], str]) -> None:
        """Prints the summary (as JSON, or ``text(data)``) and records it."""
        print(json.dumps(data) if as_json else text(data), flush=True)
        self.summary(data)

    def _append(self, kind: str, data: dict) -> None:
        if self.path is None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # appended and closed record by record: a run stopped half-way keeps the rows it printed
        with self.path.open("a", encoding="utf-8") as ledger:
            ledger.write(json.dumps({**self.context, "kind": kind, "data": data}) + "\n")


NOT_RECORDED = Ledger()
"""The ledger of a benchmark called from code (tests): nothing is written."""


def open_ledger(args, bench: str, datasets: list[str] = (), device: str = "cpu") -> Ledger:
    """The ledger of a command's run (``args`` as :func:`devtools.cli.main.main` parsed them)."""
    return Ledger.open(bench, args.argv, datasets, device, record=not args.no_record)


def add_record_option(parser) -> None:
    parser.add_argument("--no-record", action="store_true",
                        help="a dry run: append nothing to devtools/bench/results/ (the results ledger)")


def run_context(bench: str, argv: list[str], datasets: list[str], device: str, root: Path = ROOT) -> dict:
    """The fields every record of one run shares."""
    commit = _git(root, "rev-parse", "HEAD")
    # the ledger's own folder changes with every run: it does not make the measured code dirty
    status = _git(root, "status", "--porcelain", "--", ".", f":(exclude){IN_CHECKOUT}")
    return {"bench": bench, "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "commit": commit, "dirty": None if commit is None or status is None else bool(status),
            "command": shlex.join(["python", "-m", "devtools", *argv]), "environment": _environment(),
            "machine": machine(device), "datasets": [str(Path(folder).resolve()) for folder in datasets]}


# Variables that choose the numeric libraries' code paths, and so the last bits of every fit
# (a fit's choices amplify them): ATen's and NumPy's vector instructions, MKL's branch, oneDNN's.
KERNEL_SWITCHES = ("ATEN_CPU_CAPABILITY", "NPY_DISABLE_CPU_FEATURES", "NPY_ENABLE_CPU_FEATURES", "MKL_CBWR",
                   "MKL_ENABLE_INSTRUCTIONS", "ONEDNN_MAX_CPU_ISA")


def _environment() -> dict:
    """The variables set that change what a benchmark measures: the renderer's compile switch
    (``WFC_COMPILE``), the thread counts its fits inherit and the numeric libraries' code paths."""
    return {name: value for name, value in sorted(os.environ.items())
            if name.startswith("WFC_") or name in THREADS or name in KERNEL_SWITCHES}


def machine(device: str) -> dict:
    """The CPU's model, its cores, this process's torch threads, the vector code its numeric libraries
    run (:func:`kernels`) and the device the benchmark ran on."""
    return {"cpu": _cpu_model(), "cores": os.cpu_count(), "torch_threads": torch.get_num_threads(),
            "kernels": kernels(), "device": device,
            "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None}


def kernels() -> dict:
    """The vector instructions PyTorch's CPU kernels use and the widest that NumPy dispatches to:
    two machines whose fits give different numbers from the same photos and code differ here (or in
    the CPU's vendor, for MKL, or in the thread count). Figures from runs that differ in them are
    different fits, not a change's effect."""
    return {"torch": torch.backends.cpu.get_cpu_capability(), "numpy": _numpy_widest()}


def _numpy_widest() -> str | None:
    """The last of NumPy's dispatch targets this machine has and NumPy uses (None where it does not say)."""
    try:
        from numpy._core import _multiarray_umath as umath
    except ImportError:
        from numpy.core import _multiarray_umath as umath
    features = getattr(umath, "__cpu_features__", {})
    used = [name for name in getattr(umath, "__cpu_dispatch__", []) if features.get(name)]
    return used[-1] if used else None


def _cpu_model() -> str | None:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:  # Linux: platform.processor() says only "x86_64"
            for line in info:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or None


def _git(root: Path, *args: str) -> str | None:
    """``git <args>``'s output in ``root``; None outside a git checkout or without git."""
    try:
        done = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True)
    except OSError:
        return None
    return done.stdout.strip() if done.returncode == 0 else None
