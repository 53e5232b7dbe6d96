"""How well a re-render matches a photo (display-space float RGB arrays in [0, 1], same shape).

- ``flip``: mean LDR FLIP error (NVIDIA's perceptual difference; 0 = identical);
- ``colour_l1``: L1 between 16 x 16 area downsamples (colour and tone);
- ``spectrum_corr``: correlation of the smoothed log power spectra of the high-passed luminance
  (Gaussian blur of sigma 16 px subtracted, Hann window, power blurred by sigma 1.5 bins, central
  half band, 5 x 5 DC neighbourhood dropped): yarn structure regardless of phase and lighting.

These follow the definitions of the team's checker (``shared/tools/imagemetrics.py``); a test
checks that both give the same numbers.
"""
from __future__ import annotations

import numpy as np

LUMA = np.array([0.2126, 0.7152, 0.0722])


def colour_l1(photo: np.ndarray, render: np.ndarray, size: int = 16) -> float:
    import cv2

    a = cv2.resize(np.asarray(photo, np.float32), (size, size), interpolation=cv2.INTER_AREA)
    b = cv2.resize(np.asarray(render, np.float32), (size, size), interpolation=cv2.INTER_AREA)
    return float(np.abs(a - b).mean())


def _log_spectrum(image: np.ndarray, keep: float, blur: float) -> np.ndarray:
    import cv2

    y = np.asarray(image, np.float64) @ LUMA
    y = y - cv2.GaussianBlur(y, (0, 0), 16)
    y = y * np.outer(np.hanning(y.shape[0]), np.hanning(y.shape[1]))
    power = cv2.GaussianBlur(np.abs(np.fft.fftshift(np.fft.fft2(y))) ** 2, (0, 0), blur)
    h, w = power.shape
    ch, cw = int(h * keep / 2), int(w * keep / 2)
    band = power[h // 2 - ch: h // 2 + ch, w // 2 - cw: w // 2 + cw].copy()
    band[ch - 2: ch + 3, cw - 2: cw + 3] = np.nan
    return np.log(band + 1e-12)


def spectrum_corr(photo: np.ndarray, render: np.ndarray, keep: float = 0.5, blur: float = 1.5) -> float:
    a, b = _log_spectrum(photo, keep, blur), _log_spectrum(render, keep, blur)
    valid = np.isfinite(a) & np.isfinite(b)
    return float(np.corrcoef(a[valid], b[valid])[0, 1])


def flip(photo: np.ndarray, render: np.ndarray) -> float:
    import flip_evaluator

    _, value, _ = flip_evaluator.evaluate(np.asarray(photo, np.float32), np.asarray(render, np.float32), "LDR")
    return float(value)


def compare(photo: np.ndarray, render: np.ndarray) -> dict[str, float]:
    """All three metrics for one photo/render pair."""
    if photo.shape != render.shape:
        raise ValueError(f"photo {photo.shape} and render {render.shape} differ in size")
    return {"flip": flip(photo, render), "colour_l1": colour_l1(photo, render),
            "spectrum_corr": spectrum_corr(photo, render)}
