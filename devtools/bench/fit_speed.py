"""The fit with and without the compiler: ``python -m devtools bench fit-speed [REFLECTION TRANSMISSION]
[--rounds N] [--iterations N] [--size N] [--json]``.

Runs the real ``fit`` command (a subprocess per fit, as the add-on runs it) on one photo pair, by
default the bundled example rendered once, with ``WFC_COMPILE=1`` (torch.compile) and
``WFC_COMPILE=0`` (the eager renderer that machines without a C++ compiler get). One compiled fit
first pays for (or loads from the disk cache) the compilation and is reported apart; then each
round runs a compiled and an eager fit back to back, alternating which goes first, so both see the
same machine load. Per fit: wall time, the CPU time of its process (user + system; POSIX only) and
the fit's stage timings. The summary gives the medians, the eager / compiled ratios of the medians
and, as a measure of the noise, the range of the per-round ratios. Both paths must find the same
parameters: the largest difference of the fitted values between the two is printed too.
"""
from __future__ import annotations

import statistics
import sys
import tempfile
from pathlib import Path

from backend.app.environment import compiler_found
from backend.app.folder import make_example
from backend.core.params import PARAMETERS

from .fit import run_fit
from .ledger import NOT_RECORDED, Ledger

MODES = {"compiled": {"WFC_COMPILE": "1"}, "eager": {"WFC_COMPILE": "0"}}


def pair_or_example(reflection: str | None, transmission: str | None, folder: Path) -> tuple[Path, Path]:
    """The given photo pair, or (none given) the fit command's own example pair rendered into ``folder``."""
    if reflection:
        return Path(reflection), Path(transmission)
    reflection, transmission, _ = make_example(folder)
    return reflection, transmission


def _largest_difference(a, b) -> float:
    return max(abs(x - y) for spec in PARAMETERS for x, y in zip(a.flat(spec.name), b.flat(spec.name)))


def bench_fit_speed(reflection: str | None, transmission: str | None, rounds: int, extra: list[str],
                    as_json: bool, ledger: Ledger = NOT_RECORDED) -> int:
    if not compiler_found():
        print("bench fit-speed: torch.compile needs a C++ compiler and none was found", file=sys.stderr)
        return 1
    runs: list[dict] = []

    def fit(mode: str, round_index: int, pair, tmp: Path) -> dict:
        result = run_fit(*pair, tmp / f"{mode}_{round_index}", extra, MODES[mode])
        if "error" not in result and "torch.compile failed" in result["stderr"]:
            result["error"] = "the compiled fit fell back to the eager renderer"
        row = {"round": round_index, "mode": mode, "wall_s": round(result["wall_s"], 2)}
        if "error" in result:
            row["error"] = result["error"]
        else:
            row.update(cpu_s=None if result["cpu_s"] is None else round(result["cpu_s"], 2),
                       timings=result["timings"], params=result["params"])
        runs.append(row)
        shown = {k: v for k, v in row.items() if k != "params"}
        ledger.print_row(shown, as_json, _run_text)
        return row

    with tempfile.TemporaryDirectory(prefix="fit-speed-") as tmp_name:
        tmp = Path(tmp_name)
        pair = pair_or_example(reflection, transmission, tmp / "photos")
        fit("compiled", 0, pair, tmp)  # compilation (or its disk cache), reported apart
        for index in range(1, rounds + 1):
            order = ("compiled", "eager") if index % 2 else ("eager", "compiled")
            for mode in order:
                fit(mode, index, pair, tmp)
    summary = _summary(runs)
    ledger.print_summary(summary, as_json, _format_summary)
    return 0 if all("error" not in r for r in runs) else 1


def _run_text(row: dict) -> str:
    label = "warm-up" if row["round"] == 0 else f"round {row['round']}"
    if "error" in row:
        return f"{label:9s} {row['mode']:8s} ERROR {row['error']}"
    cpu = "" if row["cpu_s"] is None else f"  cpu {row['cpu_s']:7.1f} s"
    optimise = row["timings"].get("optimise_s")
    return (f"{label:9s} {row['mode']:8s} wall {row['wall_s']:7.1f} s{cpu}  (fit {row['timings'].get('total_s')} s, "
            f"optimise {optimise} s)")


def _summary(runs: list[dict]) -> dict:
    timed = [r for r in runs if r["round"] > 0 and "error" not in r]
    out = {"rounds": max((r["round"] for r in runs), default=0), "failed": sum("error" in r for r in runs)}
    for key in ("wall_s", "cpu_s"):
        ratios = _ratios(timed, key)
        if ratios is not None:
            out[key] = ratios
    out.update(_agreement([r for r in runs if "params" in r]))
    return out


def _ratios(timed: list[dict], key: str) -> dict | None:
    """The medians of ``key`` (wall or CPU seconds) per mode and eager / compiled of the medians and of
    each round; None where a mode has no figure."""
    by_mode = {m: [r[key] for r in timed if r["mode"] == m and r[key] is not None] for m in MODES}
    if not all(by_mode.values()):
        return None
    medians = {m: statistics.median(v) for m, v in by_mode.items()}
    rounds = {}
    for r in timed:
        rounds.setdefault(r["round"], {})[r["mode"]] = r[key]
    ratios = [v["eager"] / v["compiled"] for v in rounds.values() if len(v) == 2]
    return {"compiled_median": round(medians["compiled"], 2), "eager_median": round(medians["eager"], 2),
            "ratio": round(medians["eager"] / medians["compiled"], 3), "round_ratios": [round(x, 3) for x in ratios]}


def _agreement(fitted: list[dict]) -> dict:
    """Where more than one fit finished: the largest difference of a fitted value from the first
    fit's, and the patterns they found."""
    if len(fitted) < 2:
        return {}
    return {"largest_parameter_difference": max(_largest_difference(fitted[0]["params"], r["params"])
                                                for r in fitted[1:]),
            "patterns": sorted({r["params"].pattern for r in fitted})}


def _format_summary(s: dict) -> str:
    lines = [f"summary: {s['rounds']} rounds, {s['failed']} failed fits"]
    for key, name in (("wall_s", "wall"), ("cpu_s", "cpu")):
        if key in s:
            k = s[key]
            lines.append(f"  {name:4s} eager {k['eager_median']:.1f} s / compiled {k['compiled_median']:.1f} s"
                         f" = {k['ratio']:.2f}x (per round: {', '.join(f'{x:.2f}' for x in k['round_ratios'])})")
    if "largest_parameter_difference" in s:
        lines.append(f"  patterns {', '.join(s['patterns'])}; largest difference of a fitted value between fits "
                     f"{s['largest_parameter_difference']:.2e}")
    return "\n".join(lines)
