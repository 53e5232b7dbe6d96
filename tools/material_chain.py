"""The whole chain, photo to Blender: fit a photo pair, render the fitted material in Blender's
capture rig, compare with the photos and with the backend's re-render.

For each photo pair this script

1. fits it with the real backend (``python -m backend fit R T --out DIR``; the product's defaults
   unless ``--iterations`` / ``--fit-size`` say otherwise);
2. re-renders the fitted parameters with the backend at the comparison size
   (``python -m backend render``, the fit's rig, including its estimated camera blur);
3. renders the rig in Blender with the fitted material (``blender_addon/scene/rig_scene.py``, the
   same rig) in each engine: ``osl`` (Cycles CPU with OSL: the fitted shader), ``eevee`` (EEVEE: the
   standard-node fallback), ``fallback`` (Cycles without OSL, as on a GPU);
4. prints the colour L1 (16 x 16 area downsamples) and spectrum correlation (the team's
   ``../shared/tools/imagemetrics.py``) of reflection and transmission:

   - Blender vs the backend's re-render, per engine: how faithful the material is to the fitted
     model (the figures of issue 13 item 2, with their targets);
   - Blender vs the photos, per engine, and the backend's re-render vs the photos: the whole chain.

Photo pairs: real ones (``R T`` arguments, or ``--pairs DIR`` for every ``<name>_R.* / <name>_T.*``)
or synthetic ones, ``--draws N --seed S``: N fresh draws per weave from the spec's dataset priors
(``backend/core/priors.py::sample``, as tools/validate_shader.py), rendered by the backend as 8-bit
"photos" at the rig's film size and then fitted like real photos. Figures on draws with a seed in
``validate_shader.TUNING_SEEDS`` are in-sample for the shader's tuned constants; other seeds and real
photos are out-of-sample.

Usage::

    .venv/bin/python tools/material_chain.py R.png T.png [--out DIR] [options]
    .venv/bin/python tools/material_chain.py --pairs ../shared/data/real [options]
    .venv/bin/python tools/material_chain.py --draws 1 --seed 11 [--patterns twill1,satin0] [options]

    options: [--engines osl,eevee] [--size 256] [--samples 64] [--backend-spp 64] [--iterations N]
             [--fit-size N] [--pattern P] [--threads 0] [--json F]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import validate_shader as vs  # noqa: E402  (the rig renders, prior draws and figures)

from backend.core.pairs import find_pairs  # noqa: E402  (torch-free)
from backend.core.params import FabricParams  # noqa: E402
from backend.core.priors import PATTERNS  # noqa: E402

ROOT = vs.ROOT
DEFAULT_ENGINES = "osl,eevee"


def run(cmd: list[str], what: str) -> None:
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise SystemExit(f"{what} failed (exit {done.returncode}): {last}")


def synthetic_pair(name: str, params: FabricParams, folder: Path, photo_spp: int = 16) -> tuple[Path, Path]:
    """The backend's render of ``params`` as an 8-bit photo pair (512 px, like the real photos)."""
    out = folder / "render"
    run([sys.executable, "-m", "backend", "render", params.to_interchange(), "--out", str(out), "--spp",
         str(photo_spp), "--seed", "12345"], f"rendering the photos of {name}")
    pair = []
    for which, suffix in (("reflection", "R"), ("transmission", "T")):
        image = cv2.imread(str(out / f"{which}.png"), cv2.IMREAD_UNCHANGED)
        path = folder / f"{name}_{suffix}.png"
        cv2.imwrite(str(path), np.round(image.astype(np.float64) / 257.0).astype(np.uint8))
        pair.append(path)
    return pair[0], pair[1]


def fit_pair(reflection: Path, transmission: Path, out: Path, args) -> dict:
    """Fits the pair with the backend; returns its params.json (with the fit's rig)."""
    cmd = [sys.executable, "-m", "backend", "fit", str(reflection), str(transmission), "--out", str(out),
           "--overwrite"]
    for flag, value in (("--iterations", args.iterations), ("--size", args.fit_size), ("--pattern", args.pattern),
                        ("--output-spp", args.fit_output_spp)):
        if value:
            cmd += [flag, str(value)]
    run(cmd, f"fitting {reflection.name}")
    return json.loads((out / "params.json").read_text())


def photo_at(path: Path, size: int, metrics) -> np.ndarray:
    image = metrics.load_rgb(path)
    return image if image.shape[0] == size else cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA)


