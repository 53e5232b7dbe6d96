"""Flat-field correction: dividing out the lens's vignetting, measured on a photo of a uniform target.

The flat-field is a photo of a uniform target with the same camera and framing as the photo (same
pixel size, else :class:`PhotoError`). It is cropped like the photo, taken to linear light
(:func:`.tone.to_linear`), resized to the working size, smoothed (Gaussian, sigma = size / 32, at
least 0.5 px, mirrored borders) so that its noise and texture do not print into the photo,
normalised to a maximum of 1 per channel and floored at 0.05 (with a warning where it is lower):

    gain = max(G * flat / max(G * flat), 0.05)        corrected = encode(linear(photo) / gain)

The division happens in linear light and the result is clipped at 1 (:func:`.tone.encode`).
Whatever the target shows is divided out: shot under the rig's own lamp that includes the lamp's
falloff, which the renderer models, so shoot it under even light to remove only the lens vignetting.
"""
from __future__ import annotations

import os

import cv2
import numpy as np

from .decode import Box, SourceImage, read_image
from .errors import PhotoError
from .tone import GAMMA, encode, resize_linear, to_linear

FLAT_FIELD_SMOOTHING = 1 / 32  # sigma of the smoothing, in working-image sizes
FLAT_FIELD_FLOOR = 0.05        # gain floor: a near-black corner of the target would multiply noise


def flat_field_gain(flat: SourceImage, box: Box, size: int) -> tuple[np.ndarray, list[str]]:
    """Smoothed, max-normalised (per channel) and floored linear flat-field at the working size."""
    linear = resize_linear(to_linear(flat.crop(box), flat.linear), size)
    sigma = max(size * FLAT_FIELD_SMOOTHING, 0.5)
    smooth = cv2.GaussianBlur(linear, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    peak = smooth.reshape(-1, 3).max(axis=0)
    if not np.all(peak > 1e-6):
        raise PhotoError(f"{flat.path}: the flat-field image is black in at least one colour channel")
    gain = smooth / peak
    low = gain < FLAT_FIELD_FLOOR
    warnings = []
    if low.any():
        warnings.append(f"{flat.path}: the flat-field falls below {FLAT_FIELD_FLOOR:.0%} of its maximum on "
                        f"{low.any(axis=2).mean():.1%} of the image; corrected there as if at {FLAT_FIELD_FLOOR:.0%}")
    return np.maximum(gain, FLAT_FIELD_FLOOR), warnings


def apply_flat_field(image: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """Divides an encoded working image by a linear gain, in linear light."""
    return encode((image ** np.float32(GAMMA)) / gain).astype(np.float32)


def flat_corrected(image: np.ndarray, flat_path: str | os.PathLike | None, photo: SourceImage, box: Box, size: int,
                   warnings: list[str]) -> np.ndarray:
    """The working image of ``photo`` divided by the flat-field at ``flat_path`` (unchanged when None).

    The flat-field's warnings are appended to ``warnings``, each once (a pair may share one flat-field).
    """
    if flat_path is None:
        return image
    flat = read_image(flat_path)
    if flat.size != photo.size:
        raise PhotoError(f"{flat.path}: the flat-field is {flat.size[0]} x {flat.size[1]} pixels but the photo "
                         f"{photo.path} is {photo.size[0]} x {photo.size[1]}; take both with the same camera framing")
    gain, flat_warnings = flat_field_gain(flat, box, size)
    warnings += [w for w in flat_warnings if w not in warnings]
    return apply_flat_field(image, gain)
