"""``python -m devtools gpu-check``: every check that needs a GPU, in one go, within a time budget.

In order: the machine (GPU, torch and CUDA versions); the tests marked ``gpu`` (``pytest -m gpu``);
``bench render`` on the device and on the CPU (the same size and samples; the CPU with
:data:`CPU_BASELINE_THREADS` threads, the dev machine's cores) and their ratio; ``bench fit`` on the
real pairs and on the dev goldens (``../shared/data/real``, ``../shared/data/golden``) on the device,
each pair's wall time and quality. Each benchmark appends to the results ledger as it always does
(``devtools/bench/results/``, unless ``--no-record``), and what it appended is copied to ``--out`` too.

A step is started only where the budget has its :attr:`Step.min_s` left, and stopped at the budget's
end (or its own cap); what was skipped or stopped says so, in the log and in the summary. Everything
lands in ``--out``: ``gpu-check.log`` (every step's output), ``summary.json``, ``gpu-tests.xml``
(pytest's JUnit report) and ``ledger/`` (the records the benchmarks appended), so a device machine's
output folder brings it all back.

``--device cpu --quick`` is a dry run of the same plan on any machine (the GPU tests only collected,
small renders, one pair of each set with a short fit): the plumbing, not the figures.
"""
from __future__ import annotations

import json
import math
import os
import platform
import re
import shlex
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import torch

from backend.core.pairs import find_pairs

from .bench.ledger import RESULTS

ROOT = Path(__file__).resolve().parents[1]  # the checkout: tests/ and the packages
SHARED_DATA = ROOT.parent / "shared" / "data"  # goldens and real pairs beside the checkout, as the tests find them
DEFAULT_BUDGET_S = 540.0  # the whole check, under the 10 minutes a device machine is lent for at a time
CPU_BASELINE_THREADS = 2  # the CPU render's threads: the dev machine's 2 cores, the baseline of the speed target
RENDER_TARGET_RATIO = 20.0  # bench render on the GPU at least this many times the 2-core CPU (issue 89)
REAL_FIT_TARGET_S = 10.0  # a fit of a real pair on the GPU under this many seconds (issue 89)
TESTS_CAP_S = 300.0  # the GPU tests at most (a cold torch.compile on CUDA is in them): room for the benchmarks
TESTS_MIN_S = 60.0  # the GPU tests are not started with less left: they would be stopped half-way
RENDER_CAP_S = 150.0  # one bench render at most (a cold compile, then a few timed renders)
RENDER_MIN_S = 20.0  # a bench render is not started with less left
FIT_MIN_S = 30.0  # a fit set is not started with less left (one pair's fit and the process's start)


@dataclass
class Step:
    """One command of the plan: run as a subprocess, stopped after ``cap_s`` or at the budget's end,
    not started with less than ``min_s`` left; ``parse`` reads its figures from its standard output."""

    name: str
    argv: list[str]
    cap_s: float
    min_s: float
    parse: Callable[[str], dict]
    env: dict = field(default_factory=dict)
    unavailable: str | None = None  # why it cannot run here (its data missing): reported as skipped


@dataclass
class Outcome:
    """What a command did: its exit status (None: stopped at its time limit), output and seconds."""

    returncode: int | None
    stdout: str
    seconds: float


Runner = Callable[[Step, float, Callable[[str], None]], Outcome]


def shared_folder(name: str) -> Path:
    return SHARED_DATA / name


