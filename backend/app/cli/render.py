"""``python -m backend render`` and ``render-cases``: parameters in, the rig's photo pair out.

    render PARAMS --out DIR [--spp N] [--size N] [--rig RIG.json] [--flags JSON] [--seed S] [--device D]
    render-cases CASES.json --out DIR [--spp N] [--size N] [--seed S] [--device D]

``render`` writes DIR/reflection.png, DIR/transmission.png (16-bit) and DIR/params.json;
``render-cases`` writes DIR/<name>_R.png and _T.png for every case (name, params, flags) of a
golden ``cases.json``.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from ...core.jsonfile import make_folder, read_json, write_whole
from ...core.options import OptionsError, RenderOptions
from ...core.params import FabricParams, ParamError, load_params
from ...core.rig import DEFAULT_RIG, CaptureRig
from ...core.weave import WeaveError
from ...image.png import write_png
from ...model.render import render_pair
from .common import InputError, device, folder_name, positive_int


def render_and_save(params: FabricParams, out: Path, names: tuple[str, str], rig: CaptureRig,
                    options: RenderOptions, size: int, spp: int, seed: int, dev) -> None:
    """Renders the pair and writes it as 16-bit PNGs ``out/names[0]``, ``out/names[1]``."""
    pair = render_pair(params, rig, size=size, spp=spp, seed=seed, options=options, device=dev)
    write_png(out / names[0], pair.reflection)
    write_png(out / names[1], pair.transmission)


def parse_case(case, index: int, path: Path) -> tuple[str, FabricParams, RenderOptions]:
    """(name, params, options) of entry ``index`` of a cases.json file, or an :class:`InputError` naming it."""
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
    return name, params, options


def run_render(args) -> int:
    params = load_params(args.params)
    rig = CaptureRig.load(args.rig) if args.rig else DEFAULT_RIG
    try:
        flags = json.loads(args.flags) if args.flags else {}
    except json.JSONDecodeError as exc:
        raise InputError(f"--flags: not valid JSON ({exc})") from None
    options = RenderOptions.from_flags(flags)
    dev = device(args.device)
    out = make_folder(Path(args.out), InputError)
    render_and_save(params, out, ("reflection.png", "transmission.png"), rig, options,
                    args.size, args.spp, args.seed, dev)
    write_whole(out / "params.json", params.to_json(interchange=params.to_interchange(), rig=rig.to_dict(),
                                                    flags=flags, spp=args.spp, size=args.size) + "\n")
    print(f"wrote {out / 'reflection.png'}, {out / 'transmission.png'}, {out / 'params.json'}", file=sys.stderr)
    return 0


def run_render_cases(args) -> int:
    path = Path(args.cases)
    cases = read_json(path, InputError)
    if not isinstance(cases, list):
        raise InputError(f"{path}: expected a list of cases (name, params, flags)")
    prepared = [parse_case(case, index, path) for index, case in enumerate(cases)]
    dev = device(args.device)
    out = make_folder(Path(args.out), InputError)
    for index, (name, params, options) in enumerate(prepared, 1):
        render_and_save(params, out, (f"{name}_R.png", f"{name}_T.png"), DEFAULT_RIG, options,
                        args.size, args.spp, args.seed, dev)
        print(f"[{index}/{len(prepared)}] {name}", file=sys.stderr, flush=True)
    return 0


def add_parsers(sub) -> None:
    p = sub.add_parser("render", help="render the reflection/transmission pair of a parameter set")
    p.add_argument("params", help="a params.json file or an interchange string")
    p.add_argument("--out", type=folder_name, required=True, help="output folder")
    p.add_argument("--spp", type=positive_int, default=64, help="samples per pixel (default 64)")
    p.add_argument("--size", type=positive_int, default=512, help="image size in pixels (default 512)")
    p.add_argument("--seed", type=int, default=0, help="jitter seed")
    p.add_argument("--rig", help="capture rig JSON (default: the paper's rig)")
    p.add_argument("--flags", help='model variant as JSON, e.g. \'{"layers": 1}\'')
    p.add_argument("--device", default="cpu")
    p.set_defaults(run=run_render)

    p = sub.add_parser("render-cases", help="render every case of a cases.json file")
    p.add_argument("cases")
    p.add_argument("--out", type=folder_name, required=True)
    p.add_argument("--spp", type=positive_int, default=64)
    p.add_argument("--size", type=positive_int, default=512)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu")
    p.set_defaults(run=run_render_cases)
