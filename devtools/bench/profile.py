"""Where a fit's time goes: ``python -m devtools bench profile [--pair R T] [--iterations N]
[--fit-args "..."] [--top N] [--operators] [--json]``.

Runs one whole ``fit`` command in this process (by default on the bundled example, rendered first)
and prints:

- ``stages``: the fit's own stage timings (metrics.json ``timings``: the lattice, the search, the
  optimisation) and the rest of the command (loading, re-renders, metrics, report), seconds and
  shares of the command's wall time;
- ``passes``: the wall time inside autograd's backward passes (``torch.autograd.backward`` and
  ``torch.autograd.grad``, timed around each call) and inside the optimiser's steps (``Adam.step``),
  and their shares: the rest is the forward renders, the search's decisions and the files;
- ``functions``: the backend's Python functions (:mod:`cProfile`), the top by cumulative time and
  by self time (calls, seconds);
- with ``--operators``, ``operators``: torch's operators (:mod:`torch.profiler`, CPU), their self
  time split into the backward pass (an operator with an ancestor event of autograd's engine,
  ``autograd::engine::evaluate_function: ...``), the optimiser's step (under ``Optimizer.step``)
  and the rest, with the top operators of each. The profiler keeps every event in memory (a
  default fit of a real pair needs more than 20 GB): give it a short fit (``--iterations``,
  ``--fit-args "--size 128"``).

cProfile slows the fit where Python loops: read shares, not seconds, and compare a before and an
after measured on the same machine. The ledger (``devtools/bench/results/profile.jsonl``) keeps one
record per section and the summary.
"""
from __future__ import annotations

import cProfile
import functools
import json
import pstats
import tempfile
import time
from collections import defaultdict
from contextlib import ExitStack, contextmanager
from pathlib import Path

import torch

from backend.app.cli.main import main as backend_main

from .ledger import NOT_RECORDED, Ledger

BACKWARD_MARK = "autograd::engine::evaluate_function"  # autograd's engine runs a node's backward under it
STEP_MARK = "Optimizer.step"                            # torch.optim's step (Adam.step) is recorded under it


def pass_of(event, memo: dict) -> str:
    """"backward", "step" or "forward": the pass an operator event ran in, from its ancestors' names."""
    chain, kind = [], None
    while event is not None and kind is None:
        kind = memo.get(id(event))
        if kind is None:
            if event.name.startswith(BACKWARD_MARK):
                kind = "backward"
            elif event.name.startswith(STEP_MARK):
                kind = "step"
            else:
                chain.append(event)
                event = event.cpu_parent
    kind = kind or "forward"
    for seen in chain:
        memo[id(seen)] = kind
    return kind


def operator_split(events, top: int) -> dict:
    """Self CPU seconds of the operators per pass, and each pass's ``top`` operators by self time."""
    memo: dict = {}
    seconds = defaultdict(float)
    by_name = defaultdict(lambda: defaultdict(float))
    for event in events:
        if event.name.startswith((BACKWARD_MARK, STEP_MARK)):
            continue  # markers: their own time is the engine's bookkeeping, counted in the rest
        kind = pass_of(event, memo)
        spent = event.self_cpu_time_total / 1e6
        seconds[kind] += spent
        by_name[kind][event.name] += spent
    total = sum(seconds.values()) or 1.0
    out = {"section": "operators", "total_s": round(sum(seconds.values()), 6)}  # to the profiler's microsecond
    for kind in PASSES:
        out[f"{kind}_s"] = round(seconds[kind], 6)
        out[f"{kind}_share"] = round(seconds[kind] / total, 3)
        names = sorted(by_name[kind].items(), key=lambda item: -item[1])[:top]
        out[f"top_{kind}"] = [[name, round(s, 6)] for name, s in names]
    return out


def function_table(stats: pstats.Stats, top: int, package: str = "backend") -> dict:
    """The ``package``'s functions: the top by cumulative and by self seconds, [function, calls, s]."""
    rows = []
    for (path, line, name), (_, calls, self_s, cumulative_s, _) in stats.stats.items():
        module = _module_of(path, package)
        if module is not None:
            rows.append((f"{module}.{name}:{line}", calls, self_s, cumulative_s))
    cumulative = sorted(rows, key=lambda row: -row[3])[:top]
    own = sorted(rows, key=lambda row: -row[2])[:top]
    return {"section": "functions",
            "top_cumulative": [[name, calls, round(cum, 3)] for name, calls, _, cum in cumulative],
            "top_self": [[name, calls, round(s, 3)] for name, calls, s, _ in own]}


def _module_of(path: str, package: str) -> str | None:
    parts = Path(path).with_suffix("").parts
    if package not in parts:
        return None
    module = parts[len(parts) - 1 - parts[::-1].index(package):]
    return ".".join(module[:-1] if module[-1] == "__init__" else module)