def plan(device: str, quick: bool, golden: Path, real: Path, out: Path, record: bool = True
         ) -> list[Step]:
    """The steps of a check on ``device`` (``quick``: a dry run's small sizes)."""
    python = [sys.executable]
    no_record = [] if record else ["--no-record"]
    steps = [_tests_step(python, device, quick, out)]
    size, spp, runs = (64, 4, 1) if quick else (512, 4, 3)
    render = ["-m", "devtools", "bench", "render", "--json", "--size", str(size), "--spp", str(spp),
              "--runs", str(runs), *no_record]
    quick_env = {"WFC_COMPILE": "0"} if quick else {}
    steps.append(Step(render_step(device), python + render + ["--device", device], RENDER_CAP_S, RENDER_MIN_S,
                      last_json, env=quick_env))
    steps.append(Step(render_step("cpu", CPU_BASELINE_THREADS), python + render + ["--device", "cpu"], RENDER_CAP_S,
                      RENDER_MIN_S, last_json, env={**quick_env, "OMP_NUM_THREADS": str(CPU_BASELINE_THREADS)}))
    fit = ["-m", "devtools", "bench", "fit", "--json", "--device", device, *no_record]
    if quick:
        fit += ["--iterations", "2", "--no-novel-light", "--fit-args=--size 64 --output-spp 1"]
    for kind, folder, option in (("real", real, "--real"), ("golden", golden, "--golden")):
        name = f"fit-{kind}"
        if not folder.is_dir():
            steps.append(Step(name, [], 0.0, 0.0, fit_rows, unavailable=f"no {kind} pairs at {folder}"))
            continue
        cases = _first_pair(folder, kind) if quick else []
        # bounded by the budget alone: the fits are the figures the check is for
        steps.append(Step(name, python + fit + [option, str(folder)] + (["--cases", *cases] if cases else []),
                          math.inf, FIT_MIN_S, fit_rows, env=quick_env))
    return steps


def render_step(device: str, threads: int | None = None) -> str:
    """The name of a bench render step (the CPU baseline's names its threads)."""
    return f"render on {device}" + (f" ({threads} threads)" if threads else "")


def _tests_step(python: list[str], device: str, quick: bool, out: Path) -> Step:
    """``pytest -m gpu`` (with ``--device cpu`` only collected: the tests need CUDA)."""
    argv = python + ["-m", "pytest", "-m", "gpu", "-n", "0", "-p", "no:cacheprovider", "-q", "tests/test_gpu.py"]
    if device == "cpu":
        return Step("gpu-tests (collected only: --device cpu)", argv + ["--collect-only"], TESTS_CAP_S, RENDER_MIN_S,
                    pytest_counts)
    return Step("gpu-tests", argv + [f"--junitxml={out / 'gpu-tests.xml'}"], TESTS_CAP_S, TESTS_MIN_S,
                pytest_counts)


def _first_pair(folder: Path, kind: str) -> list[str]:
    """A dry run's one pair of a set: the first golden case without ablation flags, or the first real pair."""
    if kind == "golden":
        cases = json.loads((folder / "cases.json").read_text())
        return [next(case["name"] for case in cases if not case.get("flags"))]
    pairs = find_pairs(folder)[0]
    return [pairs[0].name] if pairs else []


def _json_lines(stdout: str) -> list[dict]:
    """The JSON objects a command printed, one a line (a line cut off where it was stopped is left out)."""
    objects = []
    for line in stdout.splitlines():
        if line.startswith("{"):
            try:
                objects.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return objects


def last_json(stdout: str) -> dict:
    """The last JSON object a command printed (a benchmark's result or summary)."""
    objects = _json_lines(stdout)
    return objects[-1] if objects else {}


def fit_rows(stdout: str) -> dict:
    """``bench fit --json``'s rows (one per pair: a row has a name) and its summary."""
    rows, summary = [], {}
    for data in _json_lines(stdout):
        (rows.append(data) if "name" in data else summary.update(data))
    return {"pairs": rows, "summary": summary}


def pytest_counts(stdout: str) -> dict:
    """pytest's counts from its last line ("3 passed, 1 failed in 9.1s", "8 tests collected in 2.0s")."""
    counts = {}
    for number, word in re.findall(r"(\d+) (passed|failed|errors?|skipped|deselected|tests? collected)", stdout):
        counts[word.replace("tests collected", "collected").replace("test collected", "collected")] = int(number)
    return counts


