"""Validates the Cycles approximation of the woven-fabric BSDF against the backend.

For each golden case (``../shared/data/golden/cases.json`` beside the checkout, parameters parsed with
``FabricParams.from_interchange``; by default the cases of the full model, i.e. without ablation
flags) this script

1. renders the paper's capture rig in Cycles, headless through the ``bpy`` module: the fabric plane
   with the "Woven Fabric" material (OSL shader, or the standard-node fallback with ``--fallback``),
   the pinhole camera and the front / back point light (``blender_addon/scene/rig_scene.py``), and applies
   the rig's output transform (glow where the pixel sees through the gaps, clamp, 1/2.2,
   vignette);
2. renders the same parameters with the backend
   (``python -m backend render PARAMS --out DIR --spp 16 --size N``);
3. reports, for reflection (R) and transmission (T), the colour L1 between 16 x 16 area
   downsamples and the spectrum correlation, with the definitions of
   ``../shared/tools/imagemetrics.py`` (imported from that file), per case and on average.

Targets for the approximation: colour L1 <= 0.03 and spectrum correlation >= 0.5 on average.

Usage::

    .venv/bin/python tools/validate_shader.py [--size 256] [--samples 64] [--cases a,b] [--out DIR]
                                              [--backend-spp 16] [--threads 0] [--fallback] [--json F]
                                              [--floor]

``--floor`` adds the figures of the backend against itself (another jitter seed): the spectrum
correlation of a 16-spp reference is limited by its own sampling noise where yarns are smaller than
a pixel (sharp satin and plain highlights), so read the shader's figures against that floor.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")  # read before cv2 is first imported

import bpy  # noqa: E402  (the bpy module of the venv)
import cv2  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from backend.core.params import FabricParams  # noqa: E402  (torch-free)
from blender_addon.scene import node_group, rig_scene  # noqa: E402

SHARED = ROOT.parent / "shared"  # the shared data beside the checkout (/work/shared)
GOLDEN = SHARED / "data" / "golden" / "cases.json"
METRICS = SHARED / "tools" / "imagemetrics.py"
TARGET_L1, TARGET_CORR = 0.03, 0.5


def load_metrics(path: Path = METRICS):
    spec = importlib.util.spec_from_file_location("imagemetrics", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def select_cases(path: Path, names: str | None) -> list[dict]:
    cases = json.loads(path.read_text())
    if names:
        wanted = [n.strip() for n in names.split(",") if n.strip()]
        known = {c["name"]: c for c in cases}
        missing = [n for n in wanted if n not in known]
        if missing:
            raise SystemExit(f"unknown case(s): {', '.join(missing)}; known: {', '.join(known)}")
        return [known[n] for n in wanted]
    return [c for c in cases if not c.get("flags")]


def backend_render(params: str, out: Path, size: int, spp: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "backend", "render", params, "--out", str(out), "--spp", str(spp),
           "--size", str(size), "--seed", str(seed)]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"backend render failed ({done.returncode}): {done.stderr.strip()}")
    m = load_metrics()
    return m.load_rgb(out / "reflection.png"), m.load_rgb(out / "transmission.png")


def write_png(path: Path, image: np.ndarray) -> None:
    data = np.round(np.clip(image, 0, 1) * 65535).astype(np.uint16)
    cv2.imwrite(str(path), np.ascontiguousarray(data[..., ::-1]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=256, help="image size in pixels (default 256)")
    ap.add_argument("--samples", type=int, default=64, help="Cycles samples per pixel (default 64)")
    ap.add_argument("--backend-spp", type=int, default=16, help="backend samples per pixel (default 16)")
    ap.add_argument("--cases", help="comma-separated case names (default: every case without flags)")
    ap.add_argument("--golden", default=str(GOLDEN), help="cases.json (default: the shared golden set)")
    ap.add_argument("--out", help="folder for the renders and side-by-side images")
    ap.add_argument("--threads", type=int, default=0, help="Cycles threads (0: automatic)")
    ap.add_argument("--fallback", action="store_true", help="render the standard-node fallback (OSL off)")
    ap.add_argument("--json", help="write the figures to this JSON file")
    ap.add_argument("--floor", action="store_true",
                    help="also compare the backend with itself (another jitter seed, same spp): the "
                         "figures the reference's own sampling noise allows")
    args = ap.parse_args(argv)

    metrics = load_metrics()

    cases = select_cases(Path(args.golden), args.cases)
    out_dir = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="validate_shader_"))
    out_dir.mkdir(parents=True, exist_ok=True)
    scene = rig_scene.build_scene(size=args.size, samples=args.samples, osl=not args.fallback,
                                  threads=args.threads, scene=bpy.context.scene)
    fabric = rig_scene.rig_object(scene, "fabric")

    rows = []
    print(f"{'case':28s} {'R L1':>7s} {'R corr':>7s} {'T L1':>7s} {'T corr':>7s} {'cycles s':>9s}"
          + ("   floor (backend vs backend, seed 1): R L1, R corr, T L1, T corr" if args.floor else ""), flush=True)
    for case in cases:
        params = FabricParams.from_interchange(case["params"])
        if case.get("flags"):
            print(f"  note: {case['name']} has flags {case['flags']}: the shader renders the full model")
        material = node_group.create_material(f"validate {case['name']}", params.to_dict())
        fabric.data.materials.clear()
        fabric.data.materials.append(material)
        t0 = time.time()
        R, T = rig_scene.render_pair(scene)  # the spec's rig, as the backend renders
        seconds = time.time() - t0
        bR, bT = backend_render(case["params"], out_dir / "backend" / case["name"], args.size, args.backend_spp)
        row = {"case": case["name"],
               "R_l1": metrics.downsample_l1(R, bR), "R_corr": metrics.spectrum_corr(R, bR),
               "T_l1": metrics.downsample_l1(T, bT), "T_corr": metrics.spectrum_corr(T, bT),
               "cycles_seconds": seconds}
        line = (f"{case['name']:28s} {row['R_l1']:7.4f} {row['R_corr']:7.3f} {row['T_l1']:7.4f} {row['T_corr']:7.3f}"
                f" {seconds:9.1f}")
        if args.floor:
            fR, fT = backend_render(case["params"], out_dir / "backend_seed1" / case["name"], args.size,
                                    args.backend_spp, seed=1)
            row["floor"] = {"R_l1": metrics.downsample_l1(fR, bR), "R_corr": metrics.spectrum_corr(fR, bR),
                            "T_l1": metrics.downsample_l1(fT, bT), "T_corr": metrics.spectrum_corr(fT, bT)}
            f = row["floor"]
            line += f"   floor {f['R_l1']:.4f} {f['R_corr']:.3f} {f['T_l1']:.4f} {f['T_corr']:.3f}"
        rows.append(row)
        print(line, flush=True)
        write_png(out_dir / f"{case['name']}_cycles_R.png", R)
        write_png(out_dir / f"{case['name']}_cycles_T.png", T)
        write_png(out_dir / f"{case['name']}_compare.png",
                  np.concatenate([np.concatenate([bR, R], 1), np.concatenate([bT, T], 1)], 0))
        bpy.data.materials.remove(material)

    mean = {k: float(np.mean([r[k] for r in rows])) for k in ("R_l1", "R_corr", "T_l1", "T_corr")}
    l1 = (mean["R_l1"] + mean["T_l1"]) / 2
    corr = (mean["R_corr"] + mean["T_corr"]) / 2
    line = f"{'mean':28s} {mean['R_l1']:7.4f} {mean['R_corr']:7.3f} {mean['T_l1']:7.4f} {mean['T_corr']:7.3f}"
    if args.floor:
        floor = {k: float(np.mean([r["floor"][k] for r in rows])) for k in ("R_l1", "R_corr", "T_l1", "T_corr")}
        line += (f"           floor {floor['R_l1']:.4f} {floor['R_corr']:.3f} {floor['T_l1']:.4f} "
                 f"{floor['T_corr']:.3f}")
    print(line)
    ok = l1 <= TARGET_L1 and corr >= TARGET_CORR
    print(f"average colour L1 {l1:.4f} (target <= {TARGET_L1}), spectrum correlation {corr:.3f} "
          f"(target >= {TARGET_CORR}): {'met' if ok else 'NOT met'}; size {args.size}, {args.samples} Cycles "
          f"samples, backend {args.backend_spp} spp, {'fallback' if args.fallback else 'OSL'}; images in {out_dir}")
    if args.json:
        Path(args.json).write_text(json.dumps({"cases": rows, "mean": mean, "l1": l1, "corr": corr, "met": ok,
                                               "floor": floor if args.floor else None,
                                               "size": args.size, "samples": args.samples,
                                               "backend_spp": args.backend_spp,
                                               "shader": "fallback" if args.fallback else "osl"}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
