"""Yarn density from the spectrum: the weave's reciprocal lattice in an image.

The camera looks straight down at a plane parallel to its film, so a woven fabric is an exactly
periodic texture in the image, modulated only by slowly varying lighting. With ``tiles = (tu, tv)``
repeats over the plane of side P, one tile spans P / tu scene units, and the visible square of side
V holds ``a = tu V / P`` tiles across and ``b = tv V / P`` down (:func:`lattice_of`). The luminance
spectrum therefore concentrates on the lattice ``(m a, n b)`` cycles per image (integers m, n),
folded back by aliasing beyond Nyquist (f -> N - f for an N-pixel image) and attenuated by the
pixel's box filter (sinc^2 of f / N).

What runs:
1. :func:`estimate`: the spectral peaks of both images (:func:`spectral_peaks`, sub-bin positions
   on a zero-padded *peakness* map: log power above its local background) and, per axis, a harmonic
   sieve (:func:`comb_scores`): the spacing whose folded multiples explain the strongest peaks, minus
   a cost per comb tooth so that the coarsest comb that explains them wins. This pins the lattice
   up to small sub- and super-multiples, without knowing the weave.
2. :func:`candidates`: for one pattern, that lattice times small ratios per axis (:data:`RATIOS`)
   (and, :func:`with_anchored`, the lattices read from single peaks named as the pattern's
   strongest oblique harmonics, :func:`anchored`), each polished (:func:`polish`) and scored by the
   pattern's *signature*
   (:func:`signature_score`): which harmonics (m, n) carry the energy depends on the weave (and on
   the BSDF), measured once from a render at a low density where every significant harmonic is
   below Nyquist (:func:`signature`).
3. :func:`backend.texture.spacing.mean_lattice` (through :mod:`.candidates`): each candidate moved
   from the spacing at the photo's centre, which the windowed spectrum reads, to the mean over the
   whole photo, read from the phase of its harmonics; the yarn vectors solved there also give the
   sample's turn where the candidates agree on it (:func:`backend.texture.candidates.yarn_turn`).
No rendering is needed to read a photo's density; only the pattern signatures come from renders.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np

from ..core.rig import placement_of, yarn_angles
from ..core.threads import ordered_map
from ..core.weave import PRESETS
from ..image.spectrum import Peak, highpassed_luminance, peakness, shows_weave, spectral_peaks, windowed_highpass
from ..image.tone import GAMMA, encode, resize_linear


@dataclass(frozen=True)
class Signature:
    """Relative power of the lattice harmonics (m, n) of a pattern; n >= 0 (half plane)."""

    m: np.ndarray
    n: np.ndarray
    weight: np.ndarray   # sums to 1


COARSE_SIZE = 256


@dataclass
class Spectra:
    """What the lattice search reads from a photo pair, computed once: each image's strongest spectral
    peaks (sub-bin positions), its sharp peakness map and its high-passed luminance (``highpassed``,
    the high-pass of the peakness maps without the window, for the mean spacing); for photos above
    COARSE_SIZE also the
    peaks of the pair shrunk to COARSE_SIZE (``coarse``): the sieve works on the strongest peaks,
    and at full size those can be the aliased high harmonics of a dense weave, which line up with a
    wrong comb; shrunk (a box filter in linear light), those harmonics lose their weight and the
    fundamentals lead."""

    size: int
    peaks: list[list["Peak"]]
    maps: list[np.ndarray]
    highpassed: list[np.ndarray]
    coarse: list[list["Peak"]] | None = None

    @classmethod
    def of(cls, images: list[np.ndarray], workers: int = 1) -> "Spectra":
        """The spectra of ``images``, each photo's on one of up to ``workers`` threads."""
        images = [np.asarray(img, dtype=np.float64) for img in images]
        size = images[0].shape[0]

        def read(image: np.ndarray):
            return (spectral_peaks(image), peakness(image, blur=0.0), highpassed_luminance(image, size / 64),
                    spectral_peaks(_shrunk(image, COARSE_SIZE)) if size > COARSE_SIZE else None)

        peaks, maps, highpassed, coarse = zip(*ordered_map(read, images, workers))
        return cls(size, list(peaks), list(maps), list(highpassed), list(coarse) if size > COARSE_SIZE else None)

    @property
    def all_peaks(self) -> list["Peak"]:
        return [p for peaks in self.peaks for p in peaks]

    @property
    def shows_weave(self) -> list[bool]:
        """Per photo, whether its spectrum shows a peak that noise alone would not
        (:func:`backend.image.spectrum.chance_peakness`): a dense weave behind a phone's blur can
        leave one photo (a transmission, mostly) with nothing but noise."""
        return [shows_weave(peaks, self.size) for peaks in self.peaks]

    def of_the_weave(self) -> "Spectra":
        """These spectra without the photos that show no weave (:attr:`shows_weave`), unless none
        shows it. The placement reads the photos with generic harmonics, photo by photo: the noise
        peaks of a photo that shows no weave pull the sieves, and its noise map, which some wrong
        placement always explains best, would veto the turn the other photo shows (photo-like seed 53
        plain_015: the reflection shows the (1, 1) harmonics of a plain turned -2.64 degrees, the
        transmission nothing above noise, peakness 3.27; placed at +0.12 degrees, tiles 52 % off; now
        -2.67 degrees, 0.37 %). Out of sample, the five such plains of photo-like seed 97's first 40
        pairs (transmissions 3.02-3.49): rotation off by 1.85 -> 0.06 degrees on average, tiles of the
        plain off by over 1 % on 2 -> 0 (6.6 -> 0.16 %, 9.8 -> 0.32 %); seed 7's plain_010 and seed
        23's plain_010 and twill1m_017 moved by under 0.2 degrees, tiles within 0.6 % before and after."""
        keep = self.shows_weave
        if all(keep) or not any(keep):
            return self
        pick = [k for k, shown in enumerate(keep) if shown]
        return Spectra(self.size, [self.peaks[k] for k in pick], [self.maps[k] for k in pick],
                       [self.highpassed[k] for k in pick],
                       None if self.coarse is None else [self.coarse[k] for k in pick])


def _shrunk(image: np.ndarray, size: int) -> np.ndarray:
    """A display-space image shrunk to ``size`` x ``size`` in linear light (area average)."""
    return encode(resize_linear(np.clip(image, 0.0, None) ** GAMMA, size))


@dataclass(frozen=True)
class Lattice:
    a: float       # tiles across the image (cycles per image width)
    b: float       # tiles down the image
    score: float

    def tiles(self, view_size: float, plane_size: float) -> tuple[float, float]:
        return self.a * plane_size / view_size, self.b * plane_size / view_size


