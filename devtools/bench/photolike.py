"""Photo-like synthetic pairs with ground truth: ``python -m devtools photolike --out DIR --count N``.

Item ``k`` of a set with seed ``s``: the weave preset ``PATTERNS[k mod 5]``, mirrored left-right
(``twill0m``, ... :data:`backend.core.weave.MIRRORED_OF`) in every other run of five (k // 5 odd;
a plain weave has no mirror image), drawn, framed, turned in the holder and photographed by a phone
at :data:`devtools.photo_like.PHONE_SCALE` times the film's resolution
(:func:`devtools.photo_like.photograph`), from a generator seeded by (s, k), so a set is the
same files whatever else runs. A mirrored item draws what its unmirrored twin would: only the
diagonal of its weave differs. Real fabrics come in both handednesses (a twill seen from its back,
a left-hand twill), and a fit that knew only the paper's five would put the other one's weave where
no photo shows it.

With ``moved``, the phone also moves between the shots of every item (:class:`devtools.photo_like.PhoneMove`,
drawn from a generator seeded by (s, k) of its own): the reflection photo shows the lattice 1-1.1
times as dense and turned by up to 2 degrees, the transmission photo and every other draw stay the
unmoved set's, and the truth stays the transmission's framing.

With ``varied``, every item's yarns vary (:func:`devtools.photo_like.photograph`'s
``variation_rng``, seeded by (s, k) of its own): the other draws stay the regular set's. With
``forward``, every item's yarns scatter forward (``forward_rng``, the same way).

With ``without`` (names of :data:`devtools.phone.EFFECTS`), the phone lacks those effects
(:meth:`devtools.phone.PhoneEffects.without`): every draw, the render and the other effects
stay the full set's, so a fit benchmark of the two sets tells what those effects cost.

Files: ``DIR/<name>_R.png``, ``DIR/<name>_T.png`` (8-bit) and ``DIR/cases.json``, a list of
``{"name", "params" (interchange string), "flags": {}, "rig" (with the true rotation and camera
blur), "phone" (every drawn effect, as the photos have them), "move" (a moved set's reflection move,
else absent), "without" (the effects taken away, else absent), "variation" (a varied set's yarn
variation, ``{name: [warp, weft]}``; the interchange string does not carry it), "forward_scattering"
(a forward set's, ``[warp, weft]``)}``: the
golden folders' format plus the truth the fit benchmark needs (:mod:`devtools.bench.fit`).
"""
from __future__ import annotations

import json
import random
import sys
import zlib
from pathlib import Path

from backend.core import priors
from backend.core.rig import DEFAULT_RIG, CaptureRig
from backend.core.variation import PARAMETER_NAMES
from backend.core.weave import MIRROR_OF
from backend.image.png import write_png

from ..photo_like import photograph


def item_rng(seed: int, index: int, what: str = "photolike") -> random.Random:
    return random.Random(zlib.crc32(f"{what}/{seed}/{index}".encode()))


def item_pattern(index: int) -> str:
    """The weave preset of item ``index`` (the module docstring)."""
    pattern = priors.PATTERNS[index % len(priors.PATTERNS)]
    return MIRROR_OF.get(pattern, pattern) if (index // len(priors.PATTERNS)) % 2 else pattern


def make_item(out: Path, seed: int, index: int, rig: CaptureRig = DEFAULT_RIG, pattern: str | None = None,
              moved: bool = False, without: tuple[str, ...] = (), varied: bool = False,
              forward: bool = False) -> dict:
    """Renders item ``index`` into ``out``; returns its cases.json entry. ``pattern`` replaces the
    item's preset (:func:`item_pattern`) with the same draws: a mirrored item's unmirrored twin."""
    pattern = pattern or item_pattern(index)
    shot = photograph(pattern, item_rng(seed, index), rig, move_rng=item_rng(seed, index, "move") if moved else None,
                      without=tuple(without), variation_rng=item_rng(seed, index, "variation") if varied else None,
                      forward_rng=item_rng(seed, index, "forward") if forward else None)
    name = f"{pattern}_{index:03d}"
    write_png(out / f"{name}_R.png", shot.reflection, bits=8)
    write_png(out / f"{name}_T.png", shot.transmission, bits=8)
    case = {"name": name, "params": shot.params.to_interchange(), "flags": {}, "rig": shot.rig.to_dict(),
            "phone": shot.phone.to_dict()}
    if shot.move is not None:
        case["move"] = shot.move.to_dict()
    if without:
        case["without"] = list(without)
    if varied:
        case["variation"] = {name: list(getattr(shot.params, name)) for name in PARAMETER_NAMES}
    if forward:
        case["forward_scattering"] = list(shot.params.forward_scattering)
    return case


def generate(out: str | Path, count: int, seed: int = 0, log=sys.stderr, moved: bool = False,
             without: tuple[str, ...] = (), varied: bool = False, forward: bool = False) -> list[dict]:
    """Makes items 0 .. count - 1 into ``out`` (cases.json last, so a finished set is one with it)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cases = []
    for index in range(count):
        cases.append(make_item(out, seed, index, moved=moved, without=without, varied=varied, forward=forward))
        print(f"photolike: {index + 1}/{count} {cases[-1]['name']}", file=log, flush=True)
    (out / "cases.json").write_text(json.dumps(cases, indent=1) + "\n")
    return cases
