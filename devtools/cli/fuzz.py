"""``python -m devtools fuzz [--photos N] [--options N] [--params N] [--rigs N] [--seed S]``: the fuzz
harness's full run (:mod:`devtools.fuzz`); prints the cases per kind and their outcomes (fitted,
refused with one line, anything else), then each case that broke the contract. Exit code 1 when any did."""
from __future__ import annotations

import sys
import time

from backend.app.cli.common import positive_int

from ..fuzz import cases
from ..fuzz.runner import CASE_TIMEOUT_S, FITTED, REFUSED, counts, run_cases


def _progress(done: int, total: int, outcome) -> None:
    if done % 100 == 0 or done == total or not outcome.ok:
        mark = "" if outcome.ok else f"  <- {outcome.result}: {outcome.kind} {outcome.label}"
        print(f"{done}/{total}{mark}", file=sys.stderr, flush=True)


def _table(outcomes) -> list[str]:
    table = counts(outcomes)
    lines = [f"{'kind':<8} {'cases':>6} {FITTED:>7} {REFUSED:>8} {'other':>6}"]
    for kind, results in table.items():
        total = sum(results.values())
        other = total - results[FITTED] - results[REFUSED]
        lines.append(f"{kind:<8} {total:>6} {results[FITTED]:>7} {results[REFUSED]:>8} {other:>6}")
    return lines


def run_fuzz(args) -> int:
    wanted = {"photo": args.photos, "options": args.options, "params": args.params, "rig": args.rigs}
    started = time.perf_counter()
    outcomes = run_cases(cases({k: n for k, n in wanted.items() if n}, args.seed), args.timeout, _progress)
    print(f"seed {args.seed}, {len(outcomes)} cases in {time.perf_counter() - started:.0f} s")
    print("\n".join(_table(outcomes)))
    broken = [o for o in outcomes if not o.ok]
    for outcome in broken:
        print(f"{outcome.result}: {outcome.kind} {outcome.label}: {outcome.detail}")
    return 1 if broken else 0


def add_parser(sub) -> None:
    p = sub.add_parser("fuzz", help="feed generated bad input to the photo loader and the fit command; print the "
                                    "outcomes per kind")
    p.add_argument("--photos", type=int, default=2000, help="mutated photo pairs (default 2000)")
    p.add_argument("--options", type=int, default=500, help="fit option sets (default 500)")
    p.add_argument("--params", type=int, default=250, help="mutated params.json files (default 250)")
    p.add_argument("--rigs", type=int, default=250, help="mutated rig files (default 250)")
    p.add_argument("--seed", type=int, default=0, help="seed of the cases (another seed: other cases)")
    p.add_argument("--timeout", type=positive_int, default=int(CASE_TIMEOUT_S),
                   help=f"seconds one case may take before it counts as a hang (default {CASE_TIMEOUT_S:g})")
    p.set_defaults(run=run_fuzz)