def lattice_of(tiles, rig) -> tuple[float, float]:
    """(a, b): tiles across and down the image of ``rig`` (a CaptureRig) for a ``tiles`` pair."""
    scale = rig.view_size / rig.plane_size
    return tiles[0] * scale, tiles[1] * scale


def yarns_in_view(pattern: str, tiles, rig) -> float | None:
    """Yarns across the image on the weave's denser axis (warps across, wefts down), or None when
    ``pattern`` is not a preset."""
    weave = PRESETS.get(pattern)
    if weave is None:
        return None
    a, b = lattice_of(tiles, rig)
    return max(weave.cols * a, weave.rows * b)


def turned_frequencies(f1, f2, rotation_deg: float, skew_deg: float = 0.0):
    """Image frequencies (fx to the right, fy down the image; cycles per image) of the fabric
    frequency (f1 across the warps, f2 across the wefts) of a sample whose warps are turned by
    theta_1 and wefts by theta_2 (the rig's ``yarn_angles_deg``: ``rotation_deg`` +- ``skew_deg`` / 2,
    counter-clockwise as the camera sees it):

        fx = f1 cos(theta_1) + f2 sin(theta_2),    fy = -f1 sin(theta_1) + f2 cos(theta_2)

    (the image's rows run down while the world's y runs up, so a counter-clockwise turn of the
    fabric turns its frequencies clockwise in (fx, fy)). Arrays broadcast."""
    if rotation_deg == 0 and skew_deg == 0:
        return f1, f2
    return _turned(f1, f2, *_turn(rotation_deg, skew_deg))


def yarn_vector_angles(u, v) -> tuple[float, float]:
    """(theta_1, theta_2), degrees: the yarn angles of the image vectors u (the fabric's harmonic
    (1, 0)) and v (its (0, 1)), as :func:`turned_frequencies` places them:
    u = |u| (cos theta_1, -sin theta_1), v = |v| (sin theta_2, cos theta_2)."""
    return math.degrees(math.atan2(-u[1], u[0])), math.degrees(math.atan2(v[0], v[1]))


UNTURNED = (1.0, 0.0, 0.0, 1.0)


def _turn(rotation_deg: float, skew_deg: float) -> tuple[float, float, float, float]:
    """(cos theta_1, sin theta_2, -sin theta_1, cos theta_2) of :func:`turned_frequencies`;
    :data:`UNTURNED` (this very tuple) for an unturned sample."""
    if rotation_deg == 0 and skew_deg == 0:
        return UNTURNED
    t1, t2 = (math.radians(angle) for angle in yarn_angles(rotation_deg, skew_deg))
    return math.cos(t1), math.sin(t2), -math.sin(t1), math.cos(t2)


def _turned(f1, f2, cos_1, sin_2, minus_sin_1, cos_2):
    """:func:`turned_frequencies` from the factors of :func:`_turn` (numbers or arrays that broadcast)."""
    return cos_1 * f1 + sin_2 * f2, minus_sin_1 * f1 + cos_2 * f2


def fabric_frequencies(fx, fy, rotation_deg: float, skew_deg: float = 0.0):
    """The inverse of :func:`turned_frequencies`: image frequencies -> (f1, f2) of the fabric,

        f1 = (fx cos(theta_2) - fy sin(theta_2)) / D,    f2 = (fx sin(theta_1) + fy cos(theta_1)) / D,

    D = cos(theta_1 - theta_2): f1 reads the frequency along the normal of the wefts, f2 along the
    normal of the warps."""
    if rotation_deg == 0 and skew_deg == 0:
        return fx, fy
    t1, t2 = (math.radians(angle) for angle in yarn_angles(rotation_deg, skew_deg))
    d = math.cos(t1 - t2)
    return (math.cos(t2) * fx - math.sin(t2) * fy) / d, (math.sin(t1) * fx + math.cos(t1) * fy) / d


COVERAGE_PEAKS = 8             # the strongest peaks of each photo that :func:`peak_coverage` weighs
COVERAGE_TOLERANCE = (3.0, 0.02)  # a peak is on a harmonic within 3 cycles per image + 2 % of its frequency
COVERAGE_REACH = 1.6           # harmonics up to 1.6 times the Nyquist frequency fold into the image
LOW_COVERAGE = 0.7             # lattices that make less of the photos' peak strength have not explained them


def peak_coverage(spectra: Spectra, a: float, b: float, rotation_deg: float = 0.0, skew_deg: float = 0.0) -> float:
    """The share of the photos' peak strength that the tile lattice (a, b) (tiles across and down the
    image; the sample turned and sheared as given) can make: over the COVERAGE_PEAKS strongest peaks
    of each photo, the strength of those within COVERAGE_TOLERANCE of a harmonic
    ``turned_frequencies(m a, n b)``, folded by the sampling (:func:`fold`: a dense weave's high
    harmonics alias), divided by the strength of all of them.

    A weave repeats on its tile, so every peak of its photos (but noise) is a harmonic of its lattice:
    a lattice three times too fine on one axis misses the harmonics between its own. It is one-sided:
    a lattice too coarse has harmonics everywhere and explains everything, so the measure can rule a
    lattice out, never in. Measured on the 20 photo-like pairs of seed 7 and the 11 dev goldens (at
    the true placement): the true lattice 0.64-1, the fit's trials on a wrong lattice 0.28-0.40; real
    twill2 (at the fit's placement): twill1 on a lattice three times too fine down the image
    (tiles 119.5 x 161.5) 0.13, twill0 on the photos' own (126.5 x 53.7) 0.93."""
    size = spectra.size
    peaks = [p for image_peaks in spectra.peaks for p in image_peaks[:COVERAGE_PEAKS]]
    total = sum(p.strength for p in peaks)
    if total <= 0:
        return 1.0
    reach = COVERAGE_REACH * size / 2
    m = np.arange(-math.ceil(reach / a), math.ceil(reach / a) + 1)
    n = np.arange(-math.ceil(reach / b), math.ceil(reach / b) + 1)
    fx, fy = turned_frequencies(m[:, None] * a, n[None, :] * b, rotation_deg, skew_deg)
    fx, fy = np.broadcast_to(fx, (m.size, n.size)).ravel(), np.broadcast_to(fy, (m.size, n.size)).ravel()
    near = (np.abs(fx) <= reach) & (np.abs(fy) <= reach)
    fx, fy = fold(fx[near], size), fold(fy[near], size)
    explained = 0.0
    for p in peaks:
        # a real image's spectrum is symmetric: the peak at -f is the same peak
        distance = min(np.min(np.hypot(fx - p.fx, fy - p.fy)), np.min(np.hypot(fx + p.fx, fy + p.fy)))
        if distance <= COVERAGE_TOLERANCE[0] + COVERAGE_TOLERANCE[1] * math.hypot(p.fx, p.fy):
            explained += p.strength
    return explained / total


