"""The one windowed power spectrum of the image code: high-pass, Hann window, centred |FFT|^2.

For an (H, W, 3) image, with ``y`` its luminance (:func:`.tone.luminance`, Rec. 709 weights):

    highpass(y, sigma)  = y - G_sigma * y        (Gaussian blur of sigma pixels, OpenCV's default
                                                  border: reflected without repeating the edge)
    hann(H, W)          = outer(hanning(H), hanning(W))
    windowed_highpass   = highpass(y, sigma) * hann(H, W)      (float64)
    power_spectrum(z)   = |fftshift(fft2(z))|^2                (DC at (H // 2, W // 2))

The high-pass removes the lighting gradient, glow and vignetting (everything much slower than
1 / (2 pi sigma) cycles per pixel); the window keeps the image's edges from leaking a cross of
power through the spectrum. The spectrum metric (:mod:`.metrics`), the yarn peaks of the pair checks
(:mod:`.pair_checks`) and the camera blur (:mod:`.camera_blur`) take their spectra from here;
``windowed_highpass(image, N / 64)`` is, bit for bit, the input of the fit's yarn lattice
(``texture/lattice.py``).
"""
from __future__ import annotations

import cv2
import numpy as np

from .tone import luminance


def highpass(y: np.ndarray, sigma: float) -> np.ndarray:
    """``y`` minus its Gaussian blur of ``sigma`` pixels (OpenCV's default border), in y's dtype."""
    return y - cv2.GaussianBlur(y, (0, 0), sigma)


def hann(height: int, width: int) -> np.ndarray:
    """The separable 2D Hann window, float64."""
    return np.outer(np.hanning(height), np.hanning(width))


def windowed_highpass(image: np.ndarray, sigma: float) -> np.ndarray:
    """The high-passed luminance of an (H, W, 3) image, Hann-windowed, float64."""
    y = luminance(np.asarray(image, np.float64))
    return highpass(y, sigma) * hann(*y.shape)


def power_spectrum(windowed: np.ndarray) -> np.ndarray:
    """``|fftshift(fft2(windowed))|^2``: the power at each frequency, DC at the centre."""
    return np.abs(np.fft.fftshift(np.fft.fft2(windowed))) ** 2
