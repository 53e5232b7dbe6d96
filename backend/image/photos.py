"""Photo input for the fit: a reflection/transmission photo pair in, two working images out.

Turns a reflection photo (front light, ``_R``) and a transmission photo (back light, ``_T``) into
*working images*: what the renderer outputs (spec section 1), so that photos and renders compare
directly. :func:`load_pair` is what the product calls; :func:`load_photo` makes one working image
the same way (the tests use it to check each step on its own).

- Working image: ``(size, size, 3)`` float32 numpy array, RGB, values in [0, 1], encoded with the
  renders' transfer curve ``value = linear ** (1 / 2.2)`` (the renders clamp radiance at 1 first);
  see :mod:`.tone`. Decoding, orientation and formats: :mod:`.decode`, :mod:`.containers`.
- Crop: a square; the centred largest square by default, or an explicit box ``(x, y, w, h)`` with
  ``w == h``, in pixels of the upright image (:func:`crop_box`). A crop under half the working size
  is refused, a smaller one than the working size upscaled with a warning (:func:`check_crop_size`).
  Resampling to the working size happens in linear light.
- Exposure of linear sources (EXR, float TIFF, camera RAW): ``exposure=None`` (auto) scales linear
  values so that the 99th percentile of linear luminance over the crop becomes 0.5
  (:func:`.tone.auto_exposure`); in :func:`load_pair` one scale serves both photos, taken from the
  brighter one, so their relative brightness (the fabric's transmittance) survives. A number
  multiplies the linear values as is. Values are then clipped at 1. Encoded photos are not scaled.
- Pair checks (:mod:`.pair_checks`) run on the working images before the flat-field division
  (:mod:`.flat_field`): a framing problem raises :class:`PhotoError`, doubts about the order are
  warnings, or :class:`PhotoError` with ``strict=True``.
- Registration (:mod:`.registration`), last: where the two photos' lattices clearly differ by a
  magnification and turn (the phone moved between the shots), the photo showing more fabric is
  magnified onto the other's framing, with a warning that says so; ``info["registration"]``. The
  fit's re-renders are carried back into each photo's own framing to be written and compared
  (:meth:`PhotoPair.in_own_framing`, then :meth:`PhotoPair.as_compared`).

Errors are :class:`PhotoError` (a ``ValueError``, declared in :mod:`.errors`) whose message names the
file and the problem.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .decode import Box, SourceImage, read_image
from .errors import PhotoError
from .flat_field import flat_corrected
from .pair_checks import (
    check_content,
    check_framing_frequency,
    check_not_the_same,
    check_order,
    check_source_sizes,
    check_weave_shown,
    order_cues,
    order_score,
)
from .registration import Registration, register
from .tone import auto_exposure, encode, resize_linear, to_linear

__all__ = ["DEFAULT_SIZE", "Photo", "PhotoError", "PhotoPair", "check_crop_size", "crop_box", "load_pair",
           "load_photo"]

PathLike = str | os.PathLike
DEFAULT_SIZE = 512


@dataclass
class Photo:
    """One working image and how it was made."""

    image: np.ndarray
    path: Path
    format: str
    source_size: tuple[int, int]
    crop: Box
    exposure: float | None
    warnings: list[str]


@dataclass
class PhotoPair:
    """Both working images, the warnings raised while making them, and facts about them.

    ``info`` is JSON-friendly: ``reflection`` / ``transmission`` (path, format, source_size as
    [width, height], crop as [x, y, w, h], exposure: the linear scale applied, None for encoded
    photos), ``size``, ``order`` (the cues of :func:`.pair_checks.order_cues` for both images and
    the order score) and ``yarn_frequency`` (each image's spectral peaks as [fx, fy] in cycles per
    image, strongest first; ``mismatch``, see :func:`.pair_checks.frequency_mismatch`; ``scale``,
    the magnification of the transmission lattice that best aligns it with the reflection's; None
    where either image shows no clear yarn pattern or no weave above the noise) and
    ``weave_peakness`` (each image's sharpest spectral peak beside the level noise alone reaches:
    :func:`.pair_checks.check_weave_shown`).
    """

    reflection: np.ndarray
    transmission: np.ndarray
    warnings: list[str]
    info: dict
    registration: Registration | None = None
    taken: tuple[np.ndarray, np.ndarray] | None = None  # both working images before any registration

    def in_own_framing(self, renders: Sequence[np.ndarray]
                       ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """(the photos, the re-renders), each in its photo's own framing: a moved photo as it was
        taken, its re-render (made in the fit's framing, this pair's images) carried back
        (:meth:`.Registration.as_taken`). The re-renders are written, shown and compared so."""
        if self.registration is None:
            return (self.reflection, self.transmission), (renders[0], renders[1])
        moved = self.registration.moved == "reflection"
        carried = self.registration.as_taken(renders[0 if moved else 1])
        return self.taken, ((carried, renders[1]) if moved else (renders[0], carried))

    def as_compared(self, framed: tuple[Sequence[np.ndarray], Sequence[np.ndarray]]
                    ) -> list[tuple[np.ndarray, np.ndarray]]:
        """(photo, re-render) per image from ``framed`` (:meth:`in_own_framing`'s photos and re-renders),
        cropped to what the fit saw (:meth:`seen_boxes`: outside it a carried-back re-render is made up).

        Compared magnified instead, a moved photo flatters the comparison: the resampling (bilinear)
        takes off the fine grain and noise a re-render lacks."""
        photos, renders = framed

        def seen(image, box):
            x, y, w, h = box
            return image[y:y + h, x:x + w]

        return [(seen(photo, box), seen(render, box)) for photo, render, box in zip(photos, renders, self.seen_boxes())]

    def seen_boxes(self) -> tuple[Box, Box]:
        """Per photo, as taken, the part compared with its re-render (x, y, w, h; px): the whole photo,
        or for a moved one the centred square its registered image holds."""
        size = self.reflection.shape[0]
        boxes = [(0, 0, size, size), (0, 0, size, size)]
        if self.registration is not None:
            k = self.registration.seen_margin(size)
            boxes[self.registration.moved == "transmission"] = (k, k, size - 2 * k, size - 2 * k)
        return boxes[0], boxes[1]


def crop_box(image_size: tuple[int, int], crop: Sequence[int] | None, path: Path | str) -> Box:
    """The square box (x, y, w, h) to use: the centred largest square, or ``crop`` validated."""
    width, height = image_size
    if crop is None:
        side = min(width, height)
        return (width - side) // 2, (height - side) // 2, side, side
    try:
        x, y, w, h = (int(v) for v in crop)
        if any(int(v) != v for v in crop):
            raise ValueError
    except (TypeError, ValueError):
        raise PhotoError(f"{path}: crop box must be four whole numbers (x, y, w, h), got {crop!r}") from None
    if w <= 0 or h <= 0:
        raise PhotoError(f"{path}: crop box {(x, y, w, h)} has no area")
    if w != h:
        raise PhotoError(f"{path}: crop box {(x, y, w, h)} is not square ({w} x {h}); the working image is square")
    if x < 0 or y < 0 or x + w > width or y + h > height:
        raise PhotoError(f"{path}: crop box {(x, y, w, h)} lies outside the {width} x {height} image")
    return x, y, w, h


def check_crop_size(box: Box, size: int, path: Path | str) -> list[str]:
    """Refuses crops under half the working size; warns about (and allows) upscaling."""
    side = box[2]
    if side < size / 2:
        raise PhotoError(f"{path}: image too small: the square crop is {side} x {side} pixels, at least "
                         f"{math.ceil(size / 2)} are needed for a {size} x {size} working image")
    if side < size:
        return [f"{path}: the square crop is only {side} x {side} pixels; upscaled to {size} x {size}, "
                "fine yarn detail will be soft"]
    return []


def _check_size_arg(size: int) -> int:
    if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or size < 8:
        raise PhotoError(f"working size must be an integer of at least 8, got {size!r}")
    return int(size)


def _check_exposure(exposure: float | None) -> float | None:
    if exposure is not None and not (isinstance(exposure, (int, float)) and math.isfinite(exposure) and exposure > 0):
        raise PhotoError(f"exposure must be a positive number (a multiplier on linear values), got {exposure!r}")
    return exposure


def _working_image(source: SourceImage, box: Box, size: int, scale: float | None) -> np.ndarray:
    """Crop, to linear light, times ``scale`` and clipped at 1 (linear sources), resize, encode."""
    linear = to_linear(source.crop(box), source.linear)
    if source.linear:
        linear = np.minimum(linear * np.float32(scale), 1.0)
    return encode(resize_linear(linear, size)).astype(np.float32)


def _linear_scales(sources: Sequence[SourceImage], box: Box,
                   exposure: float | None) -> tuple[list[float | None], list[str]]:
    """The scale of each source's linear values (None for an encoded photo) and a note, if any.

    ``exposure`` when given; else one :func:`.tone.auto_exposure` from all the linear sources together,
    so that a linear pair keeps its relative brightness.
    """
    linear = [s for s in sources if s.linear]
    notes = []
    if exposure is None and linear:
        exposure = auto_exposure(*(to_linear(s.crop(box), s.linear) for s in linear))
        if len(linear) < len(sources):
            notes.append(f"{linear[0].path}: a linear source paired with an encoded photo: exposed on its own, so "
                         "the relative brightness of the two photos is not preserved")
    return [exposure if s.linear else None for s in sources], notes


def load_photo(path: PathLike, size: int = DEFAULT_SIZE, crop: Sequence[int] | None = None,
               flat_field: PathLike | None = None, exposure: float | None = None) -> Photo:
    """Reads one photo into a working image (see the module docstring for every convention)."""
    size, exposure = _check_size_arg(size), _check_exposure(exposure)
    source = read_image(path)
    box = crop_box(source.size, crop, source.path)
    warnings = check_crop_size(box, size, source.path)
    [scale], _ = _linear_scales([source], box, exposure)
    image = flat_corrected(_working_image(source, box, size, scale), flat_field, source, box, size, warnings)
    return Photo(image, source.path, source.format, source.size, box, scale, warnings)


def _flat_paths(flat_field) -> tuple[PathLike | None, PathLike | None]:
    """``load_pair``'s ``flat_field`` argument as (reflection, transmission) paths."""
    if flat_field is None or isinstance(flat_field, (str, os.PathLike)):
        return flat_field, flat_field
    try:
        reflection_flat, transmission_flat = flat_field
    except (TypeError, ValueError):
        raise PhotoError(f"flat_field must be a path or a (reflection, transmission) pair of paths, got "
                         f"{flat_field!r}") from None
    return reflection_flat, transmission_flat


def load_pair(reflection_path: PathLike, transmission_path: PathLike, size: int = DEFAULT_SIZE,
              crop: Sequence[int] | None = None, flat_field=None, strict: bool = False,
              exposure: float | None = None, workers: int = 1) -> PhotoPair:
    """Reads, checks and prepares a reflection/transmission photo pair (the two photos' spectra on up to
    ``workers`` threads).

    ``crop`` applies to both photos (same camera, same stand). ``flat_field`` is one path for both,
    or a (reflection, transmission) pair of paths. Framing problems raise :class:`PhotoError`;
    doubts about the order are warnings, or :class:`PhotoError` when ``strict``.
    """
    size, exposure = _check_size_arg(size), _check_exposure(exposure)
    reflection, transmission = read_image(reflection_path), read_image(transmission_path)
    label = f"{reflection.path} / {transmission.path}"
    check_not_the_same(reflection.pixels, transmission.pixels, label)
    check_source_sizes(reflection.size, transmission.size, label)
    box = crop_box(reflection.size, crop, label)
    warnings = check_crop_size(box, size, label)
    (scale_r, scale_t), notes = _linear_scales([reflection, transmission], box, exposure)
    warnings += notes
    image_r = _working_image(reflection, box, size, scale_r)
    image_t = _working_image(transmission, box, size, scale_t)
    check_content(image_r, reflection.path)
    check_content(image_t, transmission.path)

    weave_warnings, weave_info = check_weave_shown(image_r, image_t, (reflection.path, transmission.path), workers)
    frequency_warnings, frequency_info = check_framing_frequency(image_r, image_t, (reflection.path, transmission.path),
                                                                 compare=not weave_warnings)
    warnings += frequency_warnings + weave_warnings
    cues_r, cues_t = order_cues(image_r), order_cues(image_t)
    reasons = check_order(cues_r, cues_t)
    if reasons:
        message = (f"{label}: the photos may be swapped (reflection = front light, transmission = back light): "
                   + "; ".join(reasons))
        if strict:
            raise PhotoError(message)
        warnings.append(message)

    flat_r, flat_t = _flat_paths(flat_field)
    image_r = flat_corrected(image_r, flat_r, reflection, box, size, warnings)
    image_t = flat_corrected(image_t, flat_t, transmission, box, size, warnings)
    taken = (image_r, image_t)
    image_r, image_t, registration = register(image_r, image_t, frequency_info["scale"], workers)
    if registration is not None:
        m = registration.magnification
        warnings.append(f"{label}: the photos are framed differently (the transmission photo's yarn lattice is the "
                        f"reflection's turned {registration.turn_deg:+.2f} degrees and magnified "
                        f"{registration.scale:.3f}x, {registration.matches} "
                        f"matching peaks): the {registration.moved} photo was magnified {m:.3f}x about its centre "
                        f"to match (the fit sees the central {1 / m:.0%} of its width)")

    def describe(source: SourceImage, scale):
        return {"path": str(source.path), "format": source.format, "source_size": list(source.size),
                "crop": list(box), "exposure": scale}

    info = {"reflection": describe(reflection, scale_r), "transmission": describe(transmission, scale_t),
            "size": size,
            "order": {"reflection": cues_r, "transmission": cues_t, "score": order_score(cues_r, cues_t)},
            "yarn_frequency": frequency_info, "weave_peakness": weave_info,
            "registration": None if registration is None else registration.to_dict()}
    return PhotoPair(image_r, image_t, warnings, info, registration, taken)