def harmonic_spectrum(image: np.ndarray, a: float, b: float, m: np.ndarray, n: np.ndarray) -> np.ndarray:
    """|DFT|^2 of the windowed, high-passed luminance at the frequencies (m a, n b), cycles per image
    (exact: the separable DFT at those frequencies, not the FFT grid)."""
    y = windowed_highpass(image, image.shape[0] / 64)
    h, w = y.shape
    um, un = np.unique(m), np.unique(n)
    ex = np.exp(-2j * np.pi * np.outer(um * a, np.arange(w)) / w)
    ey = np.exp(-2j * np.pi * np.outer(un * b, np.arange(h)) / h)
    full = ey @ y @ ex.T
    return np.abs(full[np.searchsorted(un, n), np.searchsorted(um, m)]) ** 2


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


def fold(f: np.ndarray, size: int) -> np.ndarray:
    """Frequency (cycles per image) after sampling with `size` pixels: folded into [-size/2, size/2]."""
    return (f + size / 2) % size - size / 2


def _lookup(q: np.ndarray, fx: np.ndarray, fy: np.ndarray, size: int) -> np.ndarray:
    """Bilinear lookup of a zero-padded, fftshifted map at frequencies (cycles per image)."""
    pad = q.shape[0] // size
    cx, cy = q.shape[1] / 2, q.shape[0] / 2
    x = np.clip(cx + fx * pad, 0, q.shape[1] - 1.001)
    # Same convention as the DFT probe: frequency n b along image rows (downwards).
    y = np.clip(cy + fy * pad, 0, q.shape[0] - 1.001)
    x0, y0 = np.floor(x).astype(np.intp), np.floor(y).astype(np.intp)
    tx, ty = x - x0, y - y0
    # gathers from the flat map: the same four samples as q[y0, x0] ..., in half the time
    flat, width = q.ravel(), q.shape[1]
    corner = y0 * width + x0
    return ((1 - tx) * (1 - ty) * flat.take(corner) + tx * (1 - ty) * flat.take(corner + 1)
            + (1 - tx) * ty * flat.take(corner + width) + tx * ty * flat.take(corner + width + 1))


def signature_score(maps, signatures, a, b, size, rotation_deg: float = 0.0, skew_deg: float = 0.0) -> np.ndarray:
    """Search score of lattices (a, b) (numbers or arrays that broadcast; the score has their
    broadcast shape) of a sample turned by ``rotation_deg`` and sheared by ``skew_deg`` on peakness
    maps."""
    shape = np.broadcast(a, b).shape
    a, b = np.broadcast_to(a, shape).ravel(), np.broadcast_to(b, shape).ravel()
    return _scores(maps, signatures, a, b, size, _turn(rotation_deg, skew_deg)).reshape(shape)


def scores_at_angles(maps, signatures, a: float, b: float, size: int, placements) -> np.ndarray:
    """:func:`signature_score` of one lattice (a, b) at each (rotation, skew) of ``placements``, at
    once: the same numbers as one call per placement (the same floating-point operations per
    element), without the Python overhead of hundreds of small calls."""
    turns = np.array([_turn(rotation, skew) for rotation, skew in placements])  # (P, 4)
    return _scores(maps, signatures, np.full(len(turns), float(a)), np.full(len(turns), float(b)), size,
                   tuple(turns.T))


def _scores(maps, signatures, a: np.ndarray, b: np.ndarray, size: int, turn) -> np.ndarray:
    """:func:`signature_score` of lattices (a[k], b[k]) (K,) at the factors ``turn`` of :func:`_turn`
    (numbers, or arrays (K,) with one placement per lattice)."""
    total = np.zeros(a.shape)
    for q, sig in zip(maps, signatures):
        weights = np.sqrt(sig.weight)
        weights = weights / weights.sum()
        # every harmonic at once (rows)
        f1, f2 = sig.m[:, None] * a[None, :], sig.n[:, None] * b[None, :]
        # an unturned sample skips the products (they would give the same frequencies, up to the sign of a zero)
        fx, fy = (f1, f2) if turn is UNTURNED else _turned(f1, f2, *turn)
        folded = (np.abs(fx) > size / 2) | (np.abs(fy) > size / 2)
        looked_up = _lookup(q, fold(fx, size), fold(fy, size), size)
        # added one row at a time in the signature's order: numpy's reduction would sum a single
        # lattice's column pairwise, and the sums must not depend on how many are scored at once
        for row in weights[:, None] * np.where(folded, 0.5, 1.0) * looked_up:
            total = total + row
    return total


def polish(maps, signatures, start: Lattice, size: int, square: bool, span: float = 0.006,
           step: float = 0.0003, rotation_deg: float = 0.0, skew_deg: float = 0.0) -> Lattice:
    factors = np.exp(np.arange(-span, span + step / 2, step))
    a = start.a * factors[None, :]
    b = (start.a * factors[None, :]) if square else start.b * factors[:, None]
    scores = signature_score(maps, signatures, a, b, size, rotation_deg, skew_deg)
    row, col = np.unravel_index(int(np.argmax(scores)), scores.shape)
    a_best = float(np.broadcast_to(a, scores.shape)[row, col])
    b_best = float(np.broadcast_to(b, scores.shape)[row, col])
    return Lattice(a_best, b_best, float(scores[row, col]))


def comb_scores(freqs: np.ndarray, strengths: np.ndarray, periods: np.ndarray, size: int,
                sigma: float = 0.35, reach: float = 1.6) -> np.ndarray:
    """How well each candidate spacing explains the (folded) peak frequencies: sum of strengths of
    peaks lying within ~sigma cycles of a folded multiple m * spacing, |m * spacing| <= reach * size."""
    multiples = np.arange(1, int(reach * size / periods.min()) + 1)[:, None] * periods[None, :]  # (M, G)
    folded = np.where(multiples <= reach * size, np.abs(fold(multiples, size)), np.inf)
    scores = np.zeros(len(periods))
    for f, s in zip(freqs, strengths):  # one peak at a time keeps the arrays (M, G) small
        # the nearest tooth's hit: exp is monotonic, so one exp per spacing instead of M
        nearest = np.abs(folded - abs(f)).min(axis=0)
        scores += s * np.exp(-0.5 * (nearest / sigma) ** 2)
    return scores


