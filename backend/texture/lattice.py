"""Yarn density from the spectrum: the weave's reciprocal lattice in an image.

The camera looks straight down at a plane parallel to its film, so a woven fabric is an exactly
periodic texture in the image, modulated only by slowly varying lighting. With ``tiles = (tu, tv)``
repeats over the plane of side P, one tile spans P / tu scene units, and the visible square of side
V holds ``a = tu V / P`` tiles across and ``b = tv V / P`` down. The luminance spectrum therefore
concentrates on the lattice ``(m a, n b)`` cycles per image (integers m, n), folded back by aliasing
beyond Nyquist (f -> N - f for an N-pixel image) and attenuated by the pixel's box filter
(sinc^2 of f / N).

Which harmonics (m, n) carry the energy depends on the weave (and on the BSDF); a pattern's
*signature* is measured once from a render at a low density, where every significant harmonic is
below Nyquist. :func:`search` then scores candidate (a, b) on a log grid by the signature-weighted
spectral peakness of the image at the predicted (folded) positions, and :func:`refine` maximises the
exact Fourier power at the lattice harmonics over continuous (a, b). No rendering is needed to read
a photo's density; only the pattern signatures come from renders.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LUMA = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class Signature:
    """Relative power of the lattice harmonics (m, n) of a pattern; n >= 0 (half plane)."""

    m: np.ndarray
    n: np.ndarray
    weight: np.ndarray   # sums to 1


@dataclass(frozen=True)
class Lattice:
    a: float       # tiles across the image (cycles per image width)
    b: float       # tiles down the image
    score: float

    def tiles(self, view_size: float, plane_size: float) -> tuple[float, float]:
        return self.a * plane_size / view_size, self.b * plane_size / view_size


def _highpassed_luminance(image: np.ndarray) -> np.ndarray:
    import cv2

    y = np.asarray(image, dtype=np.float64) @ LUMA
    y = y - cv2.GaussianBlur(y, (0, 0), y.shape[0] / 64)
    window = np.outer(np.hanning(y.shape[0]), np.hanning(y.shape[1]))
    return y * window


def harmonic_spectrum(image: np.ndarray, a: float, b: float, m: np.ndarray, n: np.ndarray) -> np.ndarray:
    """|DFT|^2 of the windowed, high-passed luminance at the frequencies (m a, n b), cycles per image."""
    return _HarmonicProbe(image).power(a, b, m, n)


class _HarmonicProbe:
    """Exact DFT of one image at lattice frequencies; separable, so 1D scans over a or b are cheap."""

    def __init__(self, image: np.ndarray):
        self.y = _highpassed_luminance(image)
        self.h, self.w = self.y.shape

    def _ex(self, freqs):
        return np.exp(-2j * np.pi * np.outer(freqs, np.arange(self.w)) / self.w)

    def _ey(self, freqs):
        return np.exp(-2j * np.pi * np.outer(freqs, np.arange(self.h)) / self.h)

    def power(self, a, b, m, n):
        um, un = np.unique(m), np.unique(n)
        full = self._ey(un * b) @ self.y @ self._ex(um * a).T
        return np.abs(full[np.searchsorted(un, n), np.searchsorted(um, m)]) ** 2

    def scan_a(self, a_values, b, sig: "Signature") -> np.ndarray:
        """Signature-weighted power for each a (b fixed)."""
        un = np.unique(sig.n)
        rows = self._ey(un * b) @ self.y                                  # (N, w)
        ni = np.searchsorted(un, sig.n)
        out = []
        for a in a_values:
            values = np.einsum("kw,kw->k", rows[ni], self._ex(sig.m * a))
            out.append(float((sig.weight * np.abs(values) ** 2).sum()))
        return np.array(out)

    def scan_b(self, a, b_values, sig: "Signature") -> np.ndarray:
        """Signature-weighted power for each b (a fixed)."""
        um = np.unique(sig.m)
        cols = self.y @ self._ex(um * a).T                                # (h, M)
        mi = np.searchsorted(um, sig.m)
        out = []
        for b in b_values:
            values = np.einsum("hk,kh->k", cols[:, mi], self._ey(sig.n * b))
            out.append(float((sig.weight * np.abs(values) ** 2).sum()))
        return np.array(out)


def signature(image: np.ndarray, a: float, b: float, order: int = 6, keep: int = 24) -> Signature:
    """The strongest lattice harmonics of an image whose lattice (a, b) is known (unaliased)."""
    h, w = image.shape[:2]
    mm, nn = np.meshgrid(np.arange(-order, order + 1), np.arange(0, order + 1))
    mm, nn = mm.ravel(), nn.ravel()
    ok = ((nn > 0) | (mm > 0)) & (np.abs(mm) * a < w / 2) & (nn * b < h / 2)
    mm, nn = mm[ok], nn[ok]
    power = harmonic_spectrum(image, a, b, mm, nn)
    # Undo the render's own pixel box filter so the signature describes the tile, not the film.
    power = power / (np.sinc(mm * a / w) ** 2 * np.sinc(nn * b / h) ** 2)
    best = np.argsort(-power)[:keep]
    weight = power[best] / power[best].sum()
    return Signature(mm[best], nn[best], weight)


def peakness(image: np.ndarray, pad: int = 2, blur: float = 1.0) -> np.ndarray:
    """log power minus its local background (clipped at 0), on a pad-times zero-padded FFT grid,
    blurred by ``blur`` original bins so a lattice grid of finite step cannot step over a peak."""
    import cv2

    y = _highpassed_luminance(image)
    h, w = y.shape
    spectrum = np.abs(np.fft.fft2(y, s=(h * pad, w * pad))) ** 2
    logp = np.log(np.fft.fftshift(spectrum) + 1e-12)
    background = cv2.GaussianBlur(logp, (0, 0), 6 * pad)
    excess = np.clip(logp - background, 0.0, None)
    return cv2.GaussianBlur(excess, (0, 0), blur * pad) if blur > 0 else excess


def _fold(f: np.ndarray, size: int) -> np.ndarray:
    """Frequency (cycles per image) after sampling with `size` pixels: folded into [-size/2, size/2]."""
    return (f + size / 2) % size - size / 2


def _lookup(q: np.ndarray, fx: np.ndarray, fy: np.ndarray, size: int) -> np.ndarray:
    """Bilinear lookup of a zero-padded, fftshifted map at frequencies (cycles per image)."""
    pad = q.shape[0] // size
    cx, cy = q.shape[1] / 2, q.shape[0] / 2
    x = np.clip(cx + fx * pad, 0, q.shape[1] - 1.001)
    # Same convention as the DFT probe: frequency n b along image rows (downwards).
    y = np.clip(cy + fy * pad, 0, q.shape[0] - 1.001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    tx, ty = x - x0, y - y0
    return ((1 - tx) * (1 - ty) * q[y0, x0] + tx * (1 - ty) * q[y0, x0 + 1]
            + (1 - tx) * ty * q[y0 + 1, x0] + tx * ty * q[y0 + 1, x0 + 1])


def search(images: list[np.ndarray], signatures: list[Signature], a_range: tuple[float, float],
           b_range: tuple[float, float], step: float = 0.003, square: bool = False, top: int = 24,
           blur: float = 1.5) -> list[Lattice]:
    """Best lattices (a, b) for images and their patterns' signatures (scores summed over images).

    a, b are searched on log grids of relative step ``step``; ``square`` ties b = a (plain weaves of
    equal density). Returns up to ``top`` distinct local maxima, best first.
    """
    size = images[0].shape[0]
    maps = [peakness(img, blur=blur) for img in images]
    a_grid = np.exp(np.arange(math.log(a_range[0]), math.log(a_range[1]), step))
    b_grid = a_grid if square else np.exp(np.arange(math.log(b_range[0]), math.log(b_range[1]), step))
    # Peakness measures how far a harmonic stands above the local background, not its power:
    # square-root weights keep one dominant harmonic from deciding alone, and harmonics that fold
    # past Nyquist count less (photos are anti-aliased more than renders). See _score.
    total = _score(maps, signatures, a_grid[None, :], b_grid[:, None], size)
    if square:
        total = np.diag(total)[None, :]
        b_grid = a_grid[:1]
    coarse = _local_maxima(total, a_grid, b_grid, square, top)
    # Re-centre each candidate on the sharp (unblurred) map, where the true lattice stands out.
    sharp = [peakness(img, blur=0.0) for img in images]
    return sorted((_polish(sharp, signatures, c, size, square) for c in coarse), key=lambda l: -l.score)


def _score(maps, signatures, a, b, size) -> np.ndarray:
    """Search score of lattices (a, b) (arrays of equal shape) on peakness maps."""
    total = np.zeros(np.broadcast(a, b).shape)
    for q, sig in zip(maps, signatures):
        weights = np.sqrt(sig.weight)
        weights = weights / weights.sum()
        for m, n, weight in zip(sig.m, sig.n, weights):
            folded = (np.abs(m * a) > size / 2) | (np.abs(n * b) > size / 2)
            fx, fy = np.broadcast_arrays(_fold(m * a, size), _fold(n * b, size))
            total = total + weight * np.where(folded, 0.5, 1.0) * _lookup(q, fx.ravel(), fy.ravel(), size).reshape(fx.shape)
    return total


def _polish(maps, signatures, start: "Lattice", size: int, square: bool, span: float = 0.006, step: float = 0.0003) -> "Lattice":
    factors = np.exp(np.arange(-span, span + step / 2, step))
    a = start.a * factors[None, :]
    b = (start.a * factors[None, :]) if square else start.b * factors[:, None]
    scores = _score(maps, signatures, np.broadcast_to(a, np.broadcast(a, b).shape), np.broadcast_to(b, np.broadcast(a, b).shape), size)
    row, col = np.unravel_index(int(np.argmax(scores)), scores.shape)
    a_best = float(np.broadcast_to(a, scores.shape)[row, col])
    b_best = float(np.broadcast_to(b, scores.shape)[row, col])
    return Lattice(a_best, b_best, float(scores[row, col]))


def _local_maxima(score: np.ndarray, a_grid, b_grid, square: bool, top: int) -> list[Lattice]:
    import cv2

    peaks = score >= cv2.dilate(score.astype(np.float32), np.ones((5, 5), np.uint8)).astype(score.dtype) - 1e-12
    rows, cols = np.nonzero(peaks)
    order = np.argsort(-score[rows, cols])[:top]
    out = []
    for k in order:
        a = float(a_grid[cols[k]])
        b = a if square else float(b_grid[rows[k]])
        out.append(Lattice(a, b, float(score[rows[k], cols[k]])))
    return out


def refine(images: list[np.ndarray], signatures: list[Signature], start: Lattice, square: bool = False,
           span: float = 0.01, steps: int = 41, rounds: int = 3) -> Lattice:
    """Maximise the signature-weighted exact Fourier power over (a, b) near ``start``.

    Alternating 1D scans of a and b (both together when ``square``) with a span shrinking each round.
    """
    probes = [_HarmonicProbe(img) for img in images]
    a, b = start.a, start.b
    best = 0.0
    for r in range(rounds):
        factors = np.linspace(1 - span, 1 + span, steps)
        if square:
            scores = sum(np.array([p.scan_a([a * f], a * f, sig)[0] for f in factors])
                         for p, sig in zip(probes, signatures))
            a = b = a * factors[int(np.argmax(scores))]
        else:
            scores = sum(p.scan_a(a * factors, b, sig) for p, sig in zip(probes, signatures))
            a = a * factors[int(np.argmax(scores))]
            scores = sum(p.scan_b(a, b * factors, sig) for p, sig in zip(probes, signatures))
            b = b * factors[int(np.argmax(scores))]
        best = float(np.max(scores))
        span /= 8
    return Lattice(a, b, best)


@dataclass(frozen=True)
class Peak:
    fx: float        # cycles per image, to the right
    fy: float        # cycles per image, down the image
    strength: float  # peakness (log power above the local background)


def spectral_peaks(image: np.ndarray, count: int = 24, threshold: float = 2.5, pad: int = 4) -> list[Peak]:
    """The strongest isolated spectral peaks (half plane), with sub-bin positions."""
    import cv2

    q = peakness(image, pad=pad, blur=0.0).astype(np.float32)
    size = image.shape[0]
    local_max = q >= cv2.dilate(q, np.ones((2 * pad + 1, 2 * pad + 1), np.uint8))
    cy, cx = q.shape[0] // 2, q.shape[1] // 2
    rows, cols = np.nonzero(local_max & (q > threshold))
    peaks = []
    for r, c in zip(rows, cols):
        fx, fy = (c - cx) / pad, (r - cy) / pad
        if fy < 0 or (fy == 0 and fx <= 0) or math.hypot(fx, fy) < 4 or not (0 < r < q.shape[0] - 1 and 0 < c < q.shape[1] - 1):
            continue
        # Parabolic interpolation of the log-power excess along each axis.
        dx = 0.5 * (q[r, c - 1] - q[r, c + 1]) / max(q[r, c - 1] - 2 * q[r, c] + q[r, c + 1], -1e9) if q[r, c - 1] - 2 * q[r, c] + q[r, c + 1] < 0 else 0.0
        dy = 0.5 * (q[r - 1, c] - q[r + 1, c]) / max(q[r - 1, c] - 2 * q[r, c] + q[r + 1, c], -1e9) if q[r - 1, c] - 2 * q[r, c] + q[r + 1, c] < 0 else 0.0
        peaks.append(Peak(fx + dx / pad, fy + dy / pad, float(q[r, c])))
    peaks.sort(key=lambda p: -p.strength)
    return [p for p in peaks if abs(p.fx) < size / 2 - 1 and p.fy < size / 2 - 1][:count]


def comb_scores(freqs: np.ndarray, strengths: np.ndarray, periods: np.ndarray, size: int,
                sigma: float = 0.35, reach: float = 1.6) -> np.ndarray:
    """How well each candidate spacing explains the (folded) peak frequencies: sum of strengths of
    peaks lying within ~sigma cycles of a folded multiple m * spacing, |m * spacing| <= reach * size."""
    scores = np.zeros(len(periods))
    for f, s in zip(freqs, strengths):
        best = np.zeros(len(periods))
        for m in range(1, int(reach * size / periods.min()) + 1):
            valid = m * periods <= reach * size
            folded = np.abs(_fold(m * periods, size))
            hit = np.exp(-0.5 * ((folded - abs(f)) / sigma) ** 2)
            best = np.maximum(best, np.where(valid, hit, 0.0))
        scores += s * best
    return scores


def estimate(images: list[np.ndarray], a_range: tuple[float, float], b_range: tuple[float, float],
             step: float = 0.0002, tooth_cost: float = 1.0, reach: float = 2.5) -> Lattice:
    """The tile lattice (a, b) explaining the spectral peaks of the images, independent of the pattern.

    Each axis is a 1D comb search over a fine log grid (a harmonic sieve): the strength of the peaks
    a spacing explains, minus ``tooth_cost`` per comb tooth up to ``reach`` times the image size.
    Without that cost, every sub-multiple of the true spacing (and, with enough teeth, any small
    spacing) would explain the peaks equally well; with it, the coarsest comb that explains them wins.
    """
    size = images[0].shape[0]
    peaks = [p for img in images for p in spectral_peaks(img)]
    strengths = np.array([p.strength for p in peaks])
    spacing = []
    score = 0.0
    for axis, (lo, hi) in ((0, a_range), (1, b_range)):
        freqs = np.array([p.fx if axis == 0 else p.fy for p in peaks])
        informative = np.abs(freqs) > 3
        grid = np.exp(np.arange(math.log(lo), math.log(hi), step))
        scores = comb_scores(freqs[informative], strengths[informative], grid, size, reach=reach)
        scores = scores - tooth_cost * np.floor(reach * size / grid) * len(images)
        best = int(np.argmax(scores))
        spacing.append(float(grid[best]))
        score += float(scores[best])
    return Lattice(spacing[0], spacing[1], score)


RATIOS = (1 / 3, 1 / 2, 2 / 3, 1.0, 3 / 2, 2.0, 3.0)


def candidates(images: list[np.ndarray], comb: Lattice, signatures: list[Signature],
               a_range: tuple[float, float], b_range: tuple[float, float], square: bool = False,
               top: int = 3) -> list[Lattice]:
    """Lattices for one pattern: the comb estimate times small ratios per axis (the comb pins the
    lattice only up to sub- and super-multiples), kept within the pattern's range, each polished
    and scored by the pattern's signature on the sharp peakness map. Best first."""
    size = images[0].shape[0]
    sharp = [peakness(img, blur=0.0) for img in images]
    seen, out = set(), []
    for ra in RATIOS:
        for rb in ((ra,) if square else RATIOS):
            a, b = comb.a * ra, (comb.a * ra if square else comb.b * rb)
            if not (a_range[0] <= a <= a_range[1] and b_range[0] <= b <= b_range[1]):
                continue
            key = (round(a, 1), round(b, 1))
            if key in seen:
                continue
            seen.add(key)
            out.append(_polish(sharp, signatures, Lattice(a, b, 0.0), size, square, span=0.004, step=0.0002))
    return sorted(out, key=lambda l: -l.score)[:top]
