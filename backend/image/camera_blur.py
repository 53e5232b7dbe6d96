"""How soft a photo pair is, from the spectrum of its noise: the camera's blur before any fit.

Two kinds of irregularity fill a photo's spectrum between the yarn lattice's peaks. What lies on
the fabric or happens before the lens (fuzz, yarn unevenness, a render's Monte Carlo noise) passes
through the camera's point spread; what the sensor and the phone add afterwards (shot and read
noise, most of the compression's residue) does not. For a Gaussian point spread of sigma pixels the
median power of the high-passed linear luminance in a ring of frequency f (cycles per pixel) is

    P(f) = H(f) (S exp(-4 pi^2 sigma^2 f^2) + N),   H(f) = (1 - exp(-2 pi^2 s_h^2 f^2))^2

with S the blurred part, N the white part after the optics and H what the high-pass of s_h =
:data:`HIGHPASS_PX` pixels leaves of both. The median of a ring ignores the few bins of the
lattice's peaks, so the lattice does not count. A real phone's processing removes most sensor noise
(N is small: the ring medians fall to the Nyquist band); a photo-like pair, or a raw one, keeps it
(P falls to a floor a decade below S at about f = 0.6 / (2 pi sigma), then stays flat). Fitting
N along with S is what lets one reading serve both: ignoring the floor, a soft pair with sensor noise
reads as far sharper than it is.

Both photos come through one camera, so the pair is fitted together: sigma on a grid of
:data:`SIGMA_STEP` px, S and N per photo by non-negative least squares of the relative error, the
misfit measured on log P over the rings :data:`RING_EDGES` (0.1 to 0.5 cycles per pixel: below, the
lighting's own spectrum leaks through the high-pass). A render or a golden image is white noise on
a lattice: sigma = 0 (S and N then collinear, one flat level) fits it about as well as any other
sigma, while a soft photo's fall is fitted far better by its own. So the pair reads as blurred only
where the best sigma's misfit is :data:`MIN_GAIN` times smaller than the flat one's, or where one
photo on its own does (:func:`pair_blur`); otherwise 0. Renders stay well under that gain, blurred
photos well over it (``tests/test_camera_blur.py``). A render whose black gaps have hard edges (no
glow behind them) has a falling spectrum of its own and can read soft.

The estimate is model-free, which is the point: the fit's loss also rewards blur wherever the render's
yarns disagree with the photo's (a softer render hides the disagreement), so the loss alone cannot
tell a soft camera from a wrong parameter; this estimate can, and decides whether the fit may
estimate a blur at all (:data:`SOFT_PHOTO_PX`) and its lower bound.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .spectrum import power_spectrum, windowed_highpass
from .tone import GAMMA

RING_EDGES = np.arange(0.10, 0.5001, 0.025)  # cycles per pixel
HIGHPASS_PX = 4.0      # the high-pass's Gaussian sigma in pixels
SIGMA_STEP = 0.02      # px, the grid of the fitted sigma
MAX_SIGMA_PX = 3.0     # px of the photos read: past it the blurred part is gone by the first ring
MIN_GAIN = 5.0         # misfit of the flat spectrum / misfit of the best sigma, to read a blur at all
SOFT_PHOTO_PX = 0.3    # below: as sharp as a render


@dataclass(frozen=True)
class BlurReading:
    """The pair's fitted ``sigma_px`` (photo pixels) and ``gain``: how much better than a flat
    spectrum it explains the ring medians (``blurred`` when at least MIN_GAIN)."""

    sigma_px: float
    gain: float

    @property
    def blurred(self) -> bool:
        return self.gain >= MIN_GAIN


def ring_medians(image: np.ndarray, gamma: float = GAMMA) -> tuple[np.ndarray, np.ndarray]:
    """(ring centres in cycles per pixel, median power in each ring) of ``image``'s high-passed
    linear luminance ((N, N, 3) display values in [0, 1]); empty or powerless rings are left out."""
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
    return np.asarray(centres), np.asarray(medians)


def _highpass_gain(f: np.ndarray) -> np.ndarray:
    return (1.0 - np.exp(-2.0 * math.pi ** 2 * HIGHPASS_PX ** 2 * f ** 2)) ** 2


def _nonnegative_lstsq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin |a x - b| over x >= 0 for two unknowns: the free solution if it is non-negative,
    else the better one-unknown solution."""
    candidates = []
    free = np.linalg.lstsq(a, b, rcond=None)[0]
    if (free >= 0).all():
        candidates.append(free)
    for j in range(a.shape[1]):
        x = np.zeros(a.shape[1])
        x[j] = max(0.0, float(a[:, j] @ b) / float(a[:, j] @ a[:, j]))
        candidates.append(x)
    return min(candidates, key=lambda x: float(np.sum((a @ x - b) ** 2)))


def misfit(centres: np.ndarray, medians: np.ndarray, sigma: float) -> float:
    """Sum of squared log errors of the best P(f) (module docstring) with this ``sigma``."""
    highpass = _highpass_gain(centres)
    blurred = highpass * np.exp(-4.0 * math.pi ** 2 * sigma ** 2 * centres ** 2)
    basis = np.stack((blurred, highpass), axis=1) / medians[:, None]   # relative errors
    model = basis @ _nonnegative_lstsq(basis, np.ones_like(medians)) * medians
    return float(np.sum(np.log(np.maximum(model, 1e-300) / medians) ** 2))


def read_blur(*images: np.ndarray, gamma: float = GAMMA) -> BlurReading:
    """One sigma for photos taken through the same camera (the module docstring's fit)."""
    return _reading([ring_medians(image, gamma) for image in images])


def _reading(rings: list[tuple[np.ndarray, np.ndarray]]) -> BlurReading:
    """:func:`read_blur` of photos given by their :func:`ring_medians`."""
    rings = [(c, m) for c, m in rings if len(c) >= 3]
    if not rings:
        return BlurReading(0.0, 1.0)
    sigmas = np.arange(0.0, MAX_SIGMA_PX + 1e-9, SIGMA_STEP)
    misfits = np.array([sum(misfit(c, m, s) for c, m in rings) for s in sigmas])
    best = int(np.argmin(misfits))
    return BlurReading(float(sigmas[best]), float(misfits[0] / max(misfits[best], 1e-12)))


def pair_blur(reflection: np.ndarray, transmission: np.ndarray) -> BlurReading:
    """The pair's reading: both photos fitted together, or else the one photo that reads blurred.

    A photo whose sensor noise buries its blurred part has a flat spectrum, as a render's does, and
    says nothing of the blur; fitted together with the other photo it dilutes a fall that the other
    shows plainly. So where the pair does not read blurred, a photo that does on its own (the one with
    the larger gain) speaks for the camera; no single render reads blurred.
    """
    rings = [ring_medians(reflection), ring_medians(transmission)]  # each photo's spectrum read once
    reading = _reading(rings)
    if reading.blurred:
        return reading
    return max((_reading([one]) for one in rings), key=lambda r: r.gain)


def photo_blur_px(reflection: np.ndarray, transmission: np.ndarray, film_size: int) -> float:
    """The pair's blur in film pixels (:func:`pair_blur`, scaled from the photos' size); 0 where
    the pair does not show one."""
    reading = pair_blur(reflection, transmission)
    return film_size / reflection.shape[0] * reading.sigma_px if reading.blurred else 0.0