def _combs(peaks: list[Peak], images: int, size: int, ranges, rotation_deg: float, skew_deg: float, step: float,
           tooth_cost: float, reach: float, near: tuple[float, float] | None = None,
           span: float = 0.02) -> tuple[tuple[float, float], tuple[float, float]]:
    """The best comb spacing per fabric axis and its score, for peaks turned back by ``rotation_deg``
    and ``skew_deg``; ``near`` restricts each axis to within ``span`` (relative) of a spacing. Axis 0
    (f1) reads the peaks along the normal of the wefts, axis 1 along the normal of the warps
    (:func:`fabric_frequencies`), so each axis's score depends on one yarn angle only."""
    f1, f2 = fabric_frequencies(np.array([p.fx for p in peaks]), np.array([p.fy for p in peaks]), rotation_deg,
                                skew_deg)
    strengths = np.array([p.strength for p in peaks])
    spacing, score = [], []
    for axis, freqs, (lo, hi) in ((0, f1, ranges[0]), (1, f2, ranges[1])):
        if near is not None:
            lo, hi = near[axis] * (1 - span), near[axis] * (1 + span)
        informative = np.abs(freqs) > 3
        grid = np.exp(np.arange(math.log(lo), math.log(hi), step))
        scores = comb_scores(freqs[informative], strengths[informative], grid, size, reach=reach)
        scores = scores - tooth_cost * np.floor(reach * size / grid) * images
        best = int(np.argmax(scores))
        spacing.append(float(grid[best]))
        score.append(float(scores[best]))
    return (spacing[0], spacing[1]), (score[0], score[1])


def estimate(spectra: Spectra, a_range: tuple[float, float], b_range: tuple[float, float],
             step: float = 0.0002, tooth_cost: float = 1.0, reach: float = 2.5, rotation_deg: float = 0.0,
             skew_deg: float = 0.0, coarse: bool = False) -> Lattice:
    """The tile lattice (a, b) explaining the spectral peaks of the images (of the shrunk images with
    ``coarse``), independent of the pattern.

    Each fabric axis is a 1D comb search over a fine log grid (a harmonic sieve) on the peaks'
    frequencies turned back by ``rotation_deg`` and ``skew_deg``: the strength of the peaks a spacing explains, minus
    ``tooth_cost`` per comb tooth up to ``reach`` times the image size. Without that cost, every
    sub-multiple of the true spacing (and, with enough teeth, any small spacing) would explain the
    peaks equally well; with it, the coarsest comb that explains them wins.
    """
    by_image, size = (spectra.coarse, COARSE_SIZE) if coarse else (spectra.peaks, spectra.size)
    peaks = [p for image_peaks in by_image for p in image_peaks]
    (a, b), scores = _combs(peaks, len(by_image), size, (a_range, b_range), rotation_deg, skew_deg, step, tooth_cost,
                            reach)
    return Lattice(a, b, sum(scores))


def estimates(spectra: Spectra, a_range: tuple[float, float], b_range: tuple[float, float],
              rotation_deg: float = 0.0, skew_deg: float = 0.0, workers: int = 1) -> list[Lattice]:
    """:func:`estimate` on the photos' peaks, and on the shrunk photos' peaks when there are any
    (two hypotheses: which one explains the peakness maps is for :func:`candidates` to say), on up
    to ``workers`` threads."""
    return ordered_map(lambda coarse: estimate(spectra, a_range, b_range, rotation_deg=rotation_deg,
                                               skew_deg=skew_deg, coarse=coarse),
                       (False, True) if spectra.coarse is not None else (False,), workers)


ROTATION_SCAN_DEG = 6.0
ROTATION_HYPOTHESES = 6
SHEAR_HYPOTHESES = 8
REFINED_HYPOTHESES = 8
MAX_SKEW_DEG = 5.0
SHEAR_GAIN = 1.15
RIVAL_TURN_GAIN = 1.1
SIEVE_AGREEMENT_DEG = 0.3  # a turn this close to the summed sieve scan's strongest agrees with it (its step: 0.25)
VERIFIED_RATIOS = 2
# p / q for p, q <= 5: a sieve may lock onto a yarn's frequency (2-5 times the tile's), an aliased
# harmonic, or a multiple of either
ROTATION_RATIOS = tuple(sorted({p / q for p in range(1, 6) for q in range(1, 6)}))


def _generic_signature(order: int = 3) -> Signature:
    """Every low harmonic |m|, n <= order (half plane), equally weighted: any weave's lattice."""
    m, n = np.meshgrid(np.arange(-order, order + 1), np.arange(0, order + 1))
    keep = (n > 0) | (m > 0)
    return Signature(m[keep], n[keep], np.full(int(keep.sum()), 1.0 / int(keep.sum())))


