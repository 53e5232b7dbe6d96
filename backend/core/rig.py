"""The capture rig as data (spec section 1); the defaults are the paper's rig.

Geometry: the fabric is the plane z = 0 (``plane_size`` units square, x in [0, P], y in [-P, 0]);
a pinhole camera at height ``camera_height`` looks straight down with full field of view
``fov_deg``, so the visible square has side V = 2 h tan(fov / 2) and spans x in [0, V],
y in [-V, 0]; the camera sits above its centre. Light positions are given relative to the centre
of the visible square, (V/2, -V/2, 0); the defaults put the front light 8 units "above" the top
edge in y and 8 up, the back light 9 below the camera.

Radiance = (cosine-weighted BSDF) * intensity / distance^2. Output transform per image: clamp to
at most ``clamp``, raise to 1 / gamma, multiply by the vignetting mask exp(-d^2 / sigma^2)
normalised to a maximum of 1 (d in pixels of the ``film_size`` film, from the film centre).
The transmission image adds ``glow_strength * exp(-d^2 / glow_sigma_px^2)`` (same normalised
form) to samples that see no yarn, before the clamp.

The sample's placement: turned by ``sample_rotation_deg`` about the centre of the visible square
(counter-clockwise as the camera sees it) and sheared by ``sample_skew_deg`` (a cloth pulled a
little out of square when it was laid flat): the warps are turned by rotation + skew / 2, the wefts
by rotation - skew / 2, so they cross at 90 + skew degrees (:attr:`CaptureRig.yarn_angles_deg`);
each yarn keeps its own shape. A real sample sits a few degrees off and a little skewed, enough to
move the lattice by more than a cycle across the image; the fit reads both from the photos' spectra.

Parameters of :class:`CaptureRig` (the paper's renderer has no blur, rotation or skew):

    ===================  ==================  =====================================================
    film_size            px (512)            side of the rendered film
    plane_size           units (10)          side of the fabric plane
    camera_height        units (8)           height of the pinhole camera
    fov_deg              degrees (53)        full field of view, in (0, 170)
    front_light          units (0, 8, 8)     reflection light, from the view centre; z > 0
    back_light           units (0, 0, -9)    transmission light, from the view centre; z < 0
    front_intensity      (300)               intensity of the front light
    back_intensity       (300)               intensity of the back light
    vignette_sigma_px    film px (450)       sigma of the vignetting mask
    glow_strength        (8)                 strength of the back light's glow through the gaps
    glow_sigma_px        film px (20)        sigma of the glow
    gamma                (2.2)               display encoding
    clamp                (1)                 radiance clamped here before encoding
    camera_blur_px       film px (0)         the camera's Gaussian point spread (lens,
                                             demosaicing, resize), applied to linear radiance
                                             before the output transform; 0 to 4
    sample_rotation_deg  degrees (0)         the sample's turn in the holder; -45 to 45
    sample_skew_deg      degrees (0)         the sample's shear in the holder; -10 to 10
    width_cm             cm (None)           real width of the visible square, when known
    ===================  ==================  =====================================================

A phone photo shows about a pixel of camera blur; a sharp render of yarns beside a soft photo pushes
a fit to wash them out, which is why the blur is part of the rig.
"""
from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass
from pathlib import Path

from .jsonfile import listed, read_json, shown

MAX_CAMERA_BLUR_PX = 4.0        # film px a rig may declare; a phone photo shows about one
MAX_SAMPLE_ROTATION_DEG = 45.0  # beyond it the warp and the weft would trade directions
MAX_SAMPLE_SKEW_DEG = 10.0      # a cloth laid flat by hand is a few degrees off square
MIN_FILM_SIZE = 32    # the smallest film the fit works on (backend.core.fit_options.MIN_WORKING_SIZE, the loss's least)
MAX_FILM_SIZE = 4096  # 8x the paper's 512 px: a larger film is a typo (working images and re-renders are film-sized)


def yarn_angles(rotation_deg: float, skew_deg: float) -> tuple[float, float]:
    """(warp, weft) angles of a sample turned by ``rotation_deg`` and sheared by ``skew_deg``:
    rotation + skew / 2 and rotation - skew / 2 (degrees, counter-clockwise as the camera sees it)."""
    return rotation_deg + skew_deg / 2.0, rotation_deg - skew_deg / 2.0


def placement_of(warp_deg: float, weft_deg: float) -> tuple[float, float]:
    """The inverse of :func:`yarn_angles`: (rotation, skew) of yarn angles (warp, weft)."""
    return (warp_deg + weft_deg) / 2.0, warp_deg - weft_deg


class RigError(ValueError):
    """A rig setting is missing or out of range; the message names it."""


def _check_kinds(rig: "CaptureRig") -> None:
    """Raises :class:`RigError` naming the first setting that is not of its kind: every setting a
    finite number (not true/false, not text; ``width_cm`` may be None), the lights three of them.
    Their ranges are checked after."""
    def number(value) -> bool:
        return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)

    for field in dataclasses.fields(rig):
        value = getattr(rig, field.name)
        if field.name in ("front_light", "back_light"):
            if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__len__") or len(value) != 3 \
                    or not all(number(x) for x in value):
                raise RigError(f"rig.{field.name}: expected [x, y, z], three numbers, got {shown(value)}")
        elif not number(value) and not (field.name == "width_cm" and value is None):
            raise RigError(f"rig.{field.name}: expected a finite number, got {shown(value)}")


def _check_film_size(film_size: float) -> None:
    """Raises :class:`RigError` unless ``film_size`` (a positive number) is a whole number of pixels
    from MIN_FILM_SIZE to MAX_FILM_SIZE."""
    if film_size != int(film_size) or not MIN_FILM_SIZE <= film_size <= MAX_FILM_SIZE:
        raise RigError(f"rig.film_size: must be a whole number of pixels from {MIN_FILM_SIZE} to {MAX_FILM_SIZE}, "
                       f"got {film_size!r}")


