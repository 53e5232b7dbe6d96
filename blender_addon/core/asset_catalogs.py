"""Where fitted fabrics go in the Asset Browser: their catalog, tags and the catalog file (no bpy).

Every fit becomes a material asset in the catalog ``Fabrics/<weave's name>`` (``Fabrics/Twill
(weft-faced)``, the names of core/declarations.pattern_label) with the tags ``fabric``, ``woven``, the
weave and a colour name of its rendered colour (the dye's base colour, core/dye.py; :func:`tags`).

Blender keeps an asset library's catalogs in a text file, :data:`CATALOG_FILE`, in the library's
root folder, which for a .blend outside any library is the folder of the .blend::

    VERSION 1
    <uuid>:<catalog path>:<simple name>

A catalog's UUID is ``uuid5(NAMESPACE, path)`` (:func:`catalog_id`), so every file and library
gives ``Fabrics/Plain`` the same id and merging libraries makes no duplicates; a catalog that
already exists in the file under another UUID (made by hand in Blender) keeps its UUID
(:func:`ensure_catalogs` returns the ids to use). Other lines of the file are kept as they are.
"""
from __future__ import annotations

import colorsys
import uuid
from pathlib import Path

from . import declarations, dye
from .paths import write_whole

CATALOG_FILE = "blender_assets.cats.txt"
ROOT_CATALOG = "Fabrics"
NAMESPACE = uuid.UUID("6f1c2a52-8a0e-4b7e-9a43-5b8f3c1d0e27")  # this add-on's catalogs
_HEADER = ("# This is an Asset Catalog Definition file for Blender.\n"
           "#\n"
           "# Empty lines and lines starting with `#` will be ignored.\n"
           "# The first non-ignored line should be the version indicator.\n"
           "# Other lines are of the format \"UUID:catalog/path/for/assets:simple catalog name\"\n"
           "\n"
           "VERSION 1\n")


def catalog_path(pattern: str) -> str:
    """``Fabrics/<the weave's name>`` (a pattern that is no preset keeps its code)."""
    name = declarations.pattern_label(pattern) if pattern in declarations.preset_names() else pattern
    return f"{ROOT_CATALOG}/{name or 'unknown'}"


def catalog_id(path: str) -> str:
    return str(uuid.uuid5(NAMESPACE, path))


def simple_name(path: str) -> str:
    return path.replace("/", "-")


def parse(text: str) -> dict[str, str]:
    """Catalog path -> UUID of a catalog file's text (comments, VERSION and bad lines skipped)."""
    found = {}
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith("#") or line.startswith("VERSION"):
            continue
        parts = line.split(":", 2)
        if len(parts) >= 2:
            found.setdefault(parts[1], parts[0])
    return found


def merged(text: str, paths) -> tuple[str, dict[str, str]]:
    """``text`` (a catalog file, may be empty) with the missing catalogs of ``paths`` (and their
    parents) appended; and path -> UUID for each of ``paths``."""
    existing = parse(text)
    wanted = []
    for path in paths:
        parts = path.split("/")
        for end in range(1, len(parts) + 1):
            parent = "/".join(parts[:end])
            if parent not in wanted:
                wanted.append(parent)
    lines = [f"{catalog_id(p)}:{p}:{simple_name(p)}" for p in wanted if p not in existing]
    out = text if text.strip() else _HEADER
    if lines:
        out = out + ("" if out.endswith("\n") else "\n") + "\n".join(lines) + "\n"
    ids = {p: existing.get(p, catalog_id(p)) for p in paths}
    return out, ids


def ensure_catalogs(folder: str | Path, paths) -> dict[str, str]:
    """Makes sure the catalog file in ``folder`` lists ``paths``; returns path -> UUID to use.

    Written whole or not at all (:func:`.paths.write_whole`); raises OSError when the folder cannot
    be written.
    """
    target = Path(folder) / CATALOG_FILE
    text = target.read_text(encoding="utf-8") if target.is_file() else ""
    new_text, ids = merged(text, list(paths))
    if new_text != text:
        write_whole(target, new_text)
    return ids


# -- tags -------------------------------------------------------------------------------------------

def colour_name(rgb) -> str:
    """A plain colour word for a linear RGB albedo (judged on its display value, sRGB-like)."""
    r, g, b = (max(0.0, min(1.0, float(c))) ** (1 / 2.2) for c in rgb[:3])
    hue, saturation, value = colorsys.rgb_to_hsv(r, g, b)
    if value < 0.15:
        return "black"
    if saturation < 0.15:
        return "white" if value > 0.85 else "grey"
    degrees = hue * 360.0
    if (degrees < 45 or degrees >= 345) and value < 0.6 and saturation < 0.8:
        return "brown"
    if 20 <= degrees < 65 and saturation < 0.35:
        return "beige"
    for upper, name in ((15, "red"), (45, "orange"), (70, "yellow"), (165, "green"), (200, "cyan"),
                        (255, "blue"), (290, "purple"), (345, "pink"), (360, "red")):
        if degrees < upper:
            return name
    return "red"


def tags(params: dict) -> list[str]:
    """The asset tags of a fit: fabric, woven, the weave, the colour it renders (dye.base_colour)."""
    out = ["fabric", "woven"]
    if params.get("pattern"):
        out.append(str(params["pattern"]))
    try:
        out.append(colour_name(dye.base_colour(params)))
    except (KeyError, TypeError, ValueError, IndexError):  # no albedos to name a colour by
        pass
    return out