def estimate_placement(spectra: Spectra, a_range: tuple[float, float], b_range: tuple[float, float],
                       tooth_cost: float = 1.0, reach: float = 2.5, workers: int = 1) -> "Placement":
    """The sample's placement (yarn angles, so the rig's ``sample_rotation_deg`` and
    ``sample_skew_deg``) under which the photos' spectra show an axis-aligned tile lattice, with
    that lattice.

    1. Hypotheses: the harmonic sieves of :func:`estimate` on the peaks turned back by each angle of
       a +-6 degree scan (0.25-degree steps, a coarse spacing grid). Each axis's sieve depends on
       one yarn angle only (:func:`_combs`), so one scan gives both: the best local maxima of the
       summed score (a turned sample) and every pair of each axis's SHEAR_HYPOTHESES best local
       maxima within MAX_SKEW_DEG of each other (a sheared one), with their spacings. A sieve works
       on one axis at a time, so a wrong angle can line the projections up by chance (often with a
       denser lattice); on the dev real twill1 the true yarn angles are the 5th and 7th best maxima
       of their axes. The pairs also seed turned hypotheses at their middle angle, which replace
       the summed scan's best only where they explain the maps RIVAL_TURN_GAIN times better
       (photo-like seed-7 set: rotation off by over 0.5 degrees on 11 of 20 pairs -> 8, tiles off by
       over 3 % on 4 -> 1; the unseen seed-53 set: 12 -> 11 and 10 -> 9, no pair worse in either).
       The same scan read through the 2D maps (each angle's sieve lattice at its best multiple,
       scored by the generic harmonics) seeds more turned hypotheses; one replaces the turn so far
       only where it explains the maps RIVAL_TURN_GAIN times better and each photo alone better
       (:func:`_beats_on_each_photo`). Rotation off by over 0.5 degrees, after the unturned check of
       :func:`backend.texture.candidates.placed`: seed 7 8 -> 6 of 20 pairs (mean 0.63 -> 0.37
       degrees), seed 53 11 -> 8 (1.84 -> 1.22), seed 97 11 -> 9 (1.46 -> 1.10); no pair worse; the
       golden and dev real placements unchanged. Without the per-photo test, wrong turns near the
       scan's edge and a satin's mirror turn won on seeds 7 and 97 (1.10-1.15 times over both photos).
       Pairs of strong peaks read as two low harmonics of one lattice (:func:`_peak_pair_turns`)
       seed more turned hypotheses, under the same two tests. At 2-3 px per yarn the aliased yarn
       harmonics can pull one axis's sieve to a wrong spacing at the true turn (photo-like seed-97
       plain_005, turned -2.93 degrees: 154 cycles per image where the weave has 99), and the maps
       then prefer a wrong turn; two peaks' positions still pin it. Rotation off by over 0.5
       degrees (``bench placement``, with :func:`backend.texture.candidates.placed`'s check): seed
       97 6 -> 3 of 20 pairs (mean 0.82 -> 0.40 degrees; tiles off by over 1 % 7 -> 4), seed 53 3
       -> 2 (0.37 -> 0.27; 7 -> 6), seed 7 1 -> 1 (in-sample for the gates above; no pair moved by
       over 0.04 degrees); no pair of the three sets worse by over 0.07 degrees; the golden
       placements within 0.01 degrees, the dev real ones unchanged.
       A map or peak-pair turn that agrees with the summed scan's strongest turn (within
       SIEVE_AGREEMENT_DEG) where the turn so far does not needs no RIVAL_TURN_GAIN, only a higher
       score: two readings of the peaks agree (their positions, and the sieves over all of them)
       against the generic harmonics alone. Photo-like seed-61 plain_005 (2.62 px per yarn behind
       1.48 px of blur, turned 2.77 degrees; its transmission shows nothing above noise) keeps only
       its (1, 1) and (-1, 1) peaks in the reflection: they give 2.73 degrees and the scan peaks at
       2.75, yet the generic harmonics explained the noise 1.07 times better at 4.76 degrees, and the
       sample was placed unturned with its plain's tiles 69 % off (0.35 % now). No other pair of
       the photo-like seeds 7, 53, 61 and 97 moved (``bench placement``).
    2. Verification: a sieve pins each axis's spacing only up to sub- and super-multiples, so each
       hypothesis's spacings times the small ROTATION_RATIOS per axis are scored against the whole 2D
       peakness maps with every low harmonic (:func:`_generic_signature`) folded exactly as the pixel
       grid folds it; the REFINED_HYPOTHESES best of those (VERIFIED_RATIOS at most per hypothesis)
       are refined in both yarn angles (0.02-degree steps) and spacing; each turned hypothesis's
       best VERIFIED_RATIOS are refined in one angle. The lattice that explains the maps best
       wins, a sheared one only where :func:`_shear_confirmed` says so: on each photo alone, it
       explains the map SHEAR_GAIN times better than the best turned lattice and than its own
       lattice at any single angle. Its second angle is one more degree of freedom, and over both
       photos it explains the noise or aliased harmonics of unsheared samples better than the
       best turn by over 10 % on 19 of 87 golden / photo-like pairs (up to 1.5 times: clean aliased
       renders such as the dev golden twill1_s1, photo-like pairs at 2-3 px per yarn); the
       per-photo test keeps 1 of those 87 (photo-like seed 31 twill1_017, whose turned estimate was
       2.8 degrees off as well) and confirms the dev real twill1 (warps +1.9, wefts -1.8 degrees;
       1.47 times the best turn, 2.3 times its lattice at one angle, on each photo). It misses
       milder or one-sided evidence: the dev real twill2 (1.35 degrees; 1.08 against its lattice at
       one angle), and a clean twill1 render at 14 x 18 tiles, rotation -1, skew 3, whose
       transmission a turned lattice twice as dense explains as well. (Measured on photo-like
       pairs: the sieve's angles come within half a degree of the truth, but often with a multiple
       of the true spacing on one axis, which the generic harmonics then score below a wrong angle's
       lattice. The dev real twills are sheared by 1.5-4 degrees: at one angle for both axes, the
       lattice drifts by more than a cycle across the image.)

    The scans and refinements, each independent of the others, run on up to ``workers`` threads.
    """
    turned, sheared = placement_hypotheses(spectra, a_range, b_range, tooth_cost, reach, workers)
    return sheared if sheared is not None and _shear_confirmed(spectra, sheared, turned) else turned


