"""Tone: from stored pixel values to linear light and back to the renders' encoding.

- Encoding: the renders' transfer curve, ``value = clip(linear, 0, 1) ** (1 / GAMMA)`` with
  ``GAMMA = 2.2`` (:func:`encode`). 8/16-bit PNG, JPEG and TIFF photos are taken as already encoded
  (a phone's sRGB output is close to this curve): :func:`to_linear` scales them to [0, 1] and raises
  them to 2.2. Linear sources (OpenEXR, float TIFF, camera RAW) are linear already; floats lose
  NaNs, infinities and negatives.
- Luminance: the one definition in ``image/``, Rec. 709 weights
  :data:`LUMA` = (0.2126, 0.7152, 0.0722) (:func:`luminance`).
- Auto exposure (:func:`auto_exposure`): the scale that puts the 99th percentile of linear luminance
  of the brightest of the given regions at 0.5 (0.73 encoded, a level typical of the rig's renders
  and photos, with headroom for highlights). Given both photos of a pair, one scale serves both, so
  their relative brightness (the fabric's transmittance) survives.
- Resampling (:func:`resize_linear`) happens in linear light, as the renderer averages its pixel
  samples in radiance: area interpolation when shrinking, bilinear when enlarging.
"""
from __future__ import annotations

import cv2
import numpy as np

GAMMA = 2.2
LUMA = (0.2126, 0.7152, 0.0722)  # Rec. 709 luminance weights of linear RGB

AUTO_EXPOSURE_PERCENTILE = 99.0  # the bright end of a photo, short of its few clipped highlights
AUTO_EXPOSURE_LEVEL = 0.5        # where that percentile goes: the renders' level, with headroom


def luminance(rgb: np.ndarray) -> np.ndarray:
    """``rgb @ LUMA`` over the last axis, in the array's float type (float32 stays float32)."""
    rgb = np.asarray(rgb)
    dtype = rgb.dtype if rgb.dtype.kind == "f" else np.dtype(np.float64)
    return rgb.astype(dtype, copy=False) @ np.asarray(LUMA, dtype=dtype)


def to_linear(region: np.ndarray, linear: bool) -> np.ndarray:
    """Float32 linear values. Integers are scaled to [0, 1] first, and raised to 2.2 unless linear;
    floats (always linear) lose NaNs, infinities and negatives."""
    if region.dtype.kind == "f":
        return np.nan_to_num(region.astype(np.float32), nan=0.0, posinf=1e6, neginf=0.0).clip(0.0, None)
    values = region.astype(np.float32) / np.float32(255.0 if region.dtype == np.uint8 else 65535.0)
    return values if linear else values ** np.float32(GAMMA)


def encode(linear: np.ndarray) -> np.ndarray:
    """The renders' output curve: clamp at 1, then the 1/2.2 power."""
    return np.clip(linear, 0.0, 1.0) ** np.float32(1 / GAMMA)


def auto_exposure(*linear_regions: np.ndarray) -> float:
    """Scale putting the 99th percentile of linear luminance of the brightest region at 0.5."""
    level = max(float(np.percentile(luminance(r), AUTO_EXPOSURE_PERCENTILE)) for r in linear_regions)
    return AUTO_EXPOSURE_LEVEL / level if level > 0 else 1.0


def resize_linear(linear: np.ndarray, size: int) -> np.ndarray:
    """A linear image resized to ``size`` x ``size``: area interpolation when shrinking, bilinear when
    enlarging (both average with non-negative weights, so nothing goes below 0)."""
    if linear.shape[:2] == (size, size):
        return linear
    shrink = linear.shape[0] > size
    return cv2.resize(linear, (size, size), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
