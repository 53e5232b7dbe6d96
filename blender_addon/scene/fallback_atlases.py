"""The fallback's float atlases (bpy layer): the weave's lookup tables (core/shader_weave.py) as
packed, non-colour images, and their repair when someone paints over them."""
from __future__ import annotations

import bpy
import numpy as np

from ..core import shader_weave

ATLAS_PREFIX = "Woven Fabric "


def _atlas_pixels() -> dict[str, tuple[int, int, np.ndarray]]:
    """name -> (width, height, RGBA float32 pixels) of the fallback's atlases, as generated."""
    out = {}
    for name, (w, h, px) in shader_weave.fallback_atlases().items():
        rgb = np.asarray(px, dtype=np.float32).reshape(-1, 3)
        out[name] = (w, h, np.concatenate([rgb, np.ones((len(rgb), 1), np.float32)], 1).ravel())
    return out


def _write_atlas(image, pixels: np.ndarray) -> None:
    # Only an image with edited pixels gets packed, so the pixels are written last and packed at
    # once (as OpenEXR, float).
    image.pixels.foreach_set(pixels)
    image.pack()
    if image.packed_file is None:  # pragma: no cover - depends on Blender's packing rules
        raise RuntimeError(f"could not pack the fallback atlas {image.name!r}")


def atlas_images() -> dict:
    """The fallback's float atlases as packed, non-colour images (created afresh each build).

    A generated image is regenerated (its pixels lost) when its colour space changes, so each is
    made non-colour at creation.
    """
    images = {}
    for name, (w, h, pixels) in _atlas_pixels().items():
        full = ATLAS_PREFIX + name
        old = bpy.data.images.get(full)
        if old is not None:
            bpy.data.images.remove(old)
        image = bpy.data.images.new(full, w, h, alpha=False, float_buffer=True, is_data=True)
        image.alpha_mode = "CHANNEL_PACKED"
        image.use_fake_user = True
        _write_atlas(image, pixels)
        images[name] = image
    return images


def repair_atlases() -> list[str]:
    """Restores any fallback atlas whose pixels were changed (painted over, edited by a script);
    returns the names of those it restored.

    The atlases are lookup tables of the weave, not textures (the fallback reads them through
    Environment Texture nodes, so texture painting never offers them as paint slots), yet the Image
    Editor can still paint them or a script change them: they are checked here, whenever a fabric
    material is made or updated, before a file is saved and on a timer while the add-on runs
    (ui/material_operators.py).
    """
    restored = []
    for name, (w, h, pixels) in _atlas_pixels().items():
        image = bpy.data.images.get(ATLAS_PREFIX + name)
        if image is None or tuple(image.size) != (w, h):
            continue  # missing or replaced: ensure_node_group rebuilds the group
        current = np.empty(len(pixels), dtype=np.float32)
        image.pixels.foreach_get(current)
        if not np.array_equal(current, pixels):
            _write_atlas(image, pixels)
            restored.append(image.name)
    return restored


def atlases_present() -> bool:
    return all(tuple(getattr(bpy.data.images.get(ATLAS_PREFIX + name), "size", ())) == (w, h)
               for name, (w, h, _) in _atlas_pixels().items())