def placement_hypotheses(spectra: Spectra, a_range: tuple[float, float], b_range: tuple[float, float],
                         tooth_cost: float = 1.0, reach: float = 2.5, workers: int = 1
                         ) -> tuple["Placement", "Placement | None"]:
    """The best turned and the best sheared placement of :func:`estimate_placement` (None when no
    two axes' angles are close enough to pair), each with the turn where the summed sieve scan peaks
    (``sieve_turn_deg``: a placement whose lattices miss the photos' peaks is tried there too,
    :func:`backend.texture.candidates.placed`)."""
    peaks, images, size = spectra.all_peaks, len(spectra.peaks), spectra.size
    angles = np.arange(-ROTATION_SCAN_DEG, ROTATION_SCAN_DEG + 1e-9, 0.25)
    scan = ordered_map(lambda angle: _combs(peaks, images, size, (a_range, b_range), angle, 0.0, 0.003, tooth_cost,
                                            reach), angles, workers)
    by_weft = np.array([scores[0] for _, scores in scan])   # axis 0 depends on the weft angle
    by_warp = np.array([scores[1] for _, scores in scan])   # axis 1 on the warp angle
    generic = [_generic_signature()] * images
    turned = _local_maxima(by_weft + by_warp)[:ROTATION_HYPOTHESES]
    unturned = int(np.argmin(np.abs(angles)))  # always a hypothesis: weak textures give weak evidence
    turned += [] if unturned in turned else [unturned]

    # each angle's sieve lattice at its multiples, best first: refined below, and scored over the maps
    multiples = ordered_map(lambda k: _multiples(spectra.maps, generic, Lattice(*scan[k][0], 0.0), a_range, b_range,
                                                 float(angles[k]), float(angles[k]), size), range(len(angles)), workers)

    def refined(starts: list[tuple[Lattice, float, float]], sheared: bool = False) -> list[Placement]:
        """Each (lattice, warp angle, weft angle) of ``starts`` refined (:func:`_refine_placement`), in order."""
        return ordered_map(lambda start: _refine_placement(spectra.maps, generic, *start, size, sheared), starts,
                           workers)

    def refined_at(ks: list[int]) -> list[Placement]:
        """Each angle's best VERIFIED_RATIOS multiples refined in both angles together, in order."""
        return refined([(lat, float(angles[k]), float(angles[k])) for k in ks
                        for lat in multiples[k][:VERIFIED_RATIOS]])

    best_turned = max(refined_at(turned), key=lambda p: p.score)
    # The same scan read through the 2D maps: each angle's sieve lattice at its best multiple, scored
    # by the generic harmonics. Uneven spacing smears the peaks the sieves sum, so the summed score's
    # maxima can all miss the turn while the maps still show it. One wins only by RIVAL_TURN_GAIN, and
    # only where it is better on each photo alone (:func:`_beats_on_each_photo`).
    by_map = np.array([lattices[0].score for lattices in multiples])
    mapped = [k for k in _local_maxima(by_map)[:ROTATION_HYPOTHESES] if k not in turned]
    best_mapped = max(refined_at(mapped), key=lambda p: p.score, default=None)
    # Pairs of strong peaks read as two low harmonics of one lattice: where the sieves' spacings miss
    # on one axis (aliased yarn harmonics at 2-3 px per yarn), two peaks still pin the turn.
    peaked = sorted(_peak_pair_turns(spectra, a_range, b_range),
                    key=lambda t: -float(signature_score(spectra.maps, generic, t[0], t[1], size, t[2])))
    best_peaked = max(refined([(Lattice(a, b, 0.0), turn, turn) for a, b, turn in peaked[:REFINED_HYPOTHESES]]),
                      key=lambda p: p.score, default=None)
    warps, wefts = _local_maxima(by_warp)[:SHEAR_HYPOTHESES], _local_maxima(by_weft)[:SHEAR_HYPOTHESES]
    verified = []
    for i, j in sorted((i, j) for i in warps for j in wefts if i != j and abs(angles[i] - angles[j]) <= MAX_SKEW_DEG):
        warp, weft = float(angles[i]), float(angles[j])
        start = Lattice(scan[j][0][0], scan[i][0][1], 0.0)
        verified += [(lat.score, warp, weft, lat) for lat in
                     _multiples(spectra.maps, generic, start, a_range, b_range, warp, weft, size)[:VERIFIED_RATIOS]]
    verified.sort(key=lambda v: -v[0])
    # The paired angles also seed turned hypotheses, at their middle: each axis's own angle can place
    # the lattice where the summed scan's maxima miss it. One wins only by RIVAL_TURN_GAIN: more
    # hypotheses give the generic harmonics more chances to prefer a wrong one.
    paired = refined([(lat, middle, middle) for _, warp, weft, lat in verified[:REFINED_HYPOTHESES]
                      for middle in (placement_of(warp, weft)[0],)])
    best_paired = max(paired, key=lambda p: p.score, default=None)
    if best_paired is not None and best_paired.score > RIVAL_TURN_GAIN * best_turned.score:
        best_turned = best_paired
    strongest = float(angles[turned[0]])
    for rival in (best_mapped, best_peaked):  # in turn, each against the turn so far
        if (rival is not None and rival.score > _rival_gain(rival, best_turned, strongest) * best_turned.score
                and _beats_on_each_photo(spectra, rival, [best_turned])):
            best_turned = rival
    best_sheared = max(refined([(lat, warp, weft) for _, warp, weft, lat in verified[:REFINED_HYPOTHESES]],
                               sheared=True), key=lambda p: p.score, default=None)
    return (replace(best_turned, sieve_turn_deg=strongest),
            None if best_sheared is None else replace(best_sheared, sieve_turn_deg=strongest))


def _rival_gain(rival: "Placement", current: "Placement", sieve_turn_deg: float) -> float:
    """How many times better than ``current`` a rival turn must explain the maps: RIVAL_TURN_GAIN, or
    1 (a higher score alone) where the rival's turn agrees with the summed sieve scan's strongest
    (within SIEVE_AGREEMENT_DEG) and ``current``'s does not: two readings of the peaks (their
    positions, and the sieves over all of them) agreeing, against the generic harmonics alone."""
    def agrees(placement: "Placement") -> bool:
        return abs(placement.rotation_deg - sieve_turn_deg) <= SIEVE_AGREEMENT_DEG
    return 1.0 if agrees(rival) and not agrees(current) else RIVAL_TURN_GAIN


PEAK_PAIR_PEAKS = 6
# the low harmonics (m, n) a strong peak is taken for: |m|, n <= 2 (half plane)
PEAK_PAIR_HARMONICS = tuple((m, n) for m in range(-2, 3) for n in range(3) if n > 0 or m > 0)
# every ordered pair of them that pins u and v (independent harmonics), as (pairs, 2, 2) rows (m, n)
PEAK_PAIR_BASES = np.array([(h1, h2) for h1, h2 in itertools.permutations(PEAK_PAIR_HARMONICS, 2)
                            if h1[0] * h2[1] != h1[1] * h2[0]], dtype=float)
# their inverses, (pairs, 2, 2): a pair of peaks is solved by two products each, not one LAPACK call
# per pair (a batched np.linalg.solve of these 2 x 2 systems took 0.1-0.9 s a call under a threaded
# OpenBLAS on 2 busy cores, 80 microseconds single-threaded)
_PEAK_PAIR_INVERSES = np.linalg.inv(PEAK_PAIR_BASES)


