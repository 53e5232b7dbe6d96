"""How soft a photo is, from the spectrum of its noise: the camera's blur before any fit.

A render's Monte Carlo noise and the golden images' are white: the median power of the high-passed
luminance in rings of frequency f is flat. A phone photo's irregularities (sensor noise, fuzz, yarn
unevenness) pass through the lens, the demosaicing and the resize, so its ring medians fall off as
the square of the camera's transfer function, for a Gaussian point spread of sigma pixels

    P(f) = P0 exp(-4 pi^2 sigma^2 f^2)        (f in cycles per pixel).

The median of a ring ignores the few bins of the yarn lattice's peaks, so the lattice does not
count. sigma comes from a least-squares line through log P against f^2 over 0.1 to 0.5 cycles per
pixel. It is model-free, which is the point: the fit's loss also rewards blur wherever the render's
yarns disagree with the photo's (a softer render hides the disagreement), so the loss alone cannot
tell a soft camera from a wrong parameter; this estimate can, and decides whether the fit may
estimate a blur at all (:data:`SOFT_PHOTO_PX`) and its lower bound.
"""
from __future__ import annotations

import math

import numpy as np

LUMA = np.array([0.2126, 0.7152, 0.0722])
RING_EDGES = np.arange(0.10, 0.501, 0.05)  # cycles per pixel
SOFT_PHOTO_PX = 0.3  # below this the photos are as sharp as a render (golden pairs: 0.2 at most)


def noise_blur_px(image: np.ndarray, gamma: float = 2.2) -> float:
    """sigma in pixels of ``image`` ((N, N, 3) display values in [0, 1]) from its ring medians."""
    image = np.asarray(image, dtype=np.float64)
    lum = np.clip(image, 0.0, 1.0) ** gamma @ LUMA
    n = lum.shape[0]
    # High-pass: remove the lighting (a 9 x 9 box mean is enough at these frequencies).
    kernel = np.ones(9) / 9.0
    smooth = np.apply_along_axis(lambda r: np.convolve(np.pad(r, 4, mode="reflect"), kernel, "valid"), 1, lum)
    smooth = np.apply_along_axis(lambda c: np.convolve(np.pad(c, 4, mode="reflect"), kernel, "valid"), 0, smooth)
    detail = (lum - smooth) * np.outer(np.hanning(n), np.hanning(lum.shape[1]))
    power = np.abs(np.fft.fftshift(np.fft.fft2(detail))) ** 2
    fy = np.fft.fftshift(np.fft.fftfreq(n))[:, None]
    fx = np.fft.fftshift(np.fft.fftfreq(lum.shape[1]))[None, :]
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
