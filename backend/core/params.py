"""Fabric parameters: the one declaration of names, shapes and ranges.

Everything else reads :data:`PARAMETERS`: validation and clamping here, the JSON form, the
interchange string of the paper's tools, the optimiser's tensors, the Blender node group's
sockets and the OSL shader's inputs (a test checks those stay in step).

Shapes (spec section 2): a *per-yarn* value is a pair ``(warp, weft)``; an RGB value is a triple;
``specular_albedo`` is per yarn *and* RGB: ``((r, g, b), (r, g, b))``.

Interchange string (spec section 2)::

    <pattern>_R_<a,a>_S_<beta,beta>_T_<T,T>_N_<N>_UV_<tu,tv>_Kd_<r,g,b,r,g,b>_G_<xi,xi>
    _Rm_<a,a>_Tm_<T,T>_W_<w,w_m>_Ks_<r,g,b,r,g,b>_Psi_<psi,psi>

``forward_scattering`` (:mod:`backend.model.asggx`) and the yarn variations (``width_variation`` ...
``slub_variation_length``, :mod:`backend.core.variation`) are beyond the paper: the interchange
string does not carry them (reading one gives the paper's lobe and no variation), the JSON form
does. The forward scattering is optimised with the paper's parameters; the variations are neither
optimised nor searched: a fit reads the amplitudes from the photos after
its optimisation (:mod:`backend.fit.variation_estimate`), warp and weft alike, each at the centre of
its length's prior.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

from .jsonfile import read_json, shown
from .weave import PRESETS, Weave, WeaveError


class ParamError(ValueError):
    """A parameter value is missing, malformed or out of range; the message names the field."""


@dataclass(frozen=True)
class ParamSpec:
    """Declaration of one parameter.

    name: JSON and Python name. lo, hi: inclusive range of every component.
    per_yarn: value is a (warp, weft) pair. rgb: value (per yarn) is an RGB triple.
    optimised: fitted by gradient descent; searched: fitted by the discrete search.
    prior: (lo, hi) of the uniform draw a realistic fabric takes where a generator draws this
    parameter (the yarn variations, :mod:`backend.core.variation`; the forward scattering, from the
    values fits of real photos take); None: drawn by core/priors.py's per-pattern rules, or not drawn.
    neutral: a bound at which the parameter leaves the paper's model as it is (a fit that ends there
    has not run into the range, so :meth:`FabricParams.at_bounds` does not list it); None: no such bound.
    """

    name: str
    lo: float
    hi: float
    per_yarn: bool
    rgb: bool
    label: str
    doc: str
    unit: str = ""
    optimised: bool = False
    searched: bool = False
    prior: tuple[float, float] | None = None
    neutral: float | None = None

    @property
    def size(self) -> int:
        """Number of scalar components."""
        return (2 if self.per_yarn else 1) * (3 if self.rgb else 1)


PARAMETERS: tuple[ParamSpec, ...] = (
    ParamSpec("tiles", 1.0, 400.0, True, False, "Tiles",
              "pattern repeats across the full plane of the rig (yarn density)", "repeats", searched=True),
    ParamSpec("roughness", 0.01, 1.0, True, False, "Roughness",
              "SGGX fiber roughness of the single-scattering lobe", optimised=True),
    ParamSpec("thickness", 0.01, 5.0, True, False, "Thickness",
              "optical thickness of the single-scattering lobe", optimised=True),
    ParamSpec("roughness_multiple", 0.01, 1.0, True, False, "Roughness (multiple)",
              "ASGGX roughness of the multiple-scattering lobe", optimised=True),
    ParamSpec("thickness_multiple", 0.01, 5.0, True, False, "Thickness (multiple)",
              "optical thickness of the multiple-scattering lobe", optimised=True),
    ParamSpec("forward_scattering", 0.0, 0.9, True, False, "Forward scattering",
              "how much light crossing the fabric keeps its direction around the fiber (0: evenly around it)",
              optimised=True, neutral=0.0, prior=(0.0, 0.4)),
    ParamSpec("height_scale", 0.01, 2.0, True, False, "Height scale",
              "flattens (<1) or steepens (>1) the yarn normals", optimised=True),
    ParamSpec("gap_scale", 0.01, 1.0, True, False, "Gap scale",
              "yarn width as a fraction of its nominal width", searched=True),
    ParamSpec("twist_deg", -90.0, 90.0, True, False, "Twist",
              "fiber twist angle around the yarn", "degrees", searched=True),
    ParamSpec("specular_albedo", 0.0, 1.0, True, True, "Specular albedo",
              "single-scattering albedo k_s", optimised=True),
    ParamSpec("multiple_weight", 0.01, 2.0, False, False, "Multiple weight",
              "k_m = k_s ** (1 / multiple_weight), per channel", optimised=True),
    ParamSpec("diffuse_reflection", 0.0, 1.0, False, True, "Diffuse (reflection)",
              "diffuse albedo seen in reflection", optimised=True),
    ParamSpec("diffuse_transmission", 0.0, 1.0, False, True, "Diffuse (transmission)",
              "diffuse albedo seen in transmission", optimised=True),
    ParamSpec("diffuse_normal_weight", 0.0, 1.0, False, False, "Diffuse normal weight",
              "blend of yarn-normal (1) and flat (0) Lambert in the diffuse term", optimised=True),
    ParamSpec("noise", 0.0, 10.0, False, False, "Noise",
              "yarn randomness level; 0 while fitting, about 1 for final renders"),
    # Yarn variation (backend/core/variation.py): an amplitude (0: none) and a correlation length each.
    ParamSpec("width_variation", 0.0, 0.5, True, False, "Width variation",
              "relative spread of each yarn's width (opens and closes gaps)", prior=(0.0, 0.1)),
    ParamSpec("width_variation_length", 1.0, 64.0, True, False, "Width correlation",
              "yarns over which the width drifts (1: every yarn on its own)", "yarns", prior=(1.0, 8.0)),
    ParamSpec("thickness_variation", 0.0, 0.5, True, False, "Thickness variation",
              "relative spread of each yarn's optical thickness", prior=(0.0, 0.15)),
    ParamSpec("thickness_variation_length", 1.0, 64.0, True, False, "Thickness correlation",
              "yarns over which the thickness drifts (1: every yarn on its own)", "yarns", prior=(1.0, 8.0)),
    ParamSpec("spacing_variation", 0.0, 0.5, True, False, "Spacing variation",
              "spread of each yarn's sideways slide, in yarn widths", prior=(0.0, 0.1)),
    ParamSpec("spacing_variation_length", 1.0, 64.0, True, False, "Spacing correlation",
              "yarns over which the slide drifts (1: every yarn on its own)", "yarns", prior=(1.0, 8.0)),
    ParamSpec("brightness_variation", 0.0, 0.5, True, False, "Brightness variation",
              "relative spread of each yarn's albedo", prior=(0.0, 0.1)),
    ParamSpec("brightness_variation_length", 1.0, 64.0, True, False, "Brightness correlation",
              "yarns over which the albedo drifts (1: every yarn on its own)", "yarns", prior=(1.0, 8.0)),
    ParamSpec("slub_variation", 0.0, 0.5, True, False, "Slub variation",
              "relative spread of width and thickness along each yarn (slubs)", prior=(0.0, 0.15)),
    ParamSpec("slub_variation_length", 0.5, 64.0, True, False, "Slub length",
              "crossings over which a yarn thickens or thins", "crossings", prior=(2.0, 12.0)),
)

SPECS: dict[str, ParamSpec] = {spec.name: spec for spec in PARAMETERS}

# Interchange keys in the order the paper's tools write them; W packs two of our parameters.
_INTERCHANGE_KEYS = ("R", "S", "T", "N", "UV", "Kd", "G", "Rm", "Tm", "W", "Ks", "Psi")
_INTERCHANGE_FIELDS = {
    "R": ("roughness",), "S": ("height_scale",), "T": ("thickness",), "N": ("noise",),
    "UV": ("tiles",), "Kd": ("diffuse_reflection", "diffuse_transmission"), "G": ("gap_scale",),
    "Rm": ("roughness_multiple",), "Tm": ("thickness_multiple",),
    "W": ("diffuse_normal_weight", "multiple_weight"), "Ks": ("specular_albedo",),
    "Psi": ("twist_deg",),
}


def flatten(spec: ParamSpec, value: Any) -> list[float]:
    """Scalar components of a value of `spec`, warp before weft, r g b."""
    if spec.per_yarn and spec.rgb:
        return [c for yarn in value for c in yarn]
    if spec.per_yarn or spec.rgb:
        return list(value)
    return [value]


def component_labels(spec: ParamSpec) -> list[str]:
    """Labels of the scalar components of a value of ``spec`` in :func:`flatten`'s order:
    ``" (warp)"``, ``" (weft, g)"``, ``" (b)"``, or ``""`` for a scalar."""
    yarns = ("warp", "weft") if spec.per_yarn else (None,)
    channels = ("r", "g", "b") if spec.rgb else (None,)
    labels = []
    for yarn in yarns:
        for channel in channels:
            parts = [p for p in (yarn, channel) if p]
            labels.append(f" ({', '.join(parts)})" if parts else "")
    return labels


def unflatten(spec: ParamSpec, flat: Iterable[float]) -> Any:
    """Inverse of :func:`flatten`: tuples shaped as the dataclass fields."""
    flat = [float(x) for x in flat]
    if len(flat) != spec.size:
        raise ParamError(f"{spec.name}: expected {spec.size} numbers, got {len(flat)}")
    if spec.per_yarn and spec.rgb:
        return (tuple(flat[:3]), tuple(flat[3:]))
    if spec.per_yarn or spec.rgb:
        return tuple(flat)
    return flat[0]


def _coerce(spec: ParamSpec, value: Any) -> Any:
    """Accepts lists, tuples or numbers of the right shape; raises ParamError naming the field."""
    def numbers(seq, n, what):
        if isinstance(seq, (str, bytes)) or not hasattr(seq, "__len__") or len(seq) != n:
            raise ParamError(f"{spec.name}: expected {what}, got {shown(seq)}")
        out = []
        for x in seq:
            try:
                out.append(float(x))
            except (TypeError, ValueError):
                raise ParamError(f"{spec.name}: {shown(x)} is not a number") from None
        return out

    if spec.per_yarn and spec.rgb:
        if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 2:
            raise ParamError(f"{spec.name}: expected [[warp r, g, b], [weft r, g, b]], got {shown(value)}")
        return tuple(tuple(numbers(yarn, 3, "an RGB triple per yarn")) for yarn in value)
    if spec.per_yarn:
        return tuple(numbers(value, 2, "a [warp, weft] pair"))
    if spec.rgb:
        return tuple(numbers(value, 3, "an [r, g, b] triple"))
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ParamError(f"{spec.name}: expected a number, got {shown(value)}") from None


@dataclass(frozen=True)
class FabricParams:
    """Parameters of the woven-fabric BSDF (spec section 2), validated on construction.

    ``pattern`` names a preset weave (plain, twill0, twill1, satin0, satin1) or ``custom``,
    in which case ``weave`` holds the interlacing matrix and bands. Values outside the
    declared ranges raise :class:`ParamError`; use :meth:`clamped` to pull them in.
    """

    pattern: str = "plain"
    tiles: tuple[float, float] = (173.0, 173.0)
    roughness: tuple[float, float] = (0.5, 0.5)
    thickness: tuple[float, float] = (1.5, 1.5)
    roughness_multiple: tuple[float, float] = (0.5, 0.5)
    thickness_multiple: tuple[float, float] = (1.5, 1.5)
    forward_scattering: tuple[float, float] = (0.0, 0.0)
    height_scale: tuple[float, float] = (1.0, 1.0)
    gap_scale: tuple[float, float] = (0.9, 0.9)
    twist_deg: tuple[float, float] = (0.0, 0.0)
    specular_albedo: tuple[tuple[float, float, float], tuple[float, float, float]] = (
        (0.5, 0.5, 0.5), (0.5, 0.5, 0.5))
    multiple_weight: float = 1.0
    diffuse_reflection: tuple[float, float, float] = (0.3, 0.3, 0.3)
    diffuse_transmission: tuple[float, float, float] = (0.3, 0.3, 0.3)
    diffuse_normal_weight: float = 0.5
    noise: float = 0.0
    width_variation: tuple[float, float] = (0.0, 0.0)
    width_variation_length: tuple[float, float] = (1.0, 1.0)
    thickness_variation: tuple[float, float] = (0.0, 0.0)
    thickness_variation_length: tuple[float, float] = (1.0, 1.0)
    spacing_variation: tuple[float, float] = (0.0, 0.0)
    spacing_variation_length: tuple[float, float] = (1.0, 1.0)
    brightness_variation: tuple[float, float] = (0.0, 0.0)
    brightness_variation_length: tuple[float, float] = (1.0, 1.0)
    slub_variation: tuple[float, float] = (0.0, 0.0)
    slub_variation_length: tuple[float, float] = (4.0, 4.0)
    weave: Weave | None = None

    def __post_init__(self):
        if not isinstance(self.pattern, str):
            raise ParamError(f"pattern: expected the name of a weave, got {shown(self.pattern)}")
        if self.pattern == "custom":
            if not isinstance(self.weave, Weave):
                raise ParamError("pattern: 'custom' needs a weave (interlacing matrix and bands)")
        elif self.pattern not in PRESETS:
            raise ParamError(f"pattern: unknown weave {shown(self.pattern)}; "
                             f"expected one of {', '.join(PRESETS)} or 'custom'")
        for spec in PARAMETERS:
            value = _coerce(spec, getattr(self, spec.name))
            for x in flatten(spec, value):
                if not math.isfinite(x) or not spec.lo <= x <= spec.hi:
                    raise ParamError(f"{spec.name}: {x!r} is outside [{spec.lo:g}, {spec.hi:g}] "
                                     f"({spec.doc})")
            object.__setattr__(self, spec.name, value)

    # -- derived -----------------------------------------------------------------------------
    @property
    def resolved_weave(self) -> Weave:
        """The weave geometry: the preset of that name or the custom weave."""
        return self.weave if self.pattern == "custom" else PRESETS[self.pattern]

    def replace(self, **changes) -> "FabricParams":
        return dataclasses.replace(self, **changes)

    @classmethod
    def clamped_from(cls, pattern: str = "plain", weave: Weave | None = None, **values) -> "FabricParams":
        """Builds parameters with every component clamped into its range (non-finite is an error)."""
        fixed = {}
        for name, value in values.items():
            spec = SPECS.get(name)
            if spec is None:
                raise ParamError(f"{name}: unknown parameter")
            flat = flatten(spec, _coerce(spec, value))
            if not all(math.isfinite(x) for x in flat):
                raise ParamError(f"{name}: non-finite value {value!r}")
            fixed[name] = unflatten(spec, [min(max(x, spec.lo), spec.hi) for x in flat])
        return cls(pattern=pattern, weave=weave, **fixed)

    def flat(self, name: str) -> list[float]:
        return flatten(SPECS[name], getattr(self, name))

    def at_bounds(self, names: Iterable[str], tolerance: float = 1e-3) -> list[str]:
        """The components of ``names`` within ``tolerance`` x range of a bound, as
        ``"roughness (weft) = 1 (upper bound)"``: a fit that ends there may want a value beyond the
        declared range (or the images do not constrain it)."""
        out = []
        for name in names:
            spec = SPECS[name]
            margin = tolerance * (spec.hi - spec.lo)
            for label, x in zip(component_labels(spec), self.flat(name)):
                bound = "lower" if x <= spec.lo + margin else "upper" if x >= spec.hi - margin else None
                neutral = spec.neutral is not None and abs(x - spec.neutral) <= margin
                if bound and not neutral:
                    out.append(f"{name}{label} = {x:g} ({bound} bound)")
        return out

    # -- JSON ------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """JSON-ready dict with the spec's names; pairs are [warp, weft]."""
        out: dict[str, Any] = {"pattern": self.pattern}
        for spec in PARAMETERS:
            value = getattr(self, spec.name)
            out[spec.name] = [list(v) for v in value] if spec.per_yarn and spec.rgb else (
                list(value) if isinstance(value, tuple) else value)
        if self.pattern == "custom":
            out["weave"] = self.weave.to_dict()
        return out

    @classmethod
    def from_dict(cls, data: dict, clamp: bool = False) -> "FabricParams":
        """Reads the JSON form; extra keys (units, rig, version, ...) are ignored.

        Missing parameters take the dataclass defaults. A parameter holds numbers (or lists of
        them): text, true/false, null or an object is refused. With clamp=True out-of-range values
        are pulled into range instead of raising.
        """
        if not isinstance(data, dict):
            raise ParamError(f"parameters: expected a JSON object, got {type(data).__name__}")
        if "pattern" not in data:
            raise ParamError("pattern: missing")
        weave = None
        if data["pattern"] == "custom":
            if "weave" not in data:
                raise ParamError("weave: pattern 'custom' needs a 'weave' object")
            weave = Weave.from_dict(data["weave"])
        values = {spec.name: data[spec.name] for spec in PARAMETERS if spec.name in data}
        for name, value in values.items():
            _numbers_only(name, value)
        if clamp:
            return cls.clamped_from(pattern=data["pattern"], weave=weave, **values)
        return cls(pattern=data["pattern"], weave=weave, **values)

    def to_json(self, **extra) -> str:
        return json.dumps({**self.to_dict(), **extra}, indent=2)

    # -- interchange string ----------------------------------------------------------------
    def to_interchange(self) -> str:
        """The paper's parameter string (custom weaves are written under the name 'custom')."""
        parts = [self.pattern]
        for key in _INTERCHANGE_KEYS:
            flat = [x for name in _INTERCHANGE_FIELDS[key] for x in self.flat(name)]
            parts += [key, ",".join(_short(x) for x in flat)]
        return "_".join(parts)

    @classmethod
    def from_interchange(cls, text: str, clamp: bool = False) -> "FabricParams":
        """Parses the paper's parameter string; raises ParamError naming the bad key."""
        tokens = text.strip().split("_")
        if len(tokens) < 3 or len(tokens) % 2 == 0:
            raise ParamError(f"interchange string: expected <pattern>_KEY_values..., got {text!r}")
        pattern = tokens[0]
        found: dict[str, list[float]] = {}
        for key, raw in zip(tokens[1::2], tokens[2::2]):
            if key not in _INTERCHANGE_FIELDS:
                raise ParamError(f"interchange string: unknown key {key!r}")
            try:
                found[key] = [float(x) for x in raw.split(",")]
            except ValueError:
                raise ParamError(f"interchange string: key {key}: {raw!r} is not a list of numbers") from None
        missing = [k for k in _INTERCHANGE_KEYS if k not in found]
        if missing:
            raise ParamError(f"interchange string: missing key(s) {', '.join(missing)}")
        values: dict[str, Any] = {}
        for key, numbers in found.items():
            names = _INTERCHANGE_FIELDS[key]
            want = sum(SPECS[n].size for n in names)
            if len(numbers) != want:
                raise ParamError(f"interchange string: key {key} needs {want} numbers, got {len(numbers)}")
            for name in names:
                size = SPECS[name].size
                values[name], numbers = unflatten(SPECS[name], numbers[:size]), numbers[size:]
        if clamp:
            return cls.clamped_from(pattern=pattern, **values)
        return cls(pattern=pattern, **values)


def _numbers_only(name: str, value) -> None:
    """Raises ParamError where a value read from JSON holds anything but numbers and lists of them:
    text (even "0.5"), true/false, null or an object is a wrong type, not a number to convert."""
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, (list, tuple)):
            stack.extend(item)
        elif isinstance(item, bool) or not isinstance(item, (int, float)):
            raise ParamError(f"{name}: expected numbers, got {shown(item)}")


def _short(x: float) -> str:
    """Shortest text that reads back to the same float."""
    return repr(float(x))


def _is_file(path) -> bool:
    """``path.is_file()``, False where the text cannot be a path (a long interchange string)."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def load_params(source: str) -> FabricParams:
    """Reads parameters from a JSON file path or an interchange string."""
    path = Path(source)
    if source.endswith(".json") or _is_file(path):
        data = read_json(source, ParamError)
        try:
            return FabricParams.from_dict(data)
        except (ParamError, WeaveError) as exc:
            raise ParamError(f"{source}: {exc}") from None
    return FabricParams.from_interchange(source)
