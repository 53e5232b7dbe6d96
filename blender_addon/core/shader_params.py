"""Sockets of the "Woven Fabric" node group and OSL shader, from the parameter declaration.

Plain Python (no bpy, no torch): everything here is testable without Blender.

Sockets (one per scalar component, ranges = the backend's lo/hi). Each has an *identifier*, the spec
name that params.json, the backend, the OSL shader and the tests use (``roughness warp``), and a
readable *label* and tooltip from the declaration (``ParamSpec.label`` / ``doc`` / ``unit``) under one
of the node's :data:`PANELS`:

- Weave: ``pattern`` (integer, the preset index in ``backend.core.weave.PRESETS`` order: 0 plain,
  1 twill0, 2 twill1, 3 satin0, 4 satin1), ``tiles warp`` / ``tiles weft`` (tu, the repeats along U;
  tv, along V) and ``uv scale`` (extra repeats factor for real-world scale, see :func:`uv_scale`;
  default 1; an object's ``woven_fabric_uv_scale`` property, written by Set Real-World Scale,
  overrides it for that object);
- Warp / Weft: every other per-yarn value, as ``"<name> warp"`` and ``"<name> weft"``
  (``specular_albedo`` as colours);
- Colour: the RGB values (``diffuse_reflection`` / ``diffuse_transmission``), then the dye
  (core/dye.py): ``colour map`` (default white), the colour that multiplies the fabric's colour,
  and ``colour map replace`` (default 0), where 1 makes the map replace it (Add Colour Layer links
  a painted image's colour and alpha there); the whole-fabric recolour ``recolour hue`` (degrees),
  ``recolour saturation`` and ``recolour value`` (factors);
- Warp stripes / Weft stripes: the yarn-dyed sett (core/sett.py), ``warp stripe 1 colour``,
  ``warp stripe 1 threads``, ... (no threads: no pattern);
- Warp variation / Weft variation: the yarn variations (the backend's ``core/variation.py``: each an
  amplitude, 0 by default, and a correlation length), ``width_variation warp``, ...;
- Advanced: the remaining scalars.

The OSL parameter of a socket is its name with spaces replaced by underscores
(``roughness warp`` -> ``roughness_warp``), but for names OSL has a function of (:data:`OSL_RENAMED`).

Tiles and physical size. In the rig (the backend's ``CaptureRig``) the fabric plane is
``plane_size`` (10) units square with UV = (x / 10, y / 10 + 1), and ``tiles`` counts pattern
repeats per UV unit square, which the shader keeps exactly (so the rig scene in Blender reproduces
the backend's geometry). The rig's visible square, side V = 2 h tan(fov / 2) units (7.977 with the
default rig), is ``width_cm`` wide in reality, so one UV unit of the rig plane is
``plane_size * width_cm / V`` cm. A cloth whose UV unit square is ``cloth_size_cm`` wide therefore
needs

    tiles_cloth = tiles * cloth_size_cm / (plane_size * width_cm / V)

repeats per UV unit: the ``uv scale`` socket holds ``cloth_size_cm * V / (plane_size * width_cm)``
and the shader multiplies ``tiles`` by it (the tiles sockets keep the params.json values).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from . import declarations, dye, rig_settings, sett

YARNS = ("warp", "weft")
UV_SCALE = "uv scale"
PATTERN = "pattern"
COLOUR_MAP = "colour map"
MAP_REPLACE = "colour map replace"
RECOLOUR = ("recolour hue", "recolour saturation", "recolour value")
STRIPE_PANELS = {"warp": "Warp stripes", "weft": "Weft stripes"}
VARIATION_PANELS = {"warp": "Warp variation", "weft": "Weft variation"}
PANELS = ("Weave", "Warp", "Weft", "Colour", *STRIPE_PANELS.values(), *VARIATION_PANELS.values(), "Advanced")
CLOSED_PANELS = ("Advanced", *STRIPE_PANELS.values(), *VARIATION_PANELS.values())  # panels the node shows folded
# OSL parameters renamed from their socket names: a parameter named after an OSL function hides it
# (the compiler warns '"noise" already declared in this scope').
OSL_RENAMED = {"noise": "noise_amount"}
# Object property that overrides the material's uv scale for that object (Set Real-World Scale).
OBJECT_UV_SCALE = "woven_fabric_uv_scale"
_WEAVE_PARAMS = ("tiles",)
_AXES = ("U", "V")  # tiles warp counts repeats along U, tiles weft along V


@dataclass(frozen=True)
class SocketSpec:
    """One input of the node group (and of the OSL shader).

    name: the identifier (spec name). kind: "INT", "FLOAT" or "COLOR". param: the params.json key
    it comes from (None for the extras: maps, map replace, uv scale). yarn: 0 (warp) or 1 (weft) for
    per-yarn values, else None. label: the readable name on the node, unique within its panel.
    description: the tooltip.
    """

    name: str
    kind: str
    default: Any
    lo: float
    hi: float
    param: str | None
    yarn: int | None
    description: str
    label: str = ""
    panel: str = "Advanced"

    @property
    def osl(self) -> str:
        return osl_name(self.name)


def osl_name(socket_name: str) -> str:
    return OSL_RENAMED.get(socket_name, socket_name.replace(" ", "_"))


def pattern_index(name: str) -> int:
    names = declarations.preset_names()
    if name not in names:
        raise ValueError(f"pattern: the Woven Fabric shader supports the presets {', '.join(names)}, "
                         f"not {name!r}")
    return names.index(name)


def pattern_name(index: int) -> str:
    names = declarations.preset_names()
    return names[max(0, min(int(round(index)), len(names) - 1))]


def _range_text(lo: float, hi: float, unit: str = "") -> str:
    return f"{lo:g} to {hi:g}" + (f" {unit}" if unit else "")


def _panel(spec) -> str:
    if spec.name in _WEAVE_PARAMS:
        return "Weave"
    if spec.rgb and not spec.per_yarn:
        return "Colour"
    return "Advanced"


def _yarn_sockets(spec, kind: str, value, doc: str) -> list[SocketSpec]:
    """A per-yarn parameter's two inputs: in the Weave panel by axis, the variations in each yarn's
    variation panel, the others in each yarn's panel."""
    sockets = []
    varied = spec.name in declarations.variation_parameters()
    for yarn, yarn_name in enumerate(YARNS):
        weave = spec.name in _WEAVE_PARAMS
        label = f"{spec.label} {_AXES[yarn]}" if weave else spec.label
        panel = "Weave" if weave else VARIATION_PANELS[yarn_name] if varied else yarn_name.capitalize()
        sockets.append(SocketSpec(
            f"{spec.name} {yarn_name}", kind, tuple(value[yarn]) if spec.rgb else value[yarn], spec.lo,
            spec.hi, spec.name, yarn,
            f"{doc}, {yarn_name} yarns ({_range_text(spec.lo, spec.hi, spec.unit)}). "
            f"params.json: {spec.name}[{yarn}]", label, panel))
    return sockets