def machine(device: str) -> dict:
    """The machine the check ran on: the GPU, torch and its CUDA, the CPU's cores."""
    info = {"device": device, "python": platform.python_version(), "torch": torch.__version__,
            "cuda": torch.version.cuda, "cuda_available": torch.cuda.is_available(), "cores": os.cpu_count()}
    if torch.cuda.is_available():
        props = torch.cuda.get_device_properties(0)
        info.update(gpu=props.name, gpu_memory_gib=round(props.total_memory / 2 ** 30, 1),
                    cudnn=torch.backends.cudnn.version(), gpu_count=torch.cuda.device_count())
    return info


def run_command(step: Step, timeout: float, echo: Callable[[str], None]) -> Outcome:
    """``step``'s command in the checkout, its output echoed line by line as it comes; stopped (its whole
    process group: the benchmarks' fits, the tests' commands) after ``timeout`` seconds."""
    started = time.perf_counter()
    proc = subprocess.Popen(step.argv, cwd=ROOT, env={**os.environ, **step.env}, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines: list[str] = []

    def read():
        for line in proc.stdout:
            lines.append(line)
            echo(line.rstrip("\n"))

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        returncode = proc.wait(timeout=max(timeout, 0.0))
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)  # the group this call started (start_new_session), nothing else
        proc.wait()
        returncode = None
    reader.join(timeout=10)
    return Outcome(returncode, "".join(lines), time.perf_counter() - started)


def run_check(steps: list[Step], budget_s: float, out: Path, device: str, runner: Runner = run_command,
              clock: Callable[[], float] = time.monotonic, machine_info: dict | None = None,
              ledger_folder: Path = RESULTS) -> dict:
    """Runs ``steps`` in order within ``budget_s`` seconds, writing ``out/gpu-check.log`` and
    ``out/summary.json``; returns the summary."""
    out.mkdir(parents=True, exist_ok=True)
    started = clock()
    log_path = out / "gpu-check.log"
    with log_path.open("w", encoding="utf-8") as log_file:
        def say(text: str) -> None:
            print(text, flush=True)
            log_file.write(text + "\n")
            log_file.flush()

        info = machine(device) if machine_info is None else machine_info
        say(f"== gpu-check on {device}: budget {budget_s:.0f} s, output in {out}")
        say("machine: " + json.dumps(info))
        ledger_before = _ledger_sizes(ledger_folder)
        summary = {"device": device, "budget_s": budget_s, "machine": info, "steps": {}}
        for step in steps:
            left = budget_s - (clock() - started)
            if step.unavailable:
                say(f"== {step.name}: SKIPPED, {step.unavailable}")
                summary["steps"][step.name] = {"status": "skipped", "reason": step.unavailable}
                continue
            if left < step.min_s:
                say(f"== {step.name}: SKIPPED, {left:.0f} s of the budget left, it needs {step.min_s:.0f} s at least")
                summary["steps"][step.name] = {"status": "skipped", "reason": f"budget: {left:.0f} s left"}
                continue
            limit = min(step.cap_s, left)
            say(f"== {step.name} (at most {limit:.0f} s): {shlex.join(step.argv)}")
            outcome = runner(step, limit, say)
            status = ("stopped" if outcome.returncode is None else "ok" if outcome.returncode == 0
                      else f"failed (exit {outcome.returncode})")
            record = {"status": status, "seconds": round(outcome.seconds, 1), **step.parse(outcome.stdout)}
            if outcome.returncode is None:
                record["reason"] = f"stopped after {limit:.0f} s (the budget or its cap); its figures are partial"
            summary["steps"][step.name] = record
            say(f"== {step.name}: {status.upper()} in {outcome.seconds:.1f} s")
        summary["figures"] = figures(summary["steps"], device)
        summary["seconds"] = round(clock() - started, 1)
        summary["ledger"] = _copy_ledger(ledger_folder, ledger_before, out / "ledger")
        summary["complete"] = all(step["status"] == "ok" for step in summary["steps"].values())
        for line in report_lines(summary):
            say(line)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return summary


