"""Photo-like synthetic pairs with ground truth: ``python -m backend photolike --out DIR --count N``.

Item ``k`` of a set with seed ``s``: the weave preset ``PATTERNS[k mod 5]``, its parameters drawn from
the spec's dataset prior (:func:`backend.core.priors.sample`), the sample turned by U(-5, 5) degrees
in the holder (the rig's ``sample_rotation_deg``), rendered at the rig's film size with 16 samples per
pixel, and passed through a phone (:class:`backend.model.phone.PhoneEffects`: camera blur
0.5-2 px, shot and read noise, exposure and white-balance offsets, low-frequency light falloff,
mild non-uniform yarn spacing, JPEG at the phone's resolution). Everything is drawn from a
generator seeded by (s, k), so a set is the same files whatever else runs.

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
from ..core.rig import DEFAULT_RIG, CaptureRig
from ..image.png import jpeg_at_phone_scale, write_png
from ..model.phone import PhoneEffects
from ..model.render import Renderer

MAX_ROTATION_DEG = 5.0
SPP = 16


def item_rng(seed: int, index: int) -> random.Random:
    return random.Random(zlib.crc32(f"photolike/{seed}/{index}".encode()))


def make_item(out: Path, seed: int, index: int, rig: CaptureRig = DEFAULT_RIG) -> dict:
    """Renders item ``index`` into ``out``; returns its cases.json entry."""
    rng = item_rng(seed, index)
    pattern = priors.PATTERNS[index % len(priors.PATTERNS)]
    params = priors.sample(pattern, rng)
    placed = dataclasses.replace(rig, sample_rotation_deg=rng.uniform(-MAX_ROTATION_DEG, MAX_ROTATION_DEG),
                                 camera_blur_px=0.0)
    phone = PhoneEffects.draw(rng)
    with torch.no_grad():
        pair = Renderer(placed, size=rig.film_size, spp=SPP, seed=rng.randrange(1 << 20)).render(params)
    name = f"{pattern}_{index:03d}"
    for photo, (tag, radiance) in enumerate((("R", pair.reflection_radiance), ("T", pair.transmission_radiance))):
        photo_image = jpeg_at_phone_scale(phone.apply(radiance, photo, placed), phone.jpeg_quality)
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
