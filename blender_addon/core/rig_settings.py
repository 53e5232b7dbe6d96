"""The capture rig's settings (no bpy): the backend's ``CaptureRig`` (``backend/core/rig.py``) as the
panel, the batch and the rig scene use it.

The fields, their order and their defaults (the spec's rig) come from ``CaptureRig`` itself: the
panel shows every field, and a new field appears without touching the add-on. This module adds only
what a user interface needs: labels, tooltips, a kind per field, and ``width_cm`` as a float where
0 means unknown (a Blender property cannot be None).
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

from . import declarations

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
    "sample_rotation_deg": ("Sample rotation", "How far the sample is turned in the holder, counter-clockwise in "
                                               "degrees (0: a fit reads it from the photos)"),
    "sample_skew_deg": ("Sample skew", "How far the sample is pulled out of square, in degrees: its warps and "
                                       "wefts cross at 90 + skew (a fit reads it with the rotation)"),
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


def defaults() -> dict:
    """The spec's rig as ``CaptureRig.to_dict()`` (lists for vectors, width_cm None)."""
    return declarations.rig().DEFAULT_RIG.to_dict()


def with_defaults(rig: dict | None = None) -> dict:
    """``rig`` with the spec's values filled in where a setting is missing or None (width_cm stays)."""
    out = defaults()
    out.update({k: v for k, v in (rig or {}).items() if v is not None or k == "width_cm"})
    return out


def capture_rig(rig: dict | None = None):
    """The backend's ``CaptureRig`` for a rig dict whose missing (or None) settings are the spec's.

    Raises ValueError (the backend's RigError) naming the bad setting, or where ``rig`` is not a dict.
    """
    if rig is not None and not isinstance(rig, dict):
        raise ValueError(f"rig: expected an object of the rig's settings, got {type(rig).__name__}")
    return _capture_rig(with_defaults(rig))


def rig_fields() -> list[RigField]:
    """The rig's settings with the spec's defaults, in declaration order (width_cm: float, 0 = unknown)."""
    rig = declarations.rig()
    fields = []
    for spec in dataclasses.fields(rig.CaptureRig):
        value = getattr(rig.DEFAULT_RIG, spec.name)
        if spec.name == "width_cm":
            kind, value = "float", float(value or 0.0)
        elif isinstance(value, tuple):
            kind = "vector"
        elif isinstance(value, int):
            kind = "int"
        else:
            kind = "float"
        label, description = _RIG_TEXT.get(spec.name, (_label(spec.name), spec.name))
        fields.append(RigField(spec.name, kind, value, label, description))
    return fields


def _label(name: str) -> str:
    """A readable label for a field without one: ``glow_sigma_px`` -> "Glow sigma" (no unit suffix)."""
    return re.sub(r"_(deg|px|cm)$", "", name).replace("_", " ").capitalize()


def rig_dict(values: dict) -> dict:
    """Validated ``CaptureRig.to_dict()`` from the panel's values (what a fit's rig.json holds).

    Raises ValueError (the backend's RigError) naming the bad setting.
    """
    return _capture_rig(values).to_dict()


def _capture_rig(values: dict):
    # width_cm 0 means unknown here (a Blender property cannot be None); CaptureRig wants None.
    return declarations.rig().CaptureRig.from_dict(dict(values, width_cm=values.get("width_cm") or None))
