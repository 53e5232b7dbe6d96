"""Command line: ``python -m backend <command> ...`` (a stable contract other tools call).

    render PARAMS --out DIR [--spp N] [--size N] [--rig RIG.json] [--flags JSON] [--seed S] [--device D]
    render-cases CASES.json --out DIR [--spp N] [--size N] [--device D]
    fit REFLECTION TRANSMISSION --out DIR [...]  (see backend/cli/fit.py)
    dataset --out DIR --per-pattern N [--workers K]  (see backend/init/dataset.py)
    train DATASET --out CHECKPOINT [...]  (see backend/init/train.py)
    evaluate-init [--heldout DIR] [--golden DIR] [...]  (see backend/bench/init_eval.py)
    bench render [--json] [--size N] [--spp N] [--runs N]
    bench fit --golden DIR --real DIR [--cases ...] [--iterations N] [--json]

Bad input (unreadable files, malformed or out-of-range parameters) ends with exit code 2 and a
one-line message naming the file and the problem, never a traceback.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..core.jsonfile import read_json
from ..core.options import OptionsError, RenderOptions
from ..core.params import FabricParams, ParamError, load_params
from ..core.protocol import EXIT_INPUT
from ..core.rig import DEFAULT_RIG, CaptureRig, RigError
from ..core.weave import WeaveError

INPUT_ERRORS = (ParamError, RigError, OptionsError, WeaveError, FileNotFoundError)


class InputError(ValueError):
    """Bad user input detected by the command line layer."""


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _device(name: str):
    import torch

    if name.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(f"--device {name}: CUDA is not available in this PyTorch build or on this machine")
    return torch.device(name)


def _render_and_save(params: FabricParams, out: Path, names: tuple[str, str], rig: CaptureRig,
                     options: RenderOptions, size: int, spp: int, seed: int, device) -> None:
    from ..image.png import write_png
    from ..model.render import render_pair

    pair = render_pair(params, rig, size=size, spp=spp, seed=seed, options=options, device=device)
    write_png(out / names[0], pair.reflection)
    write_png(out / names[1], pair.transmission)


def cmd_render(args) -> int:
    params = load_params(args.params)
    rig = CaptureRig.load(args.rig) if args.rig else DEFAULT_RIG
    try:
        flags = json.loads(args.flags) if args.flags else {}
    except json.JSONDecodeError as exc:
        raise InputError(f"--flags: not valid JSON ({exc})") from None
    options = RenderOptions.from_flags(flags)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    _render_and_save(params, out, ("reflection.png", "transmission.png"), rig, options,
                     args.size, args.spp, args.seed, _device(args.device))
    (out / "params.json").write_text(params.to_json(interchange=params.to_interchange(), rig=rig.to_dict(),
                                                    flags=flags, spp=args.spp, size=args.size) + "\n")
    print(f"wrote {out / 'reflection.png'}, {out / 'transmission.png'}, {out / 'params.json'}", file=sys.stderr)
    return 0


def cmd_render_cases(args) -> int:
    path = Path(args.cases)
    cases = read_json(path, InputError)
    if not isinstance(cases, list):
        raise InputError(f"{path}: expected a list of cases (name, params, flags)")
    prepared = []
    for index, case in enumerate(cases):
        if not isinstance(case, dict) or "name" not in case or "params" not in case:
            raise InputError(f"{path}: case {index} needs 'name' and 'params'")
        name = str(case["name"])
        if not name or any(c in name for c in "/\\") or name.startswith("."):
            raise InputError(f"{path}: case {index}: {name!r} is not a usable file name")
        try:
            params = FabricParams.from_interchange(case["params"]) if isinstance(case["params"], str) \
                else FabricParams.from_dict(case["params"])
            options = RenderOptions.from_flags(case.get("flags"))
        except (ParamError, OptionsError, WeaveError) as exc:
            raise InputError(f"{path}: case {name!r}: {exc}") from None
        prepared.append((name, params, options))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    device = _device(args.device)
    for index, (name, params, options) in enumerate(prepared, 1):
        _render_and_save(params, out, (f"{name}_R.png", f"{name}_T.png"), DEFAULT_RIG, options,
                         args.size, args.spp, args.seed, device)
        print(f"[{index}/{len(prepared)}] {name}", file=sys.stderr, flush=True)
    return 0


def cmd_bench(args) -> int:
    if args.what == "fit":
        from ..bench.fit import bench_fit

        if not args.golden and not args.real:
            raise InputError("bench fit: give --golden DIR and/or --real DIR")
        extra = ["--iterations", str(args.iterations)] if args.iterations else []
        return bench_fit(args.golden, args.real, args.cases, extra, args.json)
    from ..bench.render import bench_render

    return bench_render(size=args.size, spp=args.spp, runs=args.runs, as_json=args.json, device=_device(args.device))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m backend", description="Woven fabric capture backend")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("render", help="render the reflection/transmission pair of a parameter set")
    p.add_argument("params", help="a params.json file or an interchange string")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--spp", type=_positive_int, default=64, help="samples per pixel (default 64)")
    p.add_argument("--size", type=_positive_int, default=512, help="image size in pixels (default 512)")
    p.add_argument("--seed", type=int, default=0, help="jitter seed")
    p.add_argument("--rig", help="capture rig JSON (default: the paper's rig)")
    p.add_argument("--flags", help='model variant as JSON, e.g. \'{"layers": 1}\'')
    p.add_argument("--device", default="cpu")
    p.set_defaults(run=cmd_render)

    p = sub.add_parser("render-cases", help="render every case of a cases.json file")
    p.add_argument("cases")
    p.add_argument("--out", required=True)
    p.add_argument("--spp", type=_positive_int, default=64)
    p.add_argument("--size", type=_positive_int, default=512)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu")
    p.set_defaults(run=cmd_render_cases)

    from .fit import add_parser as add_fit_parser

    add_fit_parser(sub)

    from ..init.dataset import add_parser as add_dataset_parser
    from ..bench.init_eval import add_parser as add_evaluate_init_parser
    from ..init.train import add_parser as add_train_parser

    add_dataset_parser(sub)
    add_train_parser(sub)
    add_evaluate_init_parser(sub)

    p = sub.add_parser("bench", help="print performance figures")
    p.add_argument("what", choices=["render", "fit"])
    p.add_argument("--json", action="store_true", help="JSON lines")
    p.add_argument("--golden", help="fit: a folder with cases.json and <name>_R/_T.png synthetic targets")
    p.add_argument("--real", help="fit: a folder of <name>_R.* / <name>_T.* photo pairs")
    p.add_argument("--cases", nargs="*", help="fit: only these names")
    p.add_argument("--iterations", type=int, help="fit: iterations per pair (default: the fit's default)")
    p.add_argument("--size", type=_positive_int, default=512)
    p.add_argument("--spp", type=_positive_int, default=4)
    p.add_argument("--runs", type=_positive_int, default=5)
    p.add_argument("--device", default="cpu")
    p.set_defaults(run=cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.run(args)
    except (InputError, *INPUT_ERRORS) as exc:
        message = str(exc) if not isinstance(exc, FileNotFoundError) else f"{exc.filename}: file not found"
        print(f"error: {message}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("cancelled", file=sys.stderr)
        return 130