@dataclass(frozen=True)
class CaptureRig:
    """The rig's geometry, lights, output transform, camera blur and sample placement (module docstring)."""

    film_size: int = 512
    plane_size: float = 10.0
    camera_height: float = 8.0
    fov_deg: float = 53.0
    front_light: tuple[float, float, float] = (0.0, 8.0, 8.0)
    back_light: tuple[float, float, float] = (0.0, 0.0, -9.0)
    front_intensity: float = 300.0
    back_intensity: float = 300.0
    vignette_sigma_px: float = 450.0
    glow_strength: float = 8.0
    glow_sigma_px: float = 20.0
    gamma: float = 2.2
    clamp: float = 1.0
    camera_blur_px: float = 0.0
    sample_rotation_deg: float = 0.0
    sample_skew_deg: float = 0.0
    width_cm: float | None = None

    def __post_init__(self):
        _check_kinds(self)
        for name in ("film_size", "plane_size", "camera_height", "front_intensity", "back_intensity",
                     "vignette_sigma_px", "glow_sigma_px", "gamma", "clamp"):
            self._check_positive(name)
        if self.width_cm is not None:
            self._check_positive("width_cm")
        self._check_ranges()
        for name, side in (("front_light", 1), ("back_light", -1)):
            object.__setattr__(self, name, self._checked_light(name, side))
        _check_film_size(self.film_size)
        object.__setattr__(self, "film_size", int(self.film_size))

    def _check_positive(self, name: str) -> None:
        value = getattr(self, name)
        if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise RigError(f"rig.{name}: must be a positive number, got {value!r}")

    def _check_ranges(self) -> None:
        """The field of view, the camera blur, the sample's placement and the glow within their ranges."""
        if not 0 < self.fov_deg < 170:
            raise RigError(f"rig.fov_deg: must be in (0, 170), got {self.fov_deg!r}")
        if not isinstance(self.camera_blur_px, (int, float)) or not 0 <= self.camera_blur_px <= MAX_CAMERA_BLUR_PX:
            raise RigError(f"rig.camera_blur_px: must be in [0, {MAX_CAMERA_BLUR_PX}], got {self.camera_blur_px!r}")
        for name, limit in (("sample_rotation_deg", MAX_SAMPLE_ROTATION_DEG), ("sample_skew_deg", MAX_SAMPLE_SKEW_DEG)):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not abs(value) <= limit:
                raise RigError(f"rig.{name}: must be in [-{limit:g}, {limit:g}] degrees, got {value!r}")
        if self.glow_strength < 0:
            raise RigError(f"rig.glow_strength: must be >= 0, got {self.glow_strength!r}")

    def _checked_light(self, name: str, side: int) -> tuple[float, float, float]:
        """The light ``name`` as three finite floats, above the fabric (``side`` 1) or below it (-1)."""
        value = getattr(self, name)
        try:
            value = tuple(float(x) for x in value)
        except (TypeError, ValueError):
            raise RigError(f"rig.{name}: expected [x, y, z], got {value!r}") from None
        if len(value) != 3 or not all(math.isfinite(x) for x in value):
            raise RigError(f"rig.{name}: expected [x, y, z], got {value!r}")
        if value[2] * side <= 0:
            where = "above (z > 0)" if side > 0 else "below (z < 0)"
            raise RigError(f"rig.{name}: the light must be {where} the fabric, got z = {value[2]}")
        return value

    @property
    def view_size(self) -> float:
        """Side V of the visible square, in scene units."""
        return 2.0 * self.camera_height * math.tan(math.radians(self.fov_deg) / 2.0)

    @property
    def view_centre(self) -> tuple[float, float]:
        return self.view_size / 2.0, -self.view_size / 2.0

    @property
    def yarn_angles_deg(self) -> tuple[float, float]:
        """(warp, weft): how far the warps and the wefts are turned (:func:`yarn_angles`)."""
        return yarn_angles(self.sample_rotation_deg, self.sample_skew_deg)

    def camera_position(self) -> tuple[float, float, float]:
        cx, cy = self.view_centre
        return cx, cy, self.camera_height

    def light_position(self, which: str) -> tuple[float, float, float]:
        """World position of the 'front' (reflection) or 'back' (transmission) light."""
        cx, cy = self.view_centre
        dx, dy, z = self.front_light if which == "front" else self.back_light
        return cx + dx, cy + dy, z

    def mirrored(self) -> "CaptureRig":
        """The rig as its photos mirrored left-right show it: the lights' x offsets, the sample's
        rotation and skew negated (a yarn at angle a from its axis appears at -a)."""
        def flipped(light):
            return (-light[0], light[1], light[2])

        return dataclasses.replace(self, front_light=flipped(self.front_light), back_light=flipped(self.back_light),
                                   sample_rotation_deg=-self.sample_rotation_deg + 0.0,
                                   sample_skew_deg=-self.sample_skew_deg + 0.0)

    def intensity(self, which: str) -> float:
        return self.front_intensity if which == "front" else self.back_intensity

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict) -> "CaptureRig":
        if not isinstance(data, dict):
            raise RigError("rig: expected a JSON object")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise RigError(f"rig: unknown setting(s) {listed(unknown)}; known: {', '.join(sorted(known))}")
        return cls(**data)

    @classmethod
    def load(cls, path: str | Path) -> "CaptureRig":
        data = read_json(path, RigError)
        try:
            return cls.from_dict(data)
        except RigError as exc:
            raise RigError(f"{path}: {exc}") from None


DEFAULT_RIG = CaptureRig()
