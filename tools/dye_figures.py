"""Colour as dye and yarn-dyed patterns on a fit, in Blender's capture rig, against the backend's render.

For a fit (its params.json) this script renders the rig's reflection in each asked-for engine
(``osl``: Cycles with the OSL shader, ``fallback``: Cycles without OSL, ``eevee``) and prints

- the unpainted cloth's mean colour (display values) beside the backend's render of the same fit,
  and the fabric's base colour (core/dye.py) with its colour tag;
- a pure red stripe painted on a Replace colour layer: the stripe's mean colour and hue, the hue of
  the cloth beside it;
- the cloth yarn-dyed with the gingham and the tartan presets (core/sett.py);

and writes ``<out>/figures.json`` and one PNG per engine: backend (top left), then unpainted, red
stripe, gingham, tartan.

Usage::

    .venv/bin/python tools/dye_figures.py FIT/params.json --out DIR [--engines osl,fallback,eevee]
        [--size 256] [--samples 32] [--backend-spp 64] [--threads 0]
"""
from __future__ import annotations

import argparse
import colorsys
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import validate_shader as vs  # noqa: E402  (the rig renders and the backend's, cached)

from backend.core.params import FabricParams  # noqa: E402
from blender_addon.core import asset_catalogs, dye, rig_display, rig_settings, sett  # noqa: E402
from blender_addon.scene import colour_layer, node_group, rig_scene  # noqa: E402

STRIPE_U = (0.3, 0.45)  # the painted stripe's span of U (the rig's camera sees U in [0, 0.8])
PATTERNS = ("GINGHAM", "TARTAN")


def _srgb(linear: float) -> float:
    return linear * 12.92 if linear <= 0.0031308 else 1.055 * linear ** (1 / 2.4) - 0.055


def _hue(rgb) -> float:
    return colorsys.rgb_to_hsv(*(float(c) for c in rgb))[0] * 360.0


def _columns(size: int, span, rig: dict | None) -> slice:
    """The image columns of a span of U (the camera sees U from 0 to view_size / plane_size)."""
    capture = rig_settings.capture_rig(rig)
    view = capture.view_size / capture.plane_size
    return slice(int(span[0] / view * size), int(span[1] / view * size))


def paint_stripe(layer, span, rgb) -> None:
    """Paints ``rgb`` (linear) over U in ``span`` of a Replace layer, opaque; clear elsewhere."""
    w, h = layer.size
    pixels = np.zeros((h, w, 4), np.float32)
    pixels[:, int(span[0] * w):int(span[1] * w)] = (*(_srgb(c) for c in rgb), 1.0)
    layer.pixels.foreach_set(pixels.ravel())


def reflection(blender, engine: str) -> np.ndarray:
    """The rig's displayed reflection of the rig's material as it is now (front light only)."""
    rig_scene.set_engine(blender.scene, engine, blender.samples)
    return rig_display.display(rig_scene.render_linear(blender.scene, "front"), blender.rig)


def engine_figures(blender, layer, engine: str, ref_R: np.ndarray, out: Path) -> dict:
    """The figures and the PNG of one engine (``layer``: a Replace colour layer of the rig's material,
    clear; it is cleared and the setts removed afterwards)."""
    size = ref_R.shape[0]
    stripe = _columns(size, STRIPE_U, blender.rig)
    beside = _columns(size, (STRIPE_U[1] + 0.05, STRIPE_U[1] + 0.2), blender.rig)
    plain = reflection(blender, engine)
    paint_stripe(layer, STRIPE_U, (1.0, 0.0, 0.0))
    red = reflection(blender, engine)
    layer.pixels.foreach_set(np.zeros(len(layer.pixels), np.float32))
    images = [ref_R, plain, red]
    for preset in PATTERNS:
        _, warp, weft = sett.PRESETS[preset]
        colour_layer.apply_sett(blender.material, warp, weft)
        images.append(reflection(blender, engine))
    colour_layer.apply_sett(blender.material, "")
    grid = np.concatenate([np.concatenate(images[:3], 1), np.concatenate([plain, *images[3:]], 1)], 0)
    vs.write_png(out / f"dye_{engine}.png", grid)
    return {"cloth": plain.mean((0, 1)).tolist(), "backend_cloth": ref_R.mean((0, 1)).tolist(),
            "cloth_l1": float(np.abs(plain.mean((0, 1)) - ref_R.mean((0, 1))).mean()),
            "red_stripe": red[:, stripe].mean((0, 1)).tolist(), "red_stripe_hue": _hue(red[:, stripe].mean((0, 1))),
            "beside_hue": _hue(red[:, beside].mean((0, 1))), "beside_change":
            float(np.abs(red[:, beside] - plain[:, beside]).mean())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("params", help="a fit's params.json")
    ap.add_argument("--out", required=True, help="folder for figures.json and the PNGs")
    ap.add_argument("--engines", default="osl,fallback,eevee", help=f"of {', '.join(vs.ENGINES)}")
    ap.add_argument("--size", type=int, default=256, help="image size in pixels (default 256)")
    ap.add_argument("--samples", type=int, default=32, help="Blender samples per pixel (default 32)")
    ap.add_argument("--backend-spp", type=int, default=64, help="backend samples per pixel (default 64)")
    ap.add_argument("--threads", type=int, default=0, help="Blender render threads (0: automatic)")
    args = ap.parse_args(argv)
    try:
        params = json.loads(Path(args.params).read_text())
        fitted = FabricParams.from_dict(params)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SystemExit(f"{args.params}: not a fit's params.json ({exc})") from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rig = params.get("rig")
    ref_R, _ = vs.backend_render(fitted, args.size, args.backend_spp, Path(vs.DEFAULT_CACHE), rig=rig)
    blender = vs.BlenderRig(args.size, args.samples, args.threads, rig)
    node_group.apply_params(blender.material, params)
    layer = colour_layer.add_colour_layer(blender.material, "REPLACE")
    base = dye.base_colour(params)
    figures = {"params": str(args.params), "base_colour": list(base), "tag": asset_catalogs.colour_name(base),
               "engines": {}}
    print(f"base colour (linear) {', '.join(f'{c:.3f}' for c in base)}: {figures['tag']}")
    for engine in vs.parse_engines(args.engines):
        row = engine_figures(blender, layer, engine, ref_R, out)
        figures["engines"][engine] = row
        print(f"{engine:9s} cloth {', '.join(f'{c:.3f}' for c in row['cloth'])} (backend "
              f"{', '.join(f'{c:.3f}' for c in row['backend_cloth'])}, L1 {row['cloth_l1']:.4f}); red stripe hue "
              f"{row['red_stripe_hue']:.1f} deg, beside it {row['beside_hue']:.1f} deg", flush=True)
    (out / "figures.json").write_text(json.dumps(figures, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