def collect_pairs(args, work: Path) -> list[tuple[str, Path, Path, str]]:
    """(name, reflection, transmission, sample kind) of every pair to run."""
    if args.draws:
        patterns = [p.strip() for p in args.patterns.split(",")] if args.patterns else list(PATTERNS)
        kind = "in-sample" if args.seed in vs.TUNING_SEEDS else "out-of-sample"
        out = []
        for name, params in vs.prior_draws(args.seed, args.draws, patterns):
            folder = work / name
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "truth.json").write_text(params.to_json())
            out.append((name, *synthetic_pair(name, params, folder), kind))
        return out
    if args.pairs:
        pairs, problems = find_pairs(Path(args.pairs))
        for problem in problems:
            print(f"skip {problem.name}: {problem.message}")
        return [(p.name, p.reflection, p.transmission, "out-of-sample") for p in pairs]
    if not args.photos or len(args.photos) != 2:
        raise SystemExit("give a photo pair (R T), --pairs DIR or --draws N")
    reflection, transmission = (Path(p) for p in args.photos)
    return [(reflection.stem.removesuffix("_R"), reflection, transmission, "out-of-sample")]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("photos", nargs="*", help="a reflection and a transmission photo")
    ap.add_argument("--pairs", help="a folder of <name>_R.* / <name>_T.* photo pairs")
    ap.add_argument("--draws", type=int, default=0, help="synthetic pairs: prior draws per weave")
    ap.add_argument("--seed", type=int, default=11, help="seed of the draws (default 11)")
    ap.add_argument("--patterns", help="weaves of the draws, comma-separated (default: all five)")
    ap.add_argument("--engines", default=DEFAULT_ENGINES,
                    help=f"of {', '.join(vs.ENGINES)} (default {DEFAULT_ENGINES})")
    ap.add_argument("--size", type=int, default=256, help="comparison size in pixels (default 256)")
    ap.add_argument("--samples", type=int, default=64, help="Blender samples per pixel (default 64)")
    ap.add_argument("--backend-spp", type=int, default=64, help="samples of the backend's re-render (default 64)")
    ap.add_argument("--iterations", type=int, help="fit iterations (default: the product's)")
    ap.add_argument("--fit-size", type=int, help="fit working size (default: the product's)")
    ap.add_argument("--fit-output-spp", type=int, help="samples of the fit's own re-renders (default: the product's)")
    ap.add_argument("--pattern", help="weave for the fit (default: the fit chooses)")
    ap.add_argument("--out", help="working folder (fits, renders, images)")
    ap.add_argument("--cache", default=str(vs.DEFAULT_CACHE), help="folder caching the backend's renders")
    ap.add_argument("--threads", type=int, default=0, help="Blender render threads (0: automatic)")
    ap.add_argument("--json", help="write the figures to this JSON file")
    args = ap.parse_args(argv)

    metrics = vs.load_metrics()
    engines = vs.parse_engines(args.engines)
    work = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="material_chain_"))
    work.mkdir(parents=True, exist_ok=True)
    pairs = collect_pairs(args, work)
    blender = None
    rows = {"shader": {e: [] for e in engines}, "photo": {e: [] for e in engines}, "backend_photo": []}
    for name, reflection, transmission, kind in pairs:
        t0 = time.time()
        params = fit_pair(reflection, transmission, work / name / "fit", args)
        fit_s = time.time() - t0
        rig = params.get("rig")
        fitted = FabricParams.from_dict(params)
        ref_R, ref_T = vs.backend_render(fitted, args.size, args.backend_spp, Path(args.cache), rig=rig)
        photo_R, photo_T = photo_at(reflection, args.size, metrics), photo_at(transmission, args.size, metrics)
        if blender is None or blender.rig != rig:
            blender = vs.BlenderRig(args.size, args.samples, args.threads, rig)
        print(f"{name} ({kind}; fitted {fitted.pattern} in {fit_s:.0f} s)", flush=True)
        row = {"case": name, "sample": kind, **vs.compare(metrics, ref_R, ref_T, photo_R, photo_T)}
        rows["backend_photo"].append(row)
        print(vs.row_text("  backend vs photo", row), flush=True)
        images = [np.concatenate([photo_R, photo_T], 1), np.concatenate([ref_R, ref_T], 1)]
        for engine in engines:
            R, T = blender.render(params, engine)
            shader = {"case": name, "sample": kind, **vs.compare(metrics, R, T, ref_R, ref_T)}
            photo = {"case": name, "sample": kind, **vs.compare(metrics, R, T, photo_R, photo_T)}
            rows["shader"][engine].append(shader)
            rows["photo"][engine].append(photo)
            print(vs.row_text(f"  {engine} vs backend", shader), flush=True)
            print(vs.row_text(f"  {engine} vs photo", photo), flush=True)
            images.append(np.concatenate([R, T], 1))
        vs.write_png(work / f"{name}_compare.png", np.concatenate(images, 0))  # photo, backend, engines

    kinds = sorted({kind for *_, kind in pairs})
    print(f"\n{vs.HEADER}")
    report = {"size": args.size, "samples": args.samples, "backend_spp": args.backend_spp, "sample": kinds,
              "cases": [p[0] for p in pairs], "shader": {}, "photo": {}}
    report["backend_photo"] = vs.summary(rows["backend_photo"])
    print(vs.row_text("mean backend vs photo", report["backend_photo"]))
    for engine in engines:
        shader, photo = vs.summary(rows["shader"][engine]), vs.summary(rows["photo"][engine])
        report["shader"][engine], report["photo"][engine] = shader, photo
        print(vs.row_text(f"mean {engine} vs photo", photo))
        print(vs.row_text(f"mean {engine} vs backend", shader))
        print(f"  {engine} vs backend ({'/'.join(kinds)}): {vs.verdict(engine, shader)}")
    report["rows"] = rows
    print(f"size {args.size}, {args.samples} Blender samples, backend {args.backend_spp} spp; work in {work}")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
