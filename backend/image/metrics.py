"""How well a re-render matches a photo (display-space float RGB arrays in [0, 1], same shape).

- ``flip``: mean LDR FLIP error (NVIDIA's perceptual difference; 0 = identical);
- ``colour_l1``: L1 between 16 x 16 area downsamples (colour and tone);
- ``spectrum_corr``: correlation of the smoothed log power spectra of the high-passed luminance
  (:func:`.spectrum.windowed_highpass` with sigma 16 px: Gaussian blur subtracted, Hann window;
  power blurred by sigma 1.5 bins, central half band, 5 x 5 DC neighbourhood dropped): yarn
  structure regardless of phase and lighting.

These follow the definitions of the team's checker (``shared/tools/imagemetrics.py``); a test
checks that both give the same numbers.
"""
from __future__ import annotations

import cv2
import flip_evaluator
import numpy as np

from .spectrum import power_spectrum, windowed_highpass

SPECTRUM_HIGHPASS_PX = 16     # sigma of the Gaussian subtracted before the FFT
SPECTRUM_POWER_BLUR = 1.5     # sigma of the blur of the power spectrum, in bins
SPECTRUM_KEEP = 0.5           # the central part of the band that is compared
SPECTRUM_DC_HALF = 2          # the (2 h + 1)^2 bins around DC that are dropped
COLOUR_GRID = 16              # side of the area downsample colour_l1 compares


def colour_l1(photo: np.ndarray, render: np.ndarray) -> float:
    """Mean |photo - render| of the two images' COLOUR_GRID x COLOUR_GRID area downsamples."""
    size = COLOUR_GRID
    a = cv2.resize(np.asarray(photo, np.float32), (size, size), interpolation=cv2.INTER_AREA)
    b = cv2.resize(np.asarray(render, np.float32), (size, size), interpolation=cv2.INTER_AREA)
    return float(np.abs(a - b).mean())


def _log_spectrum(image: np.ndarray) -> np.ndarray:
    """The log power of the central band of the high-passed luminance's blurred spectrum, DC dropped (NaN)."""
    power = cv2.GaussianBlur(power_spectrum(windowed_highpass(image, SPECTRUM_HIGHPASS_PX)), (0, 0),
                             SPECTRUM_POWER_BLUR)
    h, w = power.shape
    ch, cw = int(h * SPECTRUM_KEEP / 2), int(w * SPECTRUM_KEEP / 2)
    band = power[h // 2 - ch: h // 2 + ch, w // 2 - cw: w // 2 + cw].copy()
    d = SPECTRUM_DC_HALF  # the DC neighbourhood (lighting residue) is dropped, as the checker drops it
    band[ch - d: ch + d + 1, cw - d: cw + d + 1] = np.nan
    return np.log(band + 1e-12)


def spectrum_corr(photo: np.ndarray, render: np.ndarray) -> float:
    """Correlation of the two images' :func:`_log_spectrum` over the bins both hold."""
    a, b = _log_spectrum(photo), _log_spectrum(render)
    valid = np.isfinite(a) & np.isfinite(b)
    return float(np.corrcoef(a[valid], b[valid])[0, 1])


def flip(photo: np.ndarray, render: np.ndarray) -> float:
    """Mean LDR FLIP error of the render against the photo."""
    _, value, _ = flip_evaluator.evaluate(np.asarray(photo, np.float32), np.asarray(render, np.float32), "LDR")
    return float(value)


def compare(photo: np.ndarray, render: np.ndarray) -> dict[str, float]:
    """All three metrics for one photo/render pair."""
    if photo.shape != render.shape:
        raise ValueError(f"photo {photo.shape} and render {render.shape} differ in size")
    return {"flip": flip(photo, render), "colour_l1": colour_l1(photo, render),
            "spectrum_corr": spectrum_corr(photo, render)}
