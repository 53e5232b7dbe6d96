"""The same fit from the add-on and from the command line: ``python -m devtools bench addon-fit
[--pair REFLECTION TRANSMISSION] [--rounds N] [--iterations N] [--fit-size N] [--json]``.

Builds the extension zip (``build.py``) once, then each round runs the ``fit`` command (a subprocess,
as :mod:`devtools.bench.fit` does) and the add-on's Fit operator in a fresh Python with the ``bpy``
module: the zip installed into a throwaway Blender user folder, the real backend (this checkout's
interpreter, ``WOVEN_FABRIC_PYTHON``), ``bpy.ops.fabric.fit()`` run as background mode runs it (the
operator follows its backend subprocess to the end, then makes the material). The two take turns at
going first, so both see the same machine load. Per fit: the wall time of its process, the fit's own
wall (``metrics.json``) and its loss; for the add-on also the operator's time and, inside it, the
material's (the node group's build, :func:`blender_addon.scene.node_group.create_material`, and the
asset's preview). The summary gives the medians, add-on / command line of the medians and of each
round, and where the add-on's time beyond its fit goes. Both must fit the same parameters: their
losses are printed side by side.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

from .fit import run_fit
from .fit_speed import pair_or_example
from .ledger import NOT_RECORDED, Ledger

ROOT = Path(__file__).resolve().parents[2]
EXTENSION = "bl_ext.user_default.woven_fabric"
TIMEOUT_S = 3600  # a liveness bound of one add-on fit, not a timing

# Runs in the bpy Python: installs the zip, times the operator and the material's steps inside it.
_SCRIPT = """
import functools, importlib, json, sys, time
import bpy
zip_path, results, reflection, transmission, iterations, size, pattern = sys.argv[1:8]
assert bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                enable_on_install=True) == {"FINISHED"}
ext = importlib.import_module(%(extension)r)
times = {}

def timed(owner, name, key):
    original = getattr(owner, name)
    @functools.wraps(original)
    def wrapper(*args, **kwargs):
        started = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            times[key] = times.get(key, 0.0) + time.perf_counter() - started
    setattr(owner, name, wrapper)

scene_modules = {n: importlib.import_module(ext.__name__ + ".scene." + n) for n in ("materials", "node_group")}
timed(scene_modules["materials"], "new_fit_material", "material_s")
timed(scene_modules["node_group"], "create_material", "node_group_s")
bpy.context.preferences.addons[ext.__name__].preferences.results_folder = results
settings = bpy.context.scene.woven_fabric
settings.reflection_path, settings.transmission_path = reflection, transmission
settings.pattern = pattern
if int(iterations):
    settings.iterations = int(iterations)
if int(size):
    settings.size = int(size)
started = time.perf_counter()
assert bpy.ops.fabric.fit() == {"FINISHED"}
times["operator_s"] = time.perf_counter() - started
print("TIMES " + json.dumps(times), flush=True)
""" % {"extension": EXTENSION}


def build_zip(folder: Path) -> Path:
    """The extension zip of this checkout (``build.py --out folder``)."""
    done = subprocess.run([sys.executable, str(ROOT / "build.py"), "--out", str(folder)], capture_output=True,
                          text=True, check=True)
    return Path(done.stdout.strip())


def addon_fit(zip_path: Path, pair: tuple[Path, Path], work: Path, iterations: int = 0, size: int = 0,
              pattern: str = "auto") -> dict:
    """The add-on's Fit operator on ``pair`` in a fresh bpy Python (see the module docstring)."""
    work.mkdir(parents=True, exist_ok=True)
    script = work / "addon_fit.py"
    script.write_text(textwrap.dedent(_SCRIPT))
    results = work / "results"
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(work / "blender_user"), "WOVEN_FABRIC_PYTHON": sys.executable,
           "WOVEN_FABRIC_BACKEND_SCRIPT": "", "PYTHONUNBUFFERED": "1"}
    started = time.perf_counter()
    done = subprocess.run([sys.executable, str(script), str(zip_path), str(results), *map(str, pair), str(iterations),
                           str(size), pattern], capture_output=True, text=True, env=env, cwd=work, timeout=TIMEOUT_S)
    wall = time.perf_counter() - started
    times = [line[6:] for line in done.stdout.splitlines() if line.startswith("TIMES ")]
    folders = sorted(results.iterdir()) if results.is_dir() else []
    if done.returncode != 0 or not times or not folders:
        return {"error": (done.stdout + done.stderr)[-800:], "wall_s": wall}
    metrics = json.loads((folders[0] / "metrics.json").read_text())
    return {"wall_s": wall, "fit_s": metrics["wall_s"], "loss": metrics["loss"], **json.loads(times[0])}