def _peak_pair_turns(spectra: Spectra, a_range, b_range) -> list[tuple[float, float, float]]:
    """Turned placements (a, b, rotation) read from pairs of one photo's PEAK_PAIR_PEAKS strongest
    peaks p, q (q or -q: a real image's spectrum is symmetric) taken as two harmonics (m1, n1),
    (m2, n2) of PEAK_PAIR_HARMONICS:

        p = m1 u + n1 v,    q = m2 u + n2 v

    solved for the image vectors u and v of the fabric's harmonics (1, 0) and (0, 1), whose angles
    are the yarns' (:func:`yarn_vector_angles`) and whose lengths are the lattice (a, b) = (|u|, |v|)
    (u and v each up to its sign). Kept where both yarn angles lie within the scan's
    +-ROTATION_SCAN_DEG and MAX_SKEW_DEG of each other, and (a, b) within the ranges; one per
    (a, b, rotation) rounded to (1, 1, 0.1).

    Dense weaves at 2-3 px per yarn behind a phone's blur can leave a few strong peaks (a plain's
    (1, 1) and (-1, 1), a yarn harmonic) whose aliased companions pull each axis's sieve to a wrong
    spacing, and the turn then loses to a wrong one in the maps; the peaks' positions alone still
    pin it."""
    found = {}
    for peaks in spectra.peaks:
        for p, q in itertools.combinations(peaks[:PEAK_PAIR_PEAKS], 2):
            for sign in (1.0, -1.0):
                images = np.array([[p.fx, p.fy], [sign * q.fx, sign * q.fy]])
                solved = _PEAK_PAIR_INVERSES[:, :, 0, None] * images[0] + _PEAK_PAIR_INVERSES[:, :, 1, None] * images[1]
                for u, v in solved:
                    a, b = math.hypot(*u), math.hypot(*v)
                    if not (a_range[0] <= a <= a_range[1] and b_range[0] <= b <= b_range[1]):
                        continue
                    for u_sign, v_sign in itertools.product((1.0, -1.0), repeat=2):
                        warp, weft = yarn_vector_angles(u_sign * u, v_sign * v)
                        if (abs(warp) <= ROTATION_SCAN_DEG and abs(weft) <= ROTATION_SCAN_DEG
                                and abs(warp - weft) <= MAX_SKEW_DEG):
                            turn = placement_of(warp, weft)[0]
                            found.setdefault((round(a), round(b), round(turn, 1)), (a, b, turn))
    return list(found.values())


def _beats_on_each_photo(spectra: Spectra, placement: "Placement", rivals: list["Placement"],
                         gain: float = 1.0) -> bool:
    """Whether ``placement`` explains each photo's peakness map alone (generic low harmonics) ``gain``
    times better than every one of ``rivals``: a true turn or shear shows in both photos of the same
    fabric, a chance one in one photo's noise or aliased harmonics (photo-like turns near the +-5
    degree edge of the scan, and a satin's mirror turn, won over both photos together by 1.1-1.15
    times and lost on one photo alone)."""
    generic = [_generic_signature()]
    return all(_map_score(q, generic, placement, spectra.size)
               > gain * max(_map_score(q, generic, rival, spectra.size) for rival in rivals)
               for q in spectra.maps)


def _shear_confirmed(spectra: Spectra, sheared: "Placement", turned: "Placement") -> bool:
    """Whether the sheared placement explains *each* photo's peakness map alone (generic low
    harmonics) SHEAR_GAIN times better than the best turned placement does, and than its own lattice
    does at the best single angle (each yarn's angle and their middle, refined): a true shear shows
    in both photos of the same fabric and needs both angles; a chance one explains one photo's noise
    or aliased harmonics, or owes its score to a better lattice rather than to the shear. The cheap
    comparison with the turned placement goes first: most shears fail it."""
    if not _beats_on_each_photo(spectra, sheared, [turned], SHEAR_GAIN):
        return False
    generic = [_generic_signature()] * len(spectra.maps)
    angles = (sheared.warp_deg, sheared.weft_deg, placement_of(sheared.warp_deg, sheared.weft_deg)[0])
    at_one_angle = [_refine_placement(spectra.maps, generic, sheared.lattice, angle, angle, spectra.size, False)
                    for angle in angles]
    return _beats_on_each_photo(spectra, sheared, at_one_angle, SHEAR_GAIN)


def _map_score(q: np.ndarray, signatures, placement: "Placement", size: int) -> float:
    return float(signature_score([q], signatures, placement.lattice.a, placement.lattice.b, size,
                                 *placement_of(placement.warp_deg, placement.weft_deg)))


@dataclass(frozen=True)
class Placement:
    """A placement hypothesis: its generic score, the yarn angles (degrees) and the lattice."""

    score: float
    warp_deg: float
    weft_deg: float
    lattice: Lattice
    sieve_turn_deg: float | None = None  # the turn where the summed sieve scan peaks (estimate_placement)

    @property
    def rotation_deg(self) -> float:
        return float(round(placement_of(self.warp_deg, self.weft_deg)[0], 3))

    @property
    def skew_deg(self) -> float:
        return float(round(placement_of(self.warp_deg, self.weft_deg)[1], 3))


def _local_maxima(scores: np.ndarray) -> list[int]:
    """Indices of the local maxima of a 1D scan, highest first."""
    last = len(scores) - 1
    local = [k for k in range(len(scores))
             if scores[k] >= scores[max(k - 1, 0)] and scores[k] >= scores[min(k + 1, last)]]
    return sorted(local, key=lambda k: -scores[k])


def _multiples(maps, signatures, lattice: Lattice, a_range, b_range, warp_deg: float, weft_deg: float,
               size: int) -> list[Lattice]:
    """``lattice`` times every pair of ROTATION_RATIOS inside the ranges, scored by ``signatures`` at
    the yarn angles, best first."""
    pairs = [(lattice.a * ra, lattice.b * rb) for ra in ROTATION_RATIOS for rb in ROTATION_RATIOS
             if a_range[0] <= lattice.a * ra <= a_range[1] and b_range[0] <= lattice.b * rb <= b_range[1]]
    pairs = pairs or [(lattice.a, lattice.b)]
    a, b = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
    scores = signature_score(maps, signatures, a, b, size, *placement_of(warp_deg, weft_deg))
    order = np.argsort(-scores, kind="stable")
    return [Lattice(float(a[i]), float(b[i]), float(scores[i])) for i in order]


def _refine_placement(maps, signatures, start: Lattice, warp_deg: float, weft_deg: float, size: int,
                      sheared: bool) -> "Placement":
    """Alternately the best angle within +-0.3 degrees for the current spacing (of each yarn in turn
    when ``sheared``, else of both together) and the polished spacing for those angles, twice."""
    rotation, skew = placement_of(warp_deg, weft_deg)
    lattice_now = polish(maps, signatures, start, size, False, span=0.01, step=0.0005, rotation_deg=rotation,
                         skew_deg=skew)
    steps = np.arange(-0.3, 0.3 + 1e-9, 0.02)
    for _ in range(2):
        for moves in ((1, 0), (0, 1)) if sheared else ((1, 1),):
            trial = [(warp_deg + moves[0] * d, weft_deg + moves[1] * d) for d in steps]
            scores = scores_at_angles(maps, signatures, lattice_now.a, lattice_now.b, size,
                                      [placement_of(*angles) for angles in trial])
            warp_deg, weft_deg = trial[int(np.argmax(scores))]
        rotation, skew = placement_of(warp_deg, weft_deg)
        lattice_now = polish(maps, signatures, lattice_now, size, False, span=0.004, step=0.0002,
                             rotation_deg=rotation, skew_deg=skew)
    return Placement(lattice_now.score, warp_deg, weft_deg, lattice_now)


