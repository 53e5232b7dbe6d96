"""A paintable colour layer on a Woven Fabric material: its size and how it is wired (no bpy).

Add Colour Layer (scene/colour_layer.py) makes a new image that starts neutral and plugs it into
the group's ``colour map`` (through the material's UV map). The map dyes the yarns (core/dye.py):
every albedo, diffuse and specular, by the ratio of the target colour T to the fabric's base
colour C0, so the cloth renders the painted colour with its sheen and weave. Two modes:

- ``MULTIPLY``: the image is white and opaque; painted colour multiplies the fabric's colour,
  ``T = C0 * paint`` (stains, overdyes, prints that darken): pure red paints red cloth;
- ``REPLACE``: the image is white and transparent, its alpha linked to ``colour map replace``;
  where paint covers it (alpha 1) the yarns are dyed to the painted colour, ``T = paint`` (so
  painting C0 itself changes nothing); elsewhere the fit is untouched.

Size: at least one texel per weave repeat across the UV square (``tiles * uv scale`` repeats), so a
stripe one repeat wide can be painted, as a power of two between :data:`MIN_SIZE` and
:data:`MAX_SIZE`.
"""
from __future__ import annotations

import math

MODES = ("MULTIPLY", "REPLACE")
MIN_SIZE, MAX_SIZE = 512, 4096
IMAGE_PREFIX = "Fabric Colour"
KEY = "woven_fabric_colour_layer"  # on the image: the mode it was made for


def layer_size(tiles, uv_scale: float = 1.0) -> int:
    """Side in pixels of a new layer for a material with these tiles (warp, weft) and uv scale."""
    repeats = max(float(t) for t in tiles) * max(float(uv_scale), 1e-6)
    size = 2 ** math.ceil(math.log2(max(repeats, 1.0)))
    return int(min(max(size, MIN_SIZE), MAX_SIZE))


def initial_pixel(mode: str) -> tuple[float, float, float, float]:
    """The neutral RGBA of a new layer: white, opaque to multiply, transparent to replace."""
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {', '.join(MODES)}, got {mode!r}")
    return (1.0, 1.0, 1.0, 1.0 if mode == "MULTIPLY" else 0.0)
