"""How soft a photo is, from the spectrum of its noise: the camera's blur before any fit.

A render's Monte Carlo noise and the golden images' are white: the median power of the high-passed
luminance in rings of frequency f is flat. A phone photo's irregularities (sensor noise, fuzz, yarn
unevenness) pass through the lens, the demosaicing and the resize, so its ring medians fall off as
the square of the camera's transfer function, for a Gaussian point spread of sigma pixels

    P(f) = P0 exp(-4 pi^2 sigma^2 f^2)        (f in cycles per pixel).

The median of a ring ignores the few bins of the yarn lattice's peaks, so the lattice does not
count. sigma comes from a least-squares line through log P against f^2 over 0.1 to 0.5 cycles per
pixel. The spectrum is that of :func:`.spectrum.windowed_highpass` of the linear image (display
values raised to 2.2) with a high-pass of :data:`HIGHPASS_PX` = 4 px: it removes the lighting
(below about 0.04 cycles per pixel) and passes (1 - exp(-2 pi^2 sigma_h^2 f^2))^2 of the power,
92 % at 0.10 cycles per pixel and 98.6 % at the first ring's centre, so that it barely bends the
line (3 px would keep only 69 % and 88 % there and read the real photos about 0.01 px sharper;
4 and 5 px agree within 0.002 px on them).

The estimate is model-free, which is the point: the fit's loss also rewards blur wherever the render's
yarns disagree with the photo's (a softer render hides the disagreement), so the loss alone cannot
tell a soft camera from a wrong parameter; this estimate can, and decides whether the fit may
estimate a blur at all (:data:`SOFT_PHOTO_PX`) and its lower bound.
"""
from __future__ import annotations

import math

import numpy as np

from .spectrum import power_spectrum, windowed_highpass
from .tone import GAMMA

RING_EDGES = np.arange(0.10, 0.501, 0.05)  # cycles per pixel
HIGHPASS_PX = 4.0  # the high-pass's Gaussian sigma in pixels (module docstring)
SOFT_PHOTO_PX = 0.3  # below: as sharp as a render (golden pairs 0.12 at most, the real pairs 0.49 or more)


def noise_blur_px(image: np.ndarray, gamma: float = GAMMA) -> float:
    """sigma in pixels of ``image`` ((N, N, 3) display values in [0, 1]) from its ring medians."""
    linear = np.clip(np.asarray(image, dtype=np.float64), 0.0, 1.0) ** gamma
    power = power_spectrum(windowed_highpass(linear, HIGHPASS_PX))
    fy = np.fft.fftshift(np.fft.fftfreq(power.shape[0]))[:, None]
    fx = np.fft.fftshift(np.fft.fftfreq(power.shape[1]))[None, :]
    radius = np.hypot(fx, fy)
    centres, medians = [], []
    for lo, hi in zip(RING_EDGES[:-1], RING_EDGES[1:]):
        ring = power[(radius >= lo) & (radius < hi)]
        if ring.size and np.median(ring) > 0:
            centres.append(0.5 * (lo + hi))
            medians.append(np.median(ring))
    if len(centres) < 3:
        return 0.0
    f2 = np.asarray(centres) ** 2
    slope = np.polyfit(f2, np.log(medians), 1)[0]  # = -4 pi^2 sigma^2
    return float(math.sqrt(max(-slope, 0.0)) / (2.0 * math.pi))


def photo_blur_px(reflection: np.ndarray, transmission: np.ndarray, film_size: int) -> float:
    """The pair's blur in film pixels: the mean of both photos' estimates, scaled from their size."""
    scale = film_size / reflection.shape[0]
    return scale * 0.5 * (noise_blur_px(reflection) + noise_blur_px(transmission))