RATIOS = (1 / 3, 1 / 2, 2 / 3, 1.0, 3 / 2, 2.0, 3.0)


def candidates(spectra: Spectra, combs: list[Lattice], signatures: list[Signature],
               a_range: tuple[float, float], b_range: tuple[float, float], square: bool = False,
               top: int = 3, rotation_deg: float = 0.0, skew_deg: float = 0.0) -> list[Lattice]:
    """Lattices for one pattern: each comb estimate times small ratios per axis (a comb pins the
    lattice only up to sub- and super-multiples), kept within the pattern's range, each polished
    and scored by the pattern's signature on the sharp peakness maps. Best first."""
    starts = [(comb.a * ra, comb.a * ra if square else comb.b * rb)
              for comb in combs for ra in RATIOS for rb in ((ra,) if square else RATIOS)]
    found = _polished(spectra, signatures, starts, a_range, b_range, square, rotation_deg, skew_deg)
    return sorted(found, key=lambda lat: -lat.score)[:top]


def with_anchored(spectra: Spectra, found: list[Lattice], signatures: list[Signature],
                  a_range: tuple[float, float], b_range: tuple[float, float], square: bool = False,
                  top: int = 3, rotation_deg: float = 0.0, skew_deg: float = 0.0) -> list[Lattice]:
    """``found`` (a pattern's :func:`candidates`, best first) joined by the lattices read from single
    peaks (:func:`anchored`), polished, that score ANCHOR_GAIN times the best of ``found``. Best
    first.

    Where the combs explain the peaks, a single peak's reading wins by a few percent at most and is
    as often a near miss (photo-like satins off by 3-9 %, the dev real satin1 read as a lattice 5
    times coarser); where they fail, it wins by 1.3-4 times (photo-like twills and satins at 2-4 px
    per yarn behind the phone's blur).

    Where none of ``found`` makes LOW_COVERAGE of the photos' peak strength (:func:`peak_coverage`),
    the combs have not explained the photos, and a reading that scores higher than they do and makes
    more of the peaks joins without the gain: photo-like seed-97 plain_000 (2.2 px per yarn behind a
    1.9-px blur, turned 3.02 degrees), whose plain comb lattice (66 % off) scores 1.15 and makes 0.06 of
    the peak strength, and the reading from the reflection's (1, 1) peak 1.3 and 0.26."""
    best = max((lat.score for lat in found), default=0.0)
    read = anchored(spectra, signatures, a_range, b_range, square, rotation_deg, skew_deg)
    polished = _polished(spectra, signatures, [(lat.a, lat.b) for lat in read], a_range, b_range, square,
                         rotation_deg, skew_deg)
    joined = [lat for lat in polished if lat.score > ANCHOR_GAIN * best]
    rest = [lat for lat in polished if best < lat.score <= ANCHOR_GAIN * best]
    if rest:
        covered = max((peak_coverage(spectra, lat.a, lat.b, rotation_deg, skew_deg) for lat in found), default=0.0)
        if covered < LOW_COVERAGE:
            joined += [lat for lat in rest if peak_coverage(spectra, lat.a, lat.b, rotation_deg, skew_deg) > covered]
    return sorted(found + joined, key=lambda lat: -lat.score)[:top]


def _polished(spectra: Spectra, signatures, starts, a_range, b_range, square: bool,
              rotation_deg: float, skew_deg: float) -> list[Lattice]:
    """Each distinct start (a, b) inside the ranges, polished."""
    seen, out = set(), []
    for a, b in starts:
        if not (a_range[0] <= a <= a_range[1] and b_range[0] <= b <= b_range[1]):
            continue
        key = (round(a, 1), round(b, 1))
        if key in seen:
            continue
        seen.add(key)
        out.append(polish(spectra.maps, signatures, Lattice(a, b, 0.0), spectra.size, square, span=0.004,
                          step=0.0002, rotation_deg=rotation_deg, skew_deg=skew_deg))
    return out


ANCHOR_GAIN = 1.25
ANCHOR_PEAKS = 4
ANCHOR_HARMONICS = 4


def anchored(spectra: Spectra, signatures: list[Signature], a_range, b_range, square: bool,
             rotation_deg: float, skew_deg: float, peaks: int = ANCHOR_PEAKS, harmonics: int = ANCHOR_HARMONICS,
             keep: int = 6) -> list[Lattice]:
    """Lattices read from single peaks: each of an image's ``peaks`` strongest peaks p (or -p) taken
    as one of its signature's ``harmonics`` strongest oblique harmonics (m, n), both non-zero, and
    turned back by ``rotation_deg`` and ``skew_deg`` into fabric frequencies (f1, f2): (a, b) = (f1 / m, f2 / n); the
    ``keep`` best by signature score.

    A dense weave behind a phone's blur can leave a single low harmonic standing (a twill's
    diagonal, with side bands from uneven yarn spacing); no comb on one axis explains it, but its
    position alone pins the lattice once the harmonic is named. The peak is taken as it is, not as
    an alias: what survives the optics' blur lies below Nyquist (an aliased reading of a clean
    render's peaks can explain a signature at a wrong lattice; see
    :func:`backend.texture.candidates.placed`)."""
    size = spectra.size
    hyp_a, hyp_b = [], []
    for image_peaks, sig in zip(spectra.peaks, signatures):
        oblique = [(m, n) for m, n in zip(sig.m, sig.n) if m != 0 and n != 0][:harmonics]
        for p in image_peaks[:peaks]:
            for sign in (1.0, -1.0):
                f1, f2 = fabric_frequencies(np.array([sign * p.fx]), np.array([sign * p.fy]), rotation_deg,
                                            skew_deg)
                for m, n in oblique:
                    hyp_a.append(f1 / m)
                    hyp_b.append(f2 / n)
    if not hyp_a:
        return []
    a, b = np.concatenate(hyp_a), np.concatenate(hyp_b)
    if square:
        b = a
    ok = (a >= a_range[0]) & (a <= a_range[1]) & (b >= b_range[0]) & (b <= b_range[1])
    a, b = a[ok], b[ok]
    if a.size == 0:
        return []
    scores = signature_score(spectra.maps, signatures, a, b, size, rotation_deg, skew_deg)
    best = np.argsort(-scores, kind="stable")[:keep]
    return [Lattice(float(a[i]), float(b[i]), float(scores[i])) for i in best]
