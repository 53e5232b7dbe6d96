"""``python -m devtools evaluate-init``: the initialisation network against the prior
(:mod:`devtools.bench.init_eval`)."""
from __future__ import annotations

import json
from pathlib import Path

import torch

from backend.init import network

from ..bench.init_eval import evaluate_fits, evaluate_golden, evaluate_heldout, print_table
from ..bench.ledger import add_record_option, open_ledger


def run_evaluate(args) -> int:
    torch.set_num_threads(args.threads)
    model = network.InitModel.load(args.weights)
    ledger = open_ledger(args, "evaluate-init", [folder for folder in (args.heldout, args.golden) if folder])
    report: dict = {"weights": str(args.weights), "training": model.info.get("training")}
    if args.heldout:
        report["heldout"] = evaluate_heldout(model, args.heldout)
        print_table(f"held-out synthetic ({report['heldout']['items']} items)", report["heldout"])
    if args.golden:
        report["golden"] = evaluate_golden(model, args.golden, ledger=ledger)
        print_table(f"golden targets ({len(report['golden']['cases'])} cases)", report["golden"])
        if not args.no_fits:
            report["fits"] = evaluate_fits(model, args.golden, args.fit_cases, args.iterations, ledger=ledger)
            print(f"\nfits ({report['fits']['iterations']} iterations), means over cases:")
            for label, values in report["fits"]["summary"].items():
                print(f"  {label:8s} " + ", ".join(f"{k} {v:.4f}" for k, v in values.items() if v is not None))
    ledger.summary({key: _without_cases(value) for key, value in report.items()})
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2) + "\n")
    return 0


def _without_cases(section):
    """A report section without its per-case rows (the ledger has them as rows)."""
    return {k: v for k, v in section.items() if k != "cases"} if isinstance(section, dict) else section


def add_parser(sub) -> None:
    p = sub.add_parser("evaluate-init", help="evaluate the initialisation network (raw predictions and fits)")
    p.add_argument("--weights", default=str(network.DEFAULT_WEIGHTS))
    p.add_argument("--heldout", help="a held-out dataset folder (made with another --seed)")
    p.add_argument("--golden", help="a folder with cases.json and <name>_R/_T.png targets")
    p.add_argument("--fit-cases", nargs="*", help="golden cases to fit both ways (default: all)")
    p.add_argument("--no-fits", action="store_true", help="raw predictions only")
    p.add_argument("--iterations", type=int, help="fit iterations (default: the fit's default)")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--json", help="write every number to this JSON file")
    add_record_option(p)
    p.set_defaults(run=run_evaluate)