def figures(steps: dict, device: str) -> dict:
    """The headline figures: the render's speed ratio (forward + backward, compiled where both were,
    and eager), each fit set's wall times and quality, against the targets."""
    result: dict = {}
    gpu, cpu = steps.get(render_step(device), {}), steps.get(render_step("cpu", CPU_BASELINE_THREADS), {})
    if gpu.get("backward_s") and cpu.get("backward_s"):
        result["render_ratio"] = round(cpu["backward_s"] / gpu["backward_s"], 2)
        result["render_ratio_eager"] = round(cpu["eager_backward_s"] / gpu["eager_backward_s"], 2)
        result["render_target_ratio"] = RENDER_TARGET_RATIO
        result["render_compiled"] = {"device": gpu.get("compiled"), "cpu": cpu.get("compiled")}
    for kind in ("real", "golden"):
        pairs = steps.get(f"fit-{kind}", {}).get("pairs", [])
        done = [p for p in pairs if "error" not in p]
        if not pairs:
            continue
        walls = [p["wall_s"] for p in done]
        result[f"fit_{kind}"] = {
            "pairs": len(pairs), "errors": len(pairs) - len(done),
            "wall_s_max": max(walls, default=None), "wall_s_mean": round(sum(walls) / len(walls), 1) if walls else None,
            "flip_mean": _mean(done, ("flip_R", "flip_T")),
            "spectrum_corr_mean": _mean(done, ("spectrum_corr_R", "spectrum_corr_T"))}
        if kind == "real":
            result["fit_real"]["target_wall_s"] = REAL_FIT_TARGET_S
    return result


def _mean(rows: list[dict], keys: tuple[str, ...]) -> float | None:
    values = [row[k] for row in rows for k in keys if k in row]
    return round(sum(values) / len(values), 4) if values else None


def report_lines(summary: dict) -> list[str]:
    """The summary in a few lines: each step's status, then the figures."""
    lines = ["== summary"]
    for name, step in summary["steps"].items():
        extra = step.get("reason", "")
        counts = {k: v for k, v in step.items() if k in ("passed", "failed", "error", "errors", "collected")}
        lines.append(f"  {name:40s} {step['status']:18s} {step.get('seconds', '')!s:>7s} s  {counts or ''} {extra}")
        for pair in step.get("pairs", []):
            quality = ("ERROR " + str(pair["error"])[:80] if "error" in pair else
                       f"{pair.get('pattern')}  FLIP {pair.get('flip_R')}/{pair.get('flip_T')}  "
                       f"spectrum {pair.get('spectrum_corr_R')}/{pair.get('spectrum_corr_T')}")
            lines.append(f"      {pair['kind']:7s} {pair['name']:18s} {pair['wall_s']:6.1f} s  {quality}")
    figures_ = summary["figures"]
    if "render_ratio" in figures_:
        lines.append(f"  render forward+backward: {summary['device']} is {figures_['render_ratio']}x the CPU's "
                     f"{CPU_BASELINE_THREADS} threads (eager: {figures_['render_ratio_eager']}x; "
                     f"target {RENDER_TARGET_RATIO:.0f}x)")
    if "fit_real" in figures_ and figures_["fit_real"]["wall_s_max"] is not None:
        lines.append(f"  real pairs: slowest fit {figures_['fit_real']['wall_s_max']} s "
                     f"(target under {REAL_FIT_TARGET_S:.0f} s)")
    lines.append(f"  {summary['seconds']} s in all; ledger records copied: {summary['ledger'] or 'none'}")
    if not summary["complete"]:
        lines.append("  NOT COMPLETE: a step above was skipped, stopped or failed")
    return lines


def _ledger_sizes(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_size for p in folder.glob("*.jsonl")} if folder.exists() else {}


def _copy_ledger(folder: Path, before: dict[str, int], target: Path) -> dict[str, int]:
    """The records the steps appended to the ledger, copied under ``target``: {file: records}."""
    copied = {}
    for name, size in _ledger_sizes(folder).items():
        start = before.get(name, 0)
        if size > start:
            with (folder / name).open("rb") as ledger:
                ledger.seek(start)
                added = ledger.read()
            target.mkdir(parents=True, exist_ok=True)
            (target / name).write_bytes(added)
            copied[name] = added.count(b"\n")
    return copied