def _single_sockets(spec, kind: str, value, doc: str) -> list[SocketSpec]:
    """A parameter's one input."""
    return [SocketSpec(
        spec.name, kind, tuple(value) if spec.rgb else value, spec.lo, spec.hi, spec.name, None,
        f"{doc} ({_range_text(spec.lo, spec.hi, spec.unit)}). params.json: {spec.name}", spec.label, _panel(spec))]


def _dye_sockets() -> list[SocketSpec]:
    """The Colour panel's dye inputs (core/dye.py): the colour map, its replace factor, the recolour."""
    hue, saturation, value = dye.NEUTRAL_RECOLOUR
    return [
        SocketSpec(COLOUR_MAP, "COLOR", (1.0, 1.0, 1.0), 0.0, 1.0, None, None,
                   "Dyes the yarns, diffuse and specular together: multiplies the fabric's colour (white: no "
                   "change); plug a painted image (Add Colour Layer)", "Colour map", "Colour"),
        SocketSpec(MAP_REPLACE, "FLOAT", 0.0, 0.0, 1.0, None, None,
                   "0: the colour map multiplies the fabric's colour; 1: the yarns are dyed to the map's colour "
                   "(link a painted image's alpha to replace only where painted)", "Map replaces colour", "Colour"),
        SocketSpec(RECOLOUR[0], "FLOAT", hue, -180.0, 180.0, None, None,
                   "Turns the hue of the whole fabric's colour (and of its stripes), in degrees", "Hue shift",
                   "Colour"),
        SocketSpec(RECOLOUR[1], "FLOAT", saturation, 0.0, 4.0, None, None,
                   "Scales the saturation of the whole fabric's colour (1: as fitted)", "Saturation", "Colour"),
        SocketSpec(RECOLOUR[2], "FLOAT", value, 0.0, 4.0, None, None,
                   "Scales the brightness of the whole fabric's colour (1: as fitted; the albedos stay at most 1)",
                   "Value", "Colour"),
    ]


def _stripe_sockets(direction: str) -> list[SocketSpec]:
    """One yarn direction's sett (core/sett.py): a colour and a thread count per stripe."""
    sockets = []
    for index in range(sett.STRIPES):
        sockets.append(SocketSpec(
            sett.socket_name(direction, index, "colour"), "COLOR", (1.0, 1.0, 1.0), 0.0, 1.0, None, None,
            f"Dye colour of the {direction} yarns of stripe {index + 1}", f"Stripe {index + 1} colour",
            STRIPE_PANELS[direction]))
        sockets.append(SocketSpec(
            sett.socket_name(direction, index, "threads"), "INT", 0, 0, sett.MAX_THREADS, None, None,
            f"{direction.capitalize()} threads of stripe {index + 1} (the sett repeats after the stripes' "
            f"threads; none at all: no pattern)", f"Stripe {index + 1} threads", STRIPE_PANELS[direction]))
    return sockets


