"""Files around a fit (no bpy): photo pairs in a folder, fresh result folders, the rig's settings.

Photo pairs: ``<name>_R.<ext>`` (reflection, lit from the front) and ``<name>_T.<ext>``
(transmission, lit from behind) in one folder; the suffix letter may be lower case. A name with a
missing partner, or with two candidate files for one side, is a problem that names the files.

Result folders are never reused: :func:`new_run_folder` creates ``<parent>/<name>_001``,
``_002``, ... atomically (``mkdir`` without ``exist_ok``), so an earlier fit is never overwritten.

The rig's settings come from ``backend/core/rig.py`` (the spec's defaults), loaded without torch: the
panel shows every field of ``CaptureRig`` and a new field appears without touching the add-on.
"""
from __future__ import annotations

import dataclasses
import json
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

from . import paths

PHOTO_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr",
                    ".dng", ".cr2", ".cr3", ".nef", ".arw", ".orf", ".rw2", ".raf", ".raw")
RAW_EXTENSIONS = PHOTO_EXTENSIONS[6:]
_PAIR_NAME = re.compile(r"^(?P<name>.+)_(?P<side>[RrTt])$")


@dataclass(frozen=True)
class PhotoPair:
    name: str
    reflection: Path
    transmission: Path


@dataclass(frozen=True)
class PairProblem:
    name: str
    message: str


def find_pairs(folder: str | Path) -> tuple[list[PhotoPair], list[PairProblem]]:
    """Every ``<name>_R.* / <name>_T.*`` pair of a folder (not recursive), sorted by name."""
    folder = Path(folder)
    sides: dict[str, dict[str, list[Path]]] = {}
    for path in sorted(folder.iterdir()):
        if not path.is_file() or path.suffix.lower() not in PHOTO_EXTENSIONS:
            continue
        match = _PAIR_NAME.match(path.stem)
        if match:
            side = match["side"].upper()
            sides.setdefault(match["name"], {"R": [], "T": []})[side].append(path)
    pairs, problems = [], []
    for name in sorted(sides):
        found = sides[name]
        if len(found["R"]) == 1 and len(found["T"]) == 1:
            pairs.append(PhotoPair(name, found["R"][0], found["T"][0]))
            continue
        for side, label, partner in (("R", "reflection", "T"), ("T", "transmission", "R")):
            if not found[side]:
                problems.append(PairProblem(name, f"no {label} photo ({name}_{side}.*) beside "
                                                  f"{', '.join(p.name for p in found[partner])}"))
            elif len(found[side]) > 1:
                problems.append(PairProblem(name, f"more than one {label} photo "
                                                  f"({', '.join(p.name for p in found[side])}); keep one"))
    return pairs, problems


def safe_name(name: str) -> str:
    """A folder-safe version of a material or photo name."""
    cleaned = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._")
    return cleaned or "fabric"


def new_run_folder(parent: str | Path, name: str) -> Path:
    """Creates and returns a folder no earlier fit used: ``<parent>/<name>_NNN``."""
    parent = Path(parent)
    parent.mkdir(parents=True, exist_ok=True)
    base = safe_name(name)
    for number in range(1, 100000):
        folder = parent / f"{base}_{number:03d}"
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return folder
    raise OSError(f"{parent}: no free result folder name for {base}")


def default_results_parent(blend_path: str = "") -> Path:
    """Beside the saved .blend (``fabric_fits``), else in the temporary folder."""
    if blend_path:
        return Path(blend_path).resolve().parent / "fabric_fits"
    return Path(tempfile.gettempdir()) / "woven_fabric_fits"


def unused_path(path: str | Path) -> Path:
    """``path`` if it does not exist, else ``<stem>-2<suffix>``, ``-3``, ...: never overwrite."""
    path = Path(path)
    number = 2
    candidate = path
    while candidate.exists():
        candidate = path.with_name(f"{path.stem}-{number}{path.suffix}")
        number += 1
    return candidate


# -- the rig ------------------------------------------------------------------------------------

# Labels and tooltips of the rig's fields; a field missing here still gets a readable label.
_RIG_TEXT = {
    "film_size": ("Film size", "Width and height in pixels of the working images"),
    "plane_size": ("Plane size", "Side of the fabric plane in scene units (tiles repeat across it)"),
    "camera_height": ("Camera height", "Height of the camera above the fabric, in plane units"),
    "fov_deg": ("Field of view", "Full field of view of the camera in degrees"),
    "front_light": ("Front light", "Reflection light offset from the centre of the view (x, y, z > 0)"),
    "back_light": ("Back light", "Transmission light offset from the centre of the view (x, y, z < 0)"),
    "front_intensity": ("Front intensity", "Intensity of the reflection light"),
    "back_intensity": ("Back intensity", "Intensity of the transmission light"),
    "vignette_sigma_px": ("Vignetting sigma", "Vignetting falloff exp(-d^2/sigma^2), in pixels"),
    "glow_strength": ("Glow strength", "Out-of-focus glow of the back light seen through the gaps"),
    "glow_sigma_px": ("Glow sigma", "Size of the back light's glow, in pixels"),
    "gamma": ("Gamma", "Display gamma of the photos"),
    "clamp": ("Clamp", "Radiance clamp before the gamma"),
    "camera_blur_px": ("Camera blur", "Point spread of the camera in pixels (a fit estimates it; 0: sharp)"),
    "width_cm": ("Photographed width", "Real width of the photographed square in centimetres "
                                       "(0: unknown); gives the material its real-world scale"),
}


@dataclass(frozen=True)
class RigField:
    name: str
    kind: str            # "int", "float" or "vector"
    default: object
    label: str
    description: str


def rig_fields() -> list[RigField]:
    """The rig's settings with the spec's defaults, in declaration order (width_cm: float, 0 = unknown)."""
    rig = paths.backend_module("core.rig")
    defaults = rig.DEFAULT_RIG
    fields = []
    for spec in dataclasses.fields(rig.CaptureRig):
        value = getattr(defaults, spec.name)
        if spec.name == "width_cm":
            kind, value = "float", float(value or 0.0)
        elif isinstance(value, tuple):
            kind = "vector"
        elif isinstance(value, int):
            kind = "int"
        else:
            kind = "float"
        label, description = _RIG_TEXT.get(spec.name, (spec.name.replace("_", " ").capitalize(), spec.name))
        fields.append(RigField(spec.name, kind, value, label, description))
    return fields


def rig_dict(values: dict) -> dict:
    """Validated ``CaptureRig.to_dict()`` from panel values; width_cm 0 means unknown.

    Raises ValueError (the backend's RigError) naming the bad setting.
    """
    rig = paths.backend_module("core.rig")
    data = {name: (list(value) if hasattr(value, "__len__") else value)
            for name, value in values.items()}
    if not data.get("width_cm"):
        data["width_cm"] = None
    return rig.CaptureRig.from_dict(data).to_dict()


def write_rig_json(folder: Path, rig: dict) -> Path:
    path = Path(folder) / "rig.json"
    path.write_text(json.dumps(rig, indent=2) + "\n")
    return path


def read_fit_params(result: dict) -> dict:
    """The ``params.json`` named by a fit's result event, as a dict."""
    path = Path(result.get("params") or Path(result["out_dir"]) / "params.json")
    try:
        return json.loads(path.read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the fitted parameters ({exc.strerror or exc})") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: the fitted parameters are not valid JSON ({exc})") from None