def cli_fit(pair: tuple[Path, Path], out: Path, iterations: int = 0, size: int = 0, pattern: str = "auto") -> dict:
    """The ``fit`` command on ``pair`` (:func:`devtools.bench.fit.run_fit`)."""
    extra = (["--iterations", str(iterations)] if iterations else []) + (["--size", str(size)] if size else [])
    extra += ["--pattern", pattern]
    result = run_fit(*pair, out, extra)
    if "error" in result:
        return {"error": result["error"], "wall_s": result["wall_s"]}
    metrics = json.loads((out / "metrics.json").read_text())
    return {"wall_s": result["wall_s"], "fit_s": metrics["wall_s"], "loss": metrics["loss"]}


def summary(rows: list[dict]) -> dict:
    """Medians per way, add-on / command line of the medians and of each round, and the add-on's
    time beyond its fit (operator - fit) with the material's part of it."""
    done = [r for r in rows if "error" not in r]
    out = {"rounds": max((r["round"] for r in rows), default=0), "failed": len(rows) - len(done)}
    walls = {way: [r["wall_s"] for r in done if r["way"] == way] for way in ("cli", "addon")}
    if not all(walls.values()):
        return out
    medians = {way: statistics.median(v) for way, v in walls.items()}
    by_round: dict[int, dict] = {}
    for r in done:
        by_round.setdefault(r["round"], {})[r["way"]] = r["wall_s"]
    addon = [r for r in done if r["way"] == "addon"]
    out.update(cli_median_s=round(medians["cli"], 2), addon_median_s=round(medians["addon"], 2),
               ratio=round(medians["addon"] / medians["cli"], 3),
               round_ratios=[round(v["addon"] / v["cli"], 3) for _, v in sorted(by_round.items()) if len(v) == 2],
               beyond_fit_s=round(statistics.median(r["operator_s"] - r["fit_s"] for r in addon), 2),
               material_s=round(statistics.median(r.get("material_s", 0.0) for r in addon), 2),
               node_group_s=round(statistics.median(r.get("node_group_s", 0.0) for r in addon), 2),
               losses=sorted({round(r["loss"], 6) for r in done}))
    return out


def format_summary(s: dict) -> str:
    lines = [f"summary: {s['rounds']} rounds, {s['failed']} failed fits"]
    if "ratio" in s:
        lines.append(f"  wall: add-on {s['addon_median_s']:.1f} s / command line {s['cli_median_s']:.1f} s = "
                     f"{s['ratio']:.3f} (per round: {', '.join(f'{x:.3f}' for x in s['round_ratios'])})")
        lines.append(f"  the add-on's operator beyond its fit: {s['beyond_fit_s']:.1f} s, of which the material "
                     f"{s['material_s']:.1f} s (its node group {s['node_group_s']:.1f} s); losses "
                     f"{', '.join(str(x) for x in s['losses'])}")
    return "\n".join(lines)


def bench_addon_fit(reflection: str | None, transmission: str | None, rounds: int, iterations: int, size: int,
                    as_json: bool, ledger: Ledger = NOT_RECORDED, pattern: str = "auto") -> int:
    """``rounds`` rounds of the two ways (``iterations``, ``size``: the fit's, 0 for its defaults;
    ``pattern``: the fit's weave, auto by default); exit 0 where every fit finished."""
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="addon-fit-") as tmp_name:
        tmp = Path(tmp_name)
        pair = pair_or_example(reflection, transmission, tmp / "photos")
        zip_path = build_zip(tmp / "dist")
        for index in range(1, rounds + 1):
            for way in (("cli", "addon") if index % 2 else ("addon", "cli")):
                work = tmp / f"{way}_{index}"
                result = cli_fit(pair, work, iterations, size, pattern) if way == "cli" else \
                    addon_fit(zip_path, pair, work, iterations, size, pattern)
                row = {"round": index, "way": way, **{k: round(v, 3) if isinstance(v, float) else v
                                                       for k, v in result.items()}}
                rows.append(row)
                ledger.print_row(row, as_json, _row_text)
    s = summary(rows)
    ledger.print_summary(s, as_json, format_summary)
    return 0 if s["failed"] == 0 else 1


def _row_text(row: dict) -> str:
    if "error" in row:
        return f"round {row['round']} {row['way']:5s} ERROR {row['error']}"
    extra = f"  operator {row['operator_s']:.1f} s, material {row.get('material_s', 0.0):.1f} s" \
        if row["way"] == "addon" else ""
    return (f"round {row['round']} {row['way']:5s} wall {row['wall_s']:7.1f} s  (fit {row['fit_s']:.1f} s, "
            f"loss {row['loss']:.4f}){extra}")
