"""Pair checks: are the two photos one fabric, framed alike, and given in the right order?

Computed on the working images (before any flat-field division) by :func:`.photos.load_pair`.

Content
    A photo that cannot show a fabric is refused (:func:`check_content`): black (even its brightest
    pixels, the 99.9th percentile of linear luminance, under 0.2 % of full scale: a covered lens or a
    lamp that did not fire), overexposed (more than half of its pixels clipped in some channel), or
    featureless (its linear luminance spans under FEATURELESS_SPREAD of its mean between the 1st
    and 99th percentiles: a uniform fill shows neither yarns nor noise nor the rig's light falloff).
    A pair in which neither photo shows a yarn pattern (:func:`yarn_peaks` finds no peak in either
    spectrum: a blank wall, a photo out of focus) is refused too; one photo without is a warning
    (a transmission photo of a dense fabric may show little). A photo whose sharpest spectral peak
    does not stand above what noise alone shows (:func:`check_weave_shown`) is a warning too: the
    yarn lattice and the sample's placement are then read from the other photo, or are guesses.
    Two photos holding the same pixels once decoded (one photo given twice) are refused
    (:func:`check_not_the_same`).

Framing
    The two source images must have the same pixel size (:func:`check_source_sizes`, else
    :class:`PhotoError`). The same fabric on the same stand shows the same yarn lattice, so the peaks
    of the two luminance power spectra (:func:`yarn_peaks`, lighting gradient removed) must coincide
    within 5 %. When they do not, the magnification that best aligns them (:func:`best_lattice_scale`)
    tells a framing difference: more than 20 %, with REFUSE_MATCHES peaks agreeing on it at a ratio
    that is not harmonic, is refused; anything less certain is a warning
    (:func:`check_framing_frequency`). The two photos may emphasise different peaks of one lattice (a
    satin's diagonals in reflection, its yarn gaps in transmission), hence the comparison of peak
    sets, not of single peaks.
Order
    The front light sits above the top edge of the image, so a reflection photo is brighter towards
    the top; the back light sits behind the image centre, so a transmission photo is even from top to
    bottom, with a centred glow (:func:`order_cues`, :func:`order_score`). :func:`check_order` gives
    the reasons to believe the photos are swapped; the caller makes them warnings or errors.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from ..core.threads import ordered_map
from .errors import PhotoError
from .spectrum import chance_peakness, hann, highpass, power_spectrum, shows_weave, spectral_peaks
from .tone import GAMMA, luminance

BLACK_LEVEL = 0.002      # linear: brightest pixels (99.9th percentile) under it, the photo is black
CLIPPED_LEVEL = 0.995    # display value of a clipped channel
MAX_CLIPPED = 0.5        # share of pixels clipped in some channel over which a photo is overexposed
# A photo whose linear luminance spans (1st to 99th percentile) less than this share of its mean shows
# nothing: no texture, no sensor noise, not even the rig's light falloff (a uniform fill, a blank).
# Usable photos span many times more; 8-bit levels 127-129 alone span about 0.035.
FEATURELESS_SPREAD = 0.02
TOP_BIAS_THRESHOLD = 0.35  # log(top / bottom brightness) that tells a front-lit photo (check_order)
FREQUENCY_TOLERANCE = 0.05  # relative distance within which two spectral peaks are one
FRAMING_REFUSE = 0.20      # framing ratio off 1 beyond which strong evidence refuses a pair
MIN_YARN_CYCLES = 16       # cycles per image: below, the lighting's spectrum, not the yarns'
MAX_PEAKS = 8              # spectral peaks kept per photo
MIN_PEAK_POWER = 0.05      # a kept peak's power, relative to the strongest
MIN_PEAK_PROMINENCE = 10.0  # the strongest peak over the median power: below, no clear yarn pattern
HARMONIC_RATIOS = (2.0, 1.5, 4 / 3, 3 / 4, 2 / 3, 0.5)  # ratios the two photos of one lattice can show
HARMONIC_TOLERANCE = 0.03  # |log(scale / ratio)| within which a framing ratio is one of HARMONIC_RATIOS
SAME_DIRECTION_DEG = 3.0   # peaks this close in direction may be one lattice magnified (the stand does not turn)
DISTINCT_DIRECTION_DEG = 10.0  # two peaks this far apart in direction span the lattice
# Peaks that must agree on a framing ratio for a refusal: a phone moved between the shots moves a
# harmonic ratio by as much as the harmonic tolerance, and two peaks can agree on such a ratio.
REFUSE_MATCHES = 3


def check_not_the_same(reflection: np.ndarray, transmission: np.ndarray, label: str) -> None:
    """Refuses a pair whose two photos hold the same pixels once decoded (source pixels, before any
    crop): the same file given twice, or one photo saved twice losslessly. A copy saved otherwise (a
    JPEG of the other) differs in its pixels and is not refused here: it reads as two photos lit by
    the same light, which the order check (:func:`check_order`) flags."""
    if reflection.shape == transmission.shape and reflection.dtype == transmission.dtype \
            and np.array_equal(reflection, transmission):
        raise PhotoError(f"{label}: the two photos are the same image (the same pixels once decoded): give the "
                         "reflection photo (front light) and the transmission photo (back light)")


def check_source_sizes(reflection_size: tuple[int, int], transmission_size: tuple[int, int], label: str) -> None:
    """Refuses a pair whose photos, (width, height) in pixels, differ in size."""
    if reflection_size != transmission_size:
        raise PhotoError(f"{label}: the photos are framed differently: {reflection_size[0]} x {reflection_size[1]} "
                         f"vs {transmission_size[0]} x {transmission_size[1]} pixels; take both from the same "
                         "stand with the same camera settings")


def order_cues(image: np.ndarray) -> dict[str, float]:
    """Lighting cues of a working image, from its linear luminance.

    top_bias: log(mean of the top quarter of rows / mean of the bottom quarter). The front light
        above the top edge makes reflection photos brighter at the top (default rig: about 1/d^2 =
        2.6x from the bottom to the top edge); the back light behind the centre leaves transmission
        photos symmetric (about 0).
    centre_glow: log(mean within 0.08 size of the centre / mean of the ring 0.2 .. 0.3 size). The
        back light, and its out-of-focus glow through the gaps, peak at the centre; vignetting, the
        same in both photos, adds the same amount to both.
    """
    lum = luminance(np.asarray(image, dtype=np.float32) ** np.float32(GAMMA))
    n = lum.shape[0]
    quarter = max(n // 4, 1)
    eps = 1e-6
    top_bias = math.log((lum[:quarter].mean() + eps) / (lum[-quarter:].mean() + eps))
    yy, xx = np.mgrid[0:n, 0:n] + 0.5
    radius = np.hypot(yy - n / 2, xx - n / 2) / n
    centre = lum[radius < 0.08].mean()
    ring = lum[(radius >= 0.2) & (radius < 0.3)].mean()
    centre_glow = math.log((centre + eps) / (ring + eps))
    return {"top_bias": top_bias, "centre_glow": centre_glow}


def order_score(reflection_cues: dict, transmission_cues: dict) -> float:
    """Positive when the pair reads as given: (top_bias_R - top_bias_T) + (centre_glow_T - centre_glow_R)."""
    return ((reflection_cues["top_bias"] - transmission_cues["top_bias"])
            + (transmission_cues["centre_glow"] - reflection_cues["centre_glow"]))


def check_order(reflection_cues: dict, transmission_cues: dict) -> list[str]:
    """Reasons to believe the photos are swapped (or mislabelled); empty when the order looks right.

    Three tests, each from the rig's geometry:
    - the transmission photo has top_bias >= 0.35 (top quarter 1.4x brighter than the bottom): it
      looks lit by the front light;
    - the reflection photo has top_bias < 0.35: it does not look lit by the front light;
    - the order score (:func:`order_score`) is negative: the pair reads better the other way round.
    Real pairs and renders in order pass all three with a wide margin; swapped, they fail all three.
    """
    reasons = []
    ratio_t = math.exp(transmission_cues["top_bias"])
    ratio_r = math.exp(reflection_cues["top_bias"])
    limit = math.exp(TOP_BIAS_THRESHOLD)
    if transmission_cues["top_bias"] >= TOP_BIAS_THRESHOLD:
        reasons.append(f"the transmission photo is {ratio_t:.2f}x brighter at the top than at the bottom, like a "
                       "photo lit by the front light above the top edge "
                       f"(a back-lit photo is even: below {limit:.2f}x)")
    if reflection_cues["top_bias"] < TOP_BIAS_THRESHOLD:
        reasons.append(f"the reflection photo is only {ratio_r:.2f}x brighter at the top than at the bottom; "
                       f"the front light above the top edge makes it at least {limit:.2f}x")
    score = order_score(reflection_cues, transmission_cues)
    if score < 0:
        reasons.append(f"the lighting cues favour the opposite order (score {score:+.2f}: top brightness and "
                       "centred glow of the two photos)")
    return reasons


def yarn_peaks(image: np.ndarray) -> list[tuple[float, float, float]]:
    """Dominant peaks of the luminance power spectrum: (fx, fy, power relative to the strongest).

    Frequencies are in cycles per image width (fx, to the right) and height (fy, downwards), one of
    each +-f pair (fy > 0, or fy == 0 and fx > 0). The lighting gradient, glow and vignetting are
    removed first (:func:`.spectrum.highpass` of sigma size / 64, so under about 16 cycles), the detail is
    normalised by its local contrast (so the bright centre does not dominate) and windowed (Hann).
    Peaks are local maxima of the lightly smoothed spectrum above 16 cycles, at most 8, each at least
    5 % of the strongest. Empty when the strongest stands less than 10x above the median power: no
    clear yarn pattern.
    """
    n = image.shape[0]
    detail = highpass(luminance(np.asarray(image, dtype=np.float32)), n / 64)
    contrast = np.sqrt(cv2.GaussianBlur(detail * detail, (0, 0), n / 16, borderType=cv2.BORDER_REFLECT))
    power = power_spectrum(detail / (contrast + 1e-4) * hann(n, n))
    freqs = np.fft.fftshift(np.fft.fftfreq(n, 1.0 / n))
    fy, fx = np.meshgrid(freqs, freqs, indexing="ij")
    usable = np.hypot(fx, fy) >= MIN_YARN_CYCLES
    power = np.where(usable, power, 0.0).astype(np.float32)
    smooth = cv2.GaussianBlur(power, (0, 0), 1.0)
    if not usable.any() or smooth.max() <= 0:
        return []
    if smooth.max() < MIN_PEAK_PROMINENCE * np.median(smooth[usable]):
        return []
    is_max = smooth == cv2.dilate(smooth, np.ones((7, 7), np.uint8))
    half = (fy > 0) | ((fy == 0) & (fx > 0))
    rows, cols = np.nonzero(is_max & half & usable & (smooth >= MIN_PEAK_POWER * smooth.max()))
    order = np.argsort(-smooth[rows, cols])[:MAX_PEAKS]
    top = smooth[rows[order[0]], cols[order[0]]]
    return [(float(fx[rows[i], cols[i]]), float(fy[rows[i], cols[i]]), float(smooth[rows[i], cols[i]] / top))
            for i in order]


def frequency_mismatch(peaks_a: Sequence, peaks_b: Sequence) -> float | None:
    """Relative distance from one image's strongest peak to the nearest peak (+-f) of the other.

    Taken both ways round, the smaller wins: the two photos light the same yarn lattice differently
    (a reflection photo of a satin shows its diagonals, the transmission photo its yarn gaps), so it
    is enough that one strongest peak appears in the other spectrum. None when either has no peaks.
    """
    if not peaks_a or not peaks_b:
        return None
    return float(min(_nearest_peak(peaks_a[0], peaks_b), _nearest_peak(peaks_b[0], peaks_a)))


def _nearest_peak(peak: Sequence[float], others: Sequence, scale: float = 1.0) -> float:
    """Relative distance |p - s q| / |p| from ``peak`` to the nearest of ``others`` (either sign)."""
    p = np.asarray(peak[:2], dtype=float)
    q = scale * np.asarray([o[:2] for o in others], dtype=float)
    distances = np.minimum(np.hypot(*(q - p).T), np.hypot(*(q + p).T))
    return float(distances.min() / max(np.hypot(*p), 1e-9))


def lattice_match(peaks_a: Sequence, peaks_b: Sequence, scale: float) -> tuple[float, int]:
    """How well ``peaks_a`` and ``peaks_b`` magnified by ``scale`` coincide: (score, peaks matched).

    A peak of a is matched by a peak of b within 5 % (relative); the score adds min(power a, power b)
    over the matched peaks of a, so two dominant peaks agreeing count 1.
    """
    score, matched = 0.0, 0
    for peak in peaks_a:
        hits = [min(peak[2], other[2]) for other in peaks_b
                if _nearest_peak(peak, [other], scale) <= FREQUENCY_TOLERANCE]
        if hits:
            score, matched = score + max(hits), matched + 1
    return score, matched


def _direction_gap(p: Sequence[float], q: Sequence[float]) -> float:
    """The angle (radians, 0 to pi / 2) between the lines of two peaks (a peak is one of a +-f pair)."""
    angle = abs(math.atan2(p[1], p[0]) - math.atan2(q[1], q[0])) % math.pi
    return min(angle, math.pi - angle)


def with_lattice_combinations(peaks: Sequence) -> list:
    """``peaks`` joined by the sum and the difference of the strongest two that point different ways
    (over 10 degrees apart), each as strong as the weaker of the two: the lattice's other low
    harmonics, which the other photo of the pair may show instead. A plain weave's reflection shows
    its checkerboard's diagonals (1, 1) and (-1, 1); its transmission shows the gaps between the
    yarns, (2, 0) and (0, 2), their sum and difference: at a few pixels per yarn the two photos of a
    plain weave often share no peak directly."""
    if len(peaks) < 2:
        return list(peaks)
    p = peaks[0]
    for q in peaks[1:]:
        if _direction_gap(p, q) > math.radians(DISTINCT_DIRECTION_DEG):
            power = min(p[2], q[2])
            return [*peaks, (p[0] + q[0], p[1] + q[1], power), (p[0] - q[0], p[1] - q[1], power)]
    return list(peaks)


def same_lattice_score(peaks_a: Sequence, peaks_b: Sequence) -> float:
    """How well the two photos' peaks coincide at scale 1, as :func:`lattice_match` scores them, where
    each photo's peaks may also match the other's :func:`with_lattice_combinations` (the better of the
    two ways round)."""
    return max(lattice_match(peaks_a, with_lattice_combinations(peaks_b), 1.0)[0],
               lattice_match(peaks_b, with_lattice_combinations(peaks_a), 1.0)[0])


def best_lattice_scale(peaks_a: Sequence, peaks_b: Sequence) -> tuple[float, float, int]:
    """The magnification of b's lattice that best matches a's: (scale, score, peaks matched).

    Candidates are the length ratios of peak pairs pointing the same way (within 3 degrees, the stand
    does not rotate the camera), between 0.5 and 2.
    """
    best = (1.0, *lattice_match(peaks_a, peaks_b, 1.0))
    for p in peaks_a:
        for q in peaks_b:
            if _direction_gap(p, q) > math.radians(SAME_DIRECTION_DEG):
                continue
            scale = math.hypot(p[0], p[1]) / max(math.hypot(q[0], q[1]), 1e-9)
            if 0.5 <= scale <= 2.0:
                candidate = (scale, *lattice_match(peaks_a, peaks_b, scale))
                if candidate[1] > best[1] + 1e-9:
                    best = candidate
    return best


def _harmonic(scale: float) -> bool:
    """Whether ``scale`` is within 3 % of a ratio of small harmonics (2, 3/2, 4/3 or their inverses)."""
    return any(abs(math.log(scale / ratio)) < HARMONIC_TOLERANCE for ratio in HARMONIC_RATIOS)


def _describe_peak(peak) -> str:
    return f"{math.hypot(peak[0], peak[1]):.0f} cycles per image at ({peak[0]:+.0f}, {peak[1]:+.0f})"


def check_content(image: np.ndarray, path: Path) -> None:
    """Refuses a working image that is black, overexposed or featureless (:class:`PhotoError` naming
    ``path``)."""
    image = np.asarray(image, dtype=np.float32)
    linear = luminance(np.clip(image, 0, 1) ** np.float32(GAMMA))
    bright = float(np.percentile(linear, 99.9))
    if bright < BLACK_LEVEL:
        raise PhotoError(f"{path}: the photo is black (its brightest pixels reach {bright:.2%} of full scale): "
                         "check that the lamp was on and the lens uncovered")
    clipped = float((image >= CLIPPED_LEVEL).any(axis=-1).mean())
    if clipped > MAX_CLIPPED:
        raise PhotoError(f"{path}: the photo is overexposed ({clipped:.0%} of its pixels are clipped): "
                         "lower the exposure so the fabric's highlights stay below white")
    low, high = np.percentile(linear, (1, 99))
    spread = float(high - low) / max(float(linear.mean()), 1e-12)
    if spread < FEATURELESS_SPREAD:
        raise PhotoError(f"{path}: the photo is featureless (its pixels' brightness spans {spread:.1%} of its "
                         "mean: no yarns, no noise, no light falloff): check that it is a photo of the sample, "
                         "not a blank or filled image")


def check_framing_frequency(reflection: np.ndarray, transmission: np.ndarray, names: tuple[Path, Path],
                            compare: bool = True) -> tuple[list[str], dict]:
    """Compares the yarn lattices of the two working images (not with ``compare`` off: one photo
    shows no weave, :func:`check_weave_shown`, and its peaks are noise that no framing explains).

    The photos agree when their peaks coincide at scale 1 (:func:`same_lattice_score`: the two photos
    may show different low harmonics of the same lattice) at least half as well as at the best scale
    (:func:`best_lattice_scale`). Otherwise (:func:`_framing_verdict`): when the best scale is more
    than FRAMING_REFUSE away from 1, at least REFUSE_MATCHES peaks agree on it and it is not a ratio
    of small harmonics (:data:`HARMONIC_RATIOS`), the photos were framed at different scales (or
    show different fabrics): :class:`PhotoError`; within FRAMING_REFUSE, or with less evidence, a
    warning.
    """
    peaks_r, peaks_t = yarn_peaks(reflection), yarn_peaks(transmission)
    info = {"reflection": [list(p[:2]) for p in peaks_r], "transmission": [list(p[:2]) for p in peaks_t],
            "mismatch": frequency_mismatch(peaks_r, peaks_t), "scale": None}
    label = f"{names[0]} / {names[1]}"
    if not peaks_r and not peaks_t:
        raise PhotoError(f"{label}: neither photo shows a yarn pattern (no peak in either spectrum): photograph "
                         "the fabric flat and in focus, close enough that its yarns show")
    if not compare:
        return [], info
    if not peaks_r or not peaks_t:
        missing = [str(n) for n, p in zip(names, (peaks_r, peaks_t)) if not p]
        return [f"{', '.join(missing)}: no clear yarn pattern in the spectrum; the framing check was skipped"], info
    score_at_one = same_lattice_score(peaks_r, peaks_t)
    scale, score, matched = best_lattice_scale(peaks_r, peaks_t)
    info["scale"] = scale
    if score_at_one >= 0.5 * score and score_at_one > 0:
        return [], info
    return _framing_verdict(label, peaks_r, peaks_t, scale, matched), info


def _framing_verdict(label: str, peaks_r: Sequence, peaks_t: Sequence, scale: float, matched: int) -> list[str]:
    """The warning for a pair whose lattices agree best at ``scale`` (``matched`` peaks), or
    :class:`PhotoError` where that is clearly a different framing (:func:`check_framing_frequency`)."""
    dominant = (f"dominant yarn frequencies {_describe_peak(peaks_r[0])} (reflection) and "
                f"{_describe_peak(peaks_t[0])} (transmission)")
    if matched == 0:
        return [f"{label}: the yarn patterns share no spectral peak ({dominant}): check that both photos show the "
                "same fabric at the same scale"]
    zoom = f"the transmission photo's yarn lattice matches the reflection's magnified {scale:.2f}x"
    agree = f"{matched} matching peak{'s' if matched != 1 else ''}"
    # Refused only on REFUSE_MATCHES peaks agreeing on a ratio that is not harmonic: one photo may show 2f
    # where the other shows f, and a dense weave's aliased harmonics can match a peak at a chance ratio.
    strong = matched >= REFUSE_MATCHES and not _harmonic(scale)
    if abs(math.log(scale)) <= math.log(1 + FRAMING_REFUSE):
        return [f"{label}: {zoom} ({agree}; {dominant}): the photos may be framed at slightly "
                "different scales"]
    if not strong:
        return [f"{label}: {zoom} ({agree}; {dominant}): the photos may be framed at different scales, "
                f"but the evidence is weak (fewer than {REFUSE_MATCHES} peaks, or a harmonic ratio the same lattice "
                "can show, perhaps with the phone moved between the shots); "
                "check the framing if the fit looks wrong"]
    raise PhotoError(f"{label}: the photos are framed differently: {zoom} ({agree}; {dominant}), more "
                     f"than {FRAMING_REFUSE:.0%} off; the same fabric on the same stand shows the same yarn density "
                     "in both photos")


def check_weave_shown(reflection: np.ndarray, transmission: np.ndarray, names: tuple[Path, Path],
                      workers: int = 1) -> tuple[list[str], dict]:
    """Warnings for the photos whose spectrum shows no peak above noise (:func:`.spectrum.shows_weave`,
    the test the yarn lattice applies: :meth:`backend.texture.lattice.Spectra.of_the_weave`), and
    each photo's strongest peakness beside the level noise alone reaches. A dense weave behind a
    phone's blur can leave the transmission, or both photos, without a visible weave: the fit then
    reads the yarn lattice from the other photo, or has nothing to read it from. Each photo is read
    on one of up to ``workers`` threads."""
    size = reflection.shape[0]
    peaks = ordered_map(lambda image: spectral_peaks(image, count=1), (reflection, transmission), workers)
    strongest = [round(p[0].strength, 2) if p else 0.0 for p in peaks]
    chance = chance_peakness(size)
    info = {"reflection": strongest[0], "transmission": strongest[1], "noise_level": round(chance, 2)}
    shown = [shows_weave(p, size) for p in peaks]
    if all(shown):
        return [], info
    level = f"noise alone reaches {chance:.1f}"
    if not any(shown):
        return [f"{names[0]} / {names[1]}: neither photo shows its yarns above the noise (sharpest spectral peaks "
                f"{strongest[0]:.1f} and {strongest[1]:.1f}; {level}): the yarn density, the weave and the sample's "
                "turn are guesses; photograph the fabric closer (3 px or more per yarn) and in focus"], info
    hidden, seen = (1, 0) if shown[0] else (0, 1)
    return [f"{names[hidden]}: shows no yarn pattern above the noise (sharpest spectral peak {strongest[hidden]:.1f}; "
            f"{level}): the yarn density and the sample's turn are read from {names[seen]} alone, and the "
            "framing check was skipped"], info