def stage_table(timings: dict, wall_s: float) -> dict:
    """The fit's stages from its timings (backend/fit/pipeline.py: ``search_s`` runs from the start,
    so it holds ``lattice_s``; ``warp_s`` is part of ``optimise_s``) and the command's rest (loading,
    re-renders, metrics, report): seconds and shares of the command's wall time."""
    lattice, search = float(timings.get("lattice_s", 0.0)), float(timings.get("search_s", 0.0))
    stages = {"lattice": lattice, "search": search - lattice, "optimise": float(timings.get("optimise_s", 0.0))}
    stages["rest"] = max(wall_s - float(timings.get("total_s", sum(stages.values()))), 0.0)
    return {"section": "stages", "wall_s": round(wall_s, 3), "warp_of_optimise_s": round(timings.get("warp_s", 0.0), 3),
            "stages": {name: [round(s, 3), round(s / wall_s, 3)] for name, s in stages.items()}}


@contextmanager
def timed(owner, name: str, seconds: dict, key: str):
    """``owner.name`` replaced, while the block runs, by a wrapper adding each call's wall time to
    ``seconds[key]`` (a call inside another timed one of the same key is not counted twice)."""
    original = getattr(owner, name)
    depth = [0]

    @functools.wraps(original)
    def wrapper(*args, **kwargs):
        depth[0] += 1
        started = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            depth[0] -= 1
            if depth[0] == 0:
                seconds[key] += time.perf_counter() - started

    setattr(owner, name, wrapper)
    try:
        yield
    finally:
        setattr(owner, name, original)


def pass_table(seconds: dict, wall_s: float) -> dict:
    """The timed passes' seconds and shares of the command's wall time."""
    return {"section": "passes", **{f"{kind}_s": round(s, 6) for kind, s in seconds.items()},
            **{f"{kind}_share": round(s / wall_s, 3) for kind, s in seconds.items()}}


def bench_profile(pair: tuple[str, str] | None, fit_args: list[str], top: int, as_json: bool,
                  with_operators: bool = False, ledger: Ledger = NOT_RECORDED) -> int:
    seconds = {"backward": 0.0, "step": 0.0}
    with tempfile.TemporaryDirectory(prefix="wfc-profile-") as tmp, ExitStack() as hooks:
        out = Path(tmp) / "fit"
        command = ["fit", *(pair or ()), *([] if pair else ["--example"]), *fit_args]
        argv = [*command, "--out", str(out)]
        hooks.enter_context(timed(torch.autograd, "backward", seconds, "backward"))
        hooks.enter_context(timed(torch.autograd, "grad", seconds, "backward"))
        hooks.enter_context(timed(torch.optim.Adam, "step", seconds, "step"))
        operators = hooks.enter_context(torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU])) \
            if with_operators else None
        python = cProfile.Profile()
        started = time.perf_counter()
        code = python.runcall(backend_main, argv)
        wall = time.perf_counter() - started
        if code != 0:
            print(f"bench profile: the fit ended with exit code {code}")
            return code
        timings = json.loads((out / "metrics.json").read_text()).get("timings", {})
    rows = [stage_table(timings, wall), pass_table(seconds, wall), function_table(pstats.Stats(python), top)]
    if operators is not None:
        rows.append(operator_split(operators.events(), top))
    for row in rows:
        ledger.print_row(row, as_json, _text)
    summary = {"summary": "profile", "wall_s": round(wall, 2), "fit": command}
    ledger.print_summary(summary, as_json, lambda s: f"profiled wall {s['wall_s']} s (both profilers on)")
    return 0


PASSES = ("forward", "backward", "step")


def _text(row: dict) -> str:
    if row["section"] == "stages":
        return "stages: " + ", ".join(f"{name} {s:.1f} s ({share:.0%})" for name, (s, share) in row["stages"].items())
    if row["section"] == "passes":
        return "passes: " + ", ".join(f"{kind} {row[kind + '_s']:.1f} s ({row[kind + '_share']:.0%} of the wall)"
                                      for kind in ("backward", "step"))
    if row["section"] == "operators":
        split = ", ".join(f"{kind} {row[kind + '_s']:.1f} s ({row[kind + '_share']:.0%})" for kind in PASSES)
        lines = [f"operators (self CPU {row['total_s']:.1f} s): {split}"]
        lines += [f"  {kind}: " + ", ".join(f"{name} {s:.2f}" for name, s in row[f"top_{kind}"])
                  for kind in ("forward", "backward")]
        return "\n".join(lines)
    lines = ["functions, cumulative:"]
    lines += [f"  {name}: {calls} calls, {s:.2f} s" for name, calls, s in row["top_cumulative"]]
    lines += ["functions, self:"]
    lines += [f"  {name}: {calls} calls, {s:.2f} s" for name, calls, s in row["top_self"]]
    return "\n".join(lines)
