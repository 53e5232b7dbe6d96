"""When a fit's progress events arrive: the timelines the whole-fit progress bar is weighted on.

``record`` fits photo pairs with ``python -m backend fit R T --out DIR --json-progress`` (one after
another, each in a fresh folder) and appends, per fit, every progress event (seconds since the
process started, stage, iteration, total, the process's CPU seconds, loss, the optimiser's
since_best and patience: rows recorded before them have none), the wall and CPU time and metrics.json's stage
timings to the results ledger (``devtools/bench/results/fit-timeline.jsonl``, a row per fit).
``replay`` reads those rows back and runs them through the whole-fit progress
(``backend/core/progress.py``): each phase's share of the wall time, and how far the bar's
time-left estimate is from the time that was really left, from 20 % of the bar on (the product's
promise: within 25 %); then the shares and the length of the optimiser's discrete searches to
declare, measured on the fits ``--tune`` names (the others held out: their figures are the honest
ones).

    .venv/bin/python tools/fit_timeline.py record --pairs ../shared/data/real [--names a,b] [--keep DIR]
        [-- fit options]
    .venv/bin/python tools/fit_timeline.py replay [--ledger FILE] [--tune satin1,twill1,...]

The machine may be busy: a share (a phase's seconds over the fit's) is what carries over to another
machine, not the seconds.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.core.pairs import find_pairs  # noqa: E402

BENCH = "fit-timeline"
LEDGER = ROOT / "devtools" / "bench" / "results" / f"{BENCH}.jsonl"


def timeline(reflection: Path, transmission: Path, out: Path, fit_args: list[str]) -> dict:
    """One fit with its progress events timed on arrival (seconds since the process started)."""
    command = [sys.executable, "-m", "backend", "fit", str(reflection), str(transmission), "--out", str(out),
               "--json-progress", *fit_args]
    started = time.monotonic()
    process = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    events = []
    for line in process.stdout:
        event = json.loads(line)
        if event["event"] == "progress":
            events.append([round(time.monotonic() - started, 3), event["stage"], event["iteration"], event["total"],
                           cpu_seconds(process.pid), event.get("loss"), event.get("since_best"),
                           event.get("patience")])
    cpu = cpu_seconds(process.pid)
    code = process.wait()
    wall = time.monotonic() - started
    metrics = json.loads((out / "metrics.json").read_text()) if (out / "metrics.json").is_file() else {}
    return {"name": reflection.stem.rsplit("_", 1)[0], "exit": code, "wall_s": round(wall, 2), "cpu_s": cpu,
            "events": events, "timings": metrics.get("timings"), "fit_args": fit_args}


def cpu_seconds(pid: int) -> float | None:
    """The CPU time (user + system) process ``pid`` has used so far (Linux: /proc): on a machine
    others share, the fit's own clock, which their load does not stretch."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:  # gone already
        return None
    return round((int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK"), 2)


def record(args) -> None:
    from devtools.bench.ledger import Ledger

    pairs, _ = find_pairs(args.pairs)
    names = set(args.names.split(",")) if args.names else None
    ledger = Ledger.open(BENCH, ["tools/fit_timeline.py", *sys.argv[1:]], [args.pairs])
    for pair in pairs:
        if names is not None and pair.name not in names:
            continue
        with tempfile.TemporaryDirectory() as folder:
            out = Path(args.keep) / pair.name if args.keep else Path(folder) / "fit"
            overwrite = ["--overwrite"] if args.keep else []
            row = timeline(pair.reflection, pair.transmission, out, [*args.fit_args, *overwrite])
        ledger.row(row)
        print(f"{row['name']}: {row['wall_s']:.0f} s, exit {row['exit']}, {len(row['events'])} events", flush=True)


def replay(args) -> None:
    """Each recorded fit through the whole-fit progress, on both clocks; then what to declare, measured
    on the fits named by ``--tune`` only (all by default), so that the others are held out: each
    phase's mean share of those fits' CPU time where it ran, scaled to sum to 1, and how many of the
    optimiser's steps one of its discrete searches lasts (progress.SEARCH_COUNTS)."""
    from backend.core import progress

    rows = [json.loads(line)["data"] for line in Path(args.ledger).read_text().splitlines() if line.strip()]
    rows = [row for row in rows if row.get("exit") == 0 and row.get("cpu_s")]
    labels = _labels(rows)
    tune = set(args.tune.split(",")) if args.tune else set(labels)
    unknown = tune - set(labels)
    if unknown:
        raise SystemExit(f"--tune: no recorded fit {', '.join(sorted(unknown))} (recorded: {', '.join(labels)})")
    measured: dict[str, list[float]] = {name: [] for name in progress.NAMES}
    pauses: list[float] = []
    within: dict[bool, list[float]] = {True: [], False: []}
    for label, row in zip(labels, rows):
        tuned = label in tune
        for clock, column, total in (("cpu", 4, row["cpu_s"]), ("wall", 0, row["wall_s"])):
            events = [(event[column], *event[1:4], *(event[5:8] + [None] * 3)[:3]) for event in row["events"]]
            report = progress.replay(events, total)
            shares = ", ".join(f"{name} {share:.3f}" for name, share in report.shares.items())
            if clock == "cpu":
                within[tuned].append(report.within)
                if tuned:
                    for name, share in report.shares.items():
                        if share > 0:
                            measured[name].append(share)
                    pauses += search_counts(events)
            print(f"{label:>10} {'tuned' if tuned else 'held out':>8} {clock:>4} {total:6.0f} s  time left from 20 % "
                  f"of the bar: within {progress.ETA_CHECK:.0%} at {report.within:.0%} of the moments, worst "
                  f"{report.worst_eta_error:+.0%}; bar - time {report.worst_bar_error:+.2f} at worst; shares: {shares}")
    for tuned, values in within.items():
        if values:
            print(f"{'tuned' if tuned else 'held out'} (cpu): within {progress.ETA_CHECK:.0%} at "
                  f"{sum(values) / len(values):.0%} of the moments on average over {len(values)} fits")
    means = {name: sum(values) / len(values) for name, values in measured.items() if values}
    whole = sum(means.values())
    print("shares to declare: " + ", ".join(f"{name} {mean / whole:.4f}" for name, mean in means.items()))
    if pauses:
        print(f"search counts to declare: {sum(pauses) / len(pauses):.1f} (from {len(pauses)} searches)")


def _labels(rows: list[dict]) -> list[str]:
    """A name per recorded fit: the pair's, and for a pair recorded again, its pair's with .2, .3, ..."""
    seen: dict[str, int] = {}
    labels = []
    for row in rows:
        seen[row["name"]] = seen.get(row["name"], 0) + 1
        labels.append(row["name"] + (f".{seen[row['name']]}" if seen[row["name"]] > 1 else ""))
    return labels


def search_counts(events: list) -> list[float]:
    """How many of the optimiser's steps each of its discrete searches lasted: the step before which
    one ran (progress.PHASES' pauses) less the median step, over that median."""
    from backend.core import progress

    [optimiser] = [phase for phase in progress.PHASES if phase.pauses]
    steps = [event for event in events if event[1] == optimiser.stage]
    intervals = {b[2]: b[0] - a[0] for a, b in zip(steps, steps[1:]) if b[2] == a[2] + 1}
    if len(intervals) < 3:
        return []
    median = sorted(intervals.values())[len(intervals) // 2]
    return [(intervals[k] - median) / median for k in optimiser.pauses if k in intervals]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help="fit pairs and record their timelines in the results ledger")
    rec.add_argument("--pairs", required=True, help="folder of <name>_R.* / <name>_T.* photo pairs")
    rec.add_argument("--names", help="only these pairs (comma-separated)")
    rec.add_argument("--keep", help="keep each fit's folder here (<pair>/: params, metrics, report)")
    rec.add_argument("fit_args", nargs="*", help="fit options after --")
    rep = sub.add_parser("replay", help="run the recorded timelines through the whole-fit progress")
    rep.add_argument("--ledger", default=str(LEDGER))
    rep.add_argument("--tune", help="the recorded fits to measure what to declare on (comma-separated, as replay "
                                    "names them: a pair recorded again gets .2, .3, ...); the others are held out")
    args = parser.parse_args(argv)
    record(args) if args.command == "record" else replay(args)


if __name__ == "__main__":
    main()