def socket_specs() -> list[SocketSpec]:
    """Every group input, in UI order (panel by panel, see :data:`PANELS`)."""
    declaration = declarations.parameters()
    defaults = declarations.default_params()
    names = declarations.preset_names()
    presets = ", ".join(f"{i} {n}" for i, n in enumerate(names))
    by_panel: dict[str, list[SocketSpec]] = {panel: [] for panel in PANELS}
    by_panel["Weave"].append(SocketSpec(PATTERN, "INT", names.index(defaults["pattern"]), 0, len(names) - 1,
                                        PATTERN, None, f"Weave preset: {presets}. params.json: pattern",
                                        "Pattern", "Weave"))
    for spec in declaration:
        value = defaults[spec.name]
        kind = "COLOR" if spec.rgb else "FLOAT"
        doc = spec.doc if "_" in spec.doc.split(" ", 1)[0] else spec.doc[:1].upper() + spec.doc[1:]
        sockets = _yarn_sockets(spec, kind, value, doc) if spec.per_yarn else _single_sockets(spec, kind, value, doc)
        for socket in sockets:
            by_panel[socket.panel].append(socket)
        if spec.name == "tiles":
            by_panel["Weave"].append(SocketSpec(
                UV_SCALE, "FLOAT", 1.0, 1e-4, 1e4, None, None,
                "Multiplies the tiles for real-world scale: cloth_size_cm * V / (plane_size * width_cm); 1 for "
                "the rig's UV layout. An object's Set Real-World Scale value overrides it", "UV scale", "Weave"))
    by_panel["Colour"] += _dye_sockets()
    for direction, panel in STRIPE_PANELS.items():
        by_panel[panel] += _stripe_sockets(direction)
    return [s for panel in PANELS for s in by_panel[panel]]


def _clamp(x: float, lo: float, hi: float) -> float:
    return min(max(float(x), lo), hi)


def socket_values(params: dict) -> dict[str, Any]:
    """Socket name -> value for a params.json dict (values clamped into the declared ranges).

    Missing parameters keep their defaults; extra keys (rig, interchange, ...) are ignored.
    Maps and uv scale are not set here (see :func:`uv_scale`).
    """
    if not isinstance(params, dict) or "pattern" not in params:
        raise ValueError("params: expected a params.json object with at least a 'pattern'")
    out: dict[str, Any] = {PATTERN: pattern_index(params["pattern"])}
    for s in socket_specs():
        if s.param is None or s.param == PATTERN or s.param not in params:
            continue
        value = params[s.param]
        try:
            if s.yarn is not None:
                value = value[s.yarn]
            if s.kind == "COLOR":
                if len(value) != 3:
                    raise ValueError
                out[s.name] = tuple(_clamp(c, s.lo, s.hi) for c in value)
            else:
                out[s.name] = _clamp(value, s.lo, s.hi)
        except (TypeError, ValueError, IndexError):
            raise ValueError(f"{s.param}: malformed value {params[s.param]!r}") from None
    return out


def params_from_sockets(values: dict[str, Any]) -> dict:
    """Inverse of :func:`socket_values`: a params.json dict (``FabricParams.to_dict()`` shape)."""
    out: dict[str, Any] = {"pattern": pattern_name(values[PATTERN])}
    for spec in declarations.parameters():
        def get(name):
            v = values[name]
            return [float(c) for c in v][:3] if spec.rgb else float(v)
        if spec.per_yarn:
            out[spec.name] = [get(f"{spec.name} {y}") for y in YARNS]
        else:
            out[spec.name] = get(spec.name)
    return out


def view_size(rig: dict | None = None) -> float:
    """Side V of the rig's visible square, in scene units: 2 h tan(fov / 2) (``CaptureRig.view_size``)."""
    return rig_settings.capture_rig(rig).view_size


def uv_unit_cm(width_cm: float, rig: dict | None = None) -> float:
    """Real size (cm) of one UV unit of the rig plane: plane_size * width_cm / V."""
    capture = rig_settings.capture_rig(rig)
    return capture.plane_size * float(width_cm) / capture.view_size


def uv_scale(width_cm: float | None, cloth_size_cm: float | None, rig: dict | None = None) -> float:
    """Factor on tiles for a cloth whose UV unit square is ``cloth_size_cm`` wide (1 if unknown)."""
    if width_cm is None or cloth_size_cm is None:
        return 1.0
    if not (width_cm > 0 and cloth_size_cm > 0):
        raise ValueError(f"width_cm and cloth_size_cm must be positive (got {width_cm}, {cloth_size_cm})")
    return float(cloth_size_cm) / uv_unit_cm(width_cm, rig)
