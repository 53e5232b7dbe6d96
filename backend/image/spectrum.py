"""The one windowed power spectrum of the image code: high-pass, Hann window, centred |FFT|^2.

For an (H, W, 3) image, with ``y`` its luminance (:func:`.tone.luminance`, Rec. 709 weights):

    highpass(y, sigma)  = y - G_sigma * y        (Gaussian blur of sigma pixels, OpenCV's default
                                                  border: reflected without repeating the edge)
    hann(H, W)          = outer(hanning(H), hanning(W))
    highpassed_luminance = highpass(y, sigma)                   (float64)
    windowed_highpass   = highpassed_luminance * hann(H, W)
    power_spectrum(z)   = |fftshift(fft2(z))|^2                (DC at (H // 2, W // 2))

The high-pass removes the lighting gradient, glow and vignetting (everything much slower than
1 / (2 pi sigma) cycles per pixel); the window keeps the image's edges from leaking a cross of
power through the spectrum. The spectrum metric (:mod:`.metrics`), the yarn peaks of the pair checks
(:mod:`.pair_checks`) and the camera blur (:mod:`.camera_blur`) take their spectra from here;
``windowed_highpass(image, N / 64)`` is, bit for bit, the input of the fit's yarn lattice
(``texture/lattice.py``) and of the sharp spectral peaks (:func:`peakness`, :func:`spectral_peaks`)
that the lattice and the pair's registration (:mod:`.registration`) read.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .tone import luminance


def highpass(y: np.ndarray, sigma: float) -> np.ndarray:
    """``y`` minus its Gaussian blur of ``sigma`` pixels (OpenCV's default border), in y's dtype."""
    return y - cv2.GaussianBlur(y, (0, 0), sigma)


def hann(height: int, width: int) -> np.ndarray:
    """The separable 2D Hann window, float64."""
    return np.outer(np.hanning(height), np.hanning(width))


def highpassed_luminance(image: np.ndarray, sigma: float) -> np.ndarray:
    """The high-passed luminance of an (H, W, 3) image, float64."""
    return highpass(luminance(np.asarray(image, np.float64)), sigma)


def windowed_highpass(image: np.ndarray, sigma: float) -> np.ndarray:
    """The high-passed luminance of an (H, W, 3) image, Hann-windowed, float64."""
    y = highpassed_luminance(image, sigma)
    return y * hann(*y.shape)


def power_spectrum(windowed: np.ndarray) -> np.ndarray:
    """``|fftshift(fft2(windowed))|^2``: the power at each frequency, DC at the centre."""
    return np.abs(np.fft.fftshift(np.fft.fft2(windowed))) ** 2


def peakness(image: np.ndarray, pad: int = 2, blur: float = 1.0) -> np.ndarray:
    """log power minus its local background (clipped at 0), on a pad-times zero-padded FFT grid,
    blurred by ``blur`` original bins so a lattice grid of finite step cannot step over a peak."""
    y = windowed_highpass(image, image.shape[0] / 64)
    h, w = y.shape
    spectrum = np.abs(np.fft.fft2(y, s=(h * pad, w * pad))) ** 2
    logp = np.log(np.fft.fftshift(spectrum) + 1e-12)
    # float32: OpenCV's wide blur is several times faster on it, within 1e-6 of float64
    background = cv2.GaussianBlur(logp.astype(np.float32), (0, 0), 6 * pad)
    excess = np.clip(logp - background, 0.0, None)
    return cv2.GaussianBlur(excess, (0, 0), blur * pad) if blur > 0 else excess


@dataclass(frozen=True)
class Peak:
    fx: float        # cycles per image, to the right
    fy: float        # cycles per image, down the image
    strength: float  # peakness (log power above the local background)


PEAK_PAD = 4          # zero-padding of the peaks' FFT: a quarter-bin grid before the sub-bin fit
PEAK_THRESHOLD = 2.5  # peakness a local maximum needs to count as a peak at all


def spectral_peaks(image: np.ndarray, count: int = 24) -> list[Peak]:
    """The ``count`` strongest isolated spectral peaks (half plane), with sub-bin positions."""
    pad, threshold = PEAK_PAD, PEAK_THRESHOLD
    q = peakness(image, pad=pad, blur=0.0).astype(np.float32)
    size = image.shape[0]
    local_max = q >= cv2.dilate(q, np.ones((2 * pad + 1, 2 * pad + 1), np.uint8))
    cy, cx = q.shape[0] // 2, q.shape[1] // 2
    rows, cols = np.nonzero(local_max & (q > threshold))
    peaks = []
    for r, c in zip(rows, cols):
        fx, fy = (c - cx) / pad, (r - cy) / pad
        inside = 0 < r < q.shape[0] - 1 and 0 < c < q.shape[1] - 1
        if fy < 0 or (fy == 0 and fx <= 0) or math.hypot(fx, fy) < 4 or not inside:
            continue
        # Parabolic interpolation of the log-power excess along each axis.
        dx = _vertex_offset(q[r, c - 1], q[r, c], q[r, c + 1])
        dy = _vertex_offset(q[r - 1, c], q[r, c], q[r + 1, c])
        peaks.append(Peak(fx + dx / pad, fy + dy / pad, float(q[r, c])))
    peaks.sort(key=lambda p: -p.strength)
    return [p for p in peaks if abs(p.fx) < size / 2 - 1 and p.fy < size / 2 - 1][:count]


EULER_GAMMA = 0.5772156649015329
NOISE_FALSE_ALARM = 1e-6  # the chance that a photo of noise alone shows a peak above chance_peakness


def chance_peakness(size: int) -> float:
    """The peakness that the strongest bin of a spectrum of noise alone (a ``size`` x ``size`` image)
    exceeds with probability :data:`NOISE_FALSE_ALARM`.

    Where the image holds only noise, the power of a bin is its local mean times E, E ~ Exp(1) (a
    chi-square of 2 degrees of freedom, halved), and the mean of log E is -gamma (Euler's constant),
    so the peakness (:func:`peakness`: log power minus the local mean of log power) of a bin is
    ln E + gamma. Over the n = size^2 / 2 independent bins of the half plane,

        P(max > s) = 1 - (1 - exp(-exp(s - gamma)))^n ~ n exp(-exp(s - gamma)),

    so s = gamma + ln ln(n / NOISE_FALSE_ALARM): 3.82 at 512 px, 3.92 at 2048. A phone's noise is not
    white (JPEG, demosaicing), so the level was checked on photos: those that show their weave stand
    above it, dense weaves lost behind a phone's blur below it."""
    bins = size * size / 2
    return EULER_GAMMA + math.log(math.log(bins / NOISE_FALSE_ALARM))


def shows_weave(peaks: list[Peak], size: int) -> bool:
    """Whether the strongest of an image's :func:`spectral_peaks` stands above what noise alone
    shows (:func:`chance_peakness`): a periodic pattern, the weave's as far as the photo goes."""
    return bool(peaks) and peaks[0].strength > chance_peakness(size)


def _vertex_offset(left: float, centre: float, right: float) -> float:
    """Offset of the vertex of the parabola through three equally spaced samples (0 unless it is a maximum)."""
    curvature = left - 2 * centre + right
    return 0.5 * (left - right) / max(curvature, -1e9) if curvature < 0 else 0.0
