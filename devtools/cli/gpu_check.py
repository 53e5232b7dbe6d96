"""``python -m devtools gpu-check [--out DIR] [--budget-s S] [--device D] [--quick]``: the GPU tests and
benchmarks in one go (:mod:`devtools.gpu_check`)."""
from __future__ import annotations

from pathlib import Path

from backend.app.cli.common import device as checked_device

from ..bench.ledger import add_record_option
from ..gpu_check import DEFAULT_BUDGET_S, plan, run_check, shared_folder


def run_gpu_check(args) -> int:
    device = str(checked_device(args.device))  # no CUDA here: exit 2, naming --device
    out = Path(args.out)
    golden = Path(args.golden) if args.golden else shared_folder("golden")
    real = Path(args.real) if args.real else shared_folder("real")
    steps = plan(device, args.quick, golden, real, out.resolve(), record=not args.no_record)
    summary = run_check(steps, args.budget_s, out, device)
    return 0 if summary["complete"] else 1


def add_parser(sub) -> None:
    p = sub.add_parser("gpu-check", help="the GPU tests and benchmarks in one go, within a time budget")
    p.add_argument("--out", default="gpu-check", help="folder of the log, summary.json, the tests' report and the "
                                                       "ledger records (default gpu-check/)")
    p.add_argument("--budget-s", type=float, default=DEFAULT_BUDGET_S,
                   help=f"seconds for everything (default {DEFAULT_BUDGET_S:.0f}): what no longer fits is skipped")
    p.add_argument("--device", default="cuda", help="cuda (default), cuda:N, or cpu (a dry run)")
    p.add_argument("--quick", action="store_true", help="small renders, one short fit per set: a dry run")
    p.add_argument("--golden", help="dev goldens (default ../shared/data/golden beside the checkout)")
    p.add_argument("--real", help="real pairs (default ../shared/data/real beside the checkout)")
    add_record_option(p)
    p.set_defaults(run=run_gpu_check)
