"""Photo-like synthetic pairs with ground truth: ``python -m backend photolike --out DIR --count N``.

Item ``k`` of a set with seed ``s``: the weave preset ``PATTERNS[k mod 5]``, its parameters drawn from
the spec's dataset prior (:func:`backend.core.priors.sample`), framed as a photographer frames a
sample (:func:`framed`: the yarns at U(2, 4) film pixels each on the denser axis, as in the real
photos, where the prior's densities would give most weaves fewer than 2), the sample turned by
U(-5, 5) degrees in the holder (the rig's ``sample_rotation_deg``), rendered at the phone's
resolution (``PHONE_SCALE`` times the film's, one sample per phone pixel: 16 per film pixel), and
passed through a phone (:class:`backend.model.phone.PhoneEffects`: mild non-uniform yarn spacing,
low-frequency light falloff, camera blur 0.5-2 film pixels, exposure and white-balance offsets, shot
and read noise, JPEG at the phone's resolution, then the resize to the film). Everything is drawn
from a generator seeded by (s, k), so a set is the same files whatever else runs.

Files: ``DIR/<name>_R.png``, ``DIR/<name>_T.png`` (8-bit) and ``DIR/cases.json``, a list of
``{"name", "params" (interchange string), "flags": {}, "rig" (with the true rotation and camera
blur), "phone" (every drawn effect)}``: the golden folders' format plus the truth the fit benchmark
needs (:mod:`backend.bench.fit`).
"""
from __future__ import annotations

import dataclasses
import json
import random
import sys
import zlib
from pathlib import Path

import torch

from ..core import priors
from ..core.params import FabricParams
from ..core.rig import DEFAULT_RIG, CaptureRig
from ..image.png import phone_jpeg, write_png
from ..model.phone import PhoneEffects
from ..model.render import Renderer
from ..texture.lattice import yarns_in_view

MAX_ROTATION_DEG = 5.0
PHONE_SCALE = 4                     # phone pixels per film pixel (a 2048-px crop of a 12 MP photo)
PIXELS_PER_YARN = (2.0, 4.0)        # film pixels per yarn on the denser axis, as a photographer frames it


def item_rng(seed: int, index: int) -> random.Random:
    return random.Random(zlib.crc32(f"photolike/{seed}/{index}".encode()))


def framed(params: FabricParams, pixels_per_yarn: float, rig: CaptureRig) -> FabricParams:
    """``params`` with the tiles scaled (both axes alike) so that the denser axis's yarns get
    ``pixels_per_yarn`` film pixels, or as they are where they get more already. The prior's
    densities are the paper's 512-px training renders, which alias most of them (0.7-2.7 px per
    yarn); a photographer frames the sample so the phone resolves its weave, or the photo shows none
    (and the fit refuses it as featureless)."""
    yarns = yarns_in_view(params.pattern, params.tiles, rig)
    shrink = min(1.0, rig.film_size / pixels_per_yarn / yarns)
    return params.replace(tiles=tuple(t * shrink for t in params.tiles))


def make_item(out: Path, seed: int, index: int, rig: CaptureRig = DEFAULT_RIG) -> dict:
    """Renders item ``index`` into ``out``; returns its cases.json entry."""
    rng = item_rng(seed, index)
    pattern = priors.PATTERNS[index % len(priors.PATTERNS)]
    params = framed(priors.sample(pattern, rng), rng.uniform(*PIXELS_PER_YARN), rig)
    placed = dataclasses.replace(rig, sample_rotation_deg=rng.uniform(-MAX_ROTATION_DEG, MAX_ROTATION_DEG),
                                 camera_blur_px=0.0)
    phone = PhoneEffects.draw(rng)
    size = rig.film_size * PHONE_SCALE
    with torch.no_grad():
        pair = Renderer(placed, size=size, spp=1, seed=rng.randrange(1 << 20)).render(params)
    name = f"{pattern}_{index:03d}"
    for photo, (tag, radiance) in enumerate((("R", pair.reflection_radiance), ("T", pair.transmission_radiance))):
        photo_image = phone_jpeg(phone.apply(radiance, photo, placed), phone.jpeg_quality, rig.film_size)
        write_png(out / f"{name}_{tag}.png", photo_image, bits=8)
    truth_rig = dataclasses.replace(placed, camera_blur_px=round(phone.blur_px, 4))
    return {"name": name, "params": params.to_interchange(), "flags": {}, "rig": truth_rig.to_dict(),
            "phone": phone.to_dict()}


def generate(out: str | Path, count: int, seed: int = 0, log=sys.stderr) -> list[dict]:
    """Makes items 0 .. count - 1 into ``out`` (cases.json last, so a finished set is one with it)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cases = []
    for index in range(count):
        cases.append(make_item(out, seed, index))
        print(f"photolike: {index + 1}/{count} {cases[-1]['name']}", file=log, flush=True)
    (out / "cases.json").write_text(json.dumps(cases, indent=1) + "\n")
    return cases
