"""Registering a photo pair: one framing for both photos, so that one yarn lattice explains both.

The two photos are taken by hand, one after the other; the phone moves a little between them, and
the same fabric can show its lattice magnified and turned by several percent and a degree in one
of them. The model has one framing for both; fitted as they are, no lattice fits both photos and
the fit washes the weave out to a compromise. The map between the two lattices is linear in
frequency:

    k_R = A k_T          (cycles per image, fx to the right, fy down the image; A is 2 x 2)

:func:`lattice_map` finds A by least squares over matched spectral peaks
(:func:`.spectrum.spectral_peaks`): the transmission photo's peaks magnified by the framing check's
scale (:func:`.pair_checks.best_lattice_scale`) are matched to the reflection's within
START_TOLERANCE (relative); then, ROUNDS times, peaks within MATCH_CYCLES of their prediction
A q are matched and A is fitted again.

The photo whose lattice is denser shows more fabric; it is magnified about the image centre c by
the inverse map, which needs only pixels inside it (a function g(c + M (x - c)) has its peaks at
M^T k):

    R'(x) = R(c + A^-T (x - c))    when det A > 1,        T'(x) = T(c + A^T (x - c))   otherwise.

:func:`register` does this only on clear evidence: at least MIN_MATCHES peaks matched, a residual
under MAX_RESIDUAL cycles (RMS), and a map that moves the matched peaks by more than MIN_SHIFT
cycles and by more than SHIFT_OVER_RESIDUAL times the residual (RMS). One sample's non-uniform yarn
spacing alone moves the fitted map off the identity: the two photos weigh different parts of the
fabric (the reflection its lit top, the transmission its glowing centre), by a cycle or two where
a moved phone shifts the peaks by many. A magnification past MAX_MAGNIFICATION is left alone (the
framing check refuses such a pair, or has called its ratio one of the lattice's own harmonics).

Where the framing check's scale finds no clear map (the two photos' strongest peaks can be different
harmonics of the lattice, as a satin's or a plain weave's reflection and transmission show: the
check then reads a ratio such as 0.69), the map is sought again from every start on a log grid over
[1 / MAX_MAGNIFICATION, MAX_MAGNIFICATION] (:data:`START_SCAN_STEP`), and of the clear maps found with
at least SCANNED_MIN_MATCHES peaks and no more shear than SCANNED_MAX_SHEAR (:func:`shear`: a phone
moved between the shots turns and zooms the framing; a map that only some harmonics agree with by
chance need not) the one whose matched peaks are the strongest in all (the sum over its matches of
the weaker peakness of the two) is kept.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..core.threads import ordered_map
from .spectrum import spectral_peaks

START_TOLERANCE = 0.03      # relative: first matches, at the framing check's scale
MATCH_CYCLES = 1.0          # cycles per image: later matches, around the fitted map's prediction
ROUNDS = 4                  # refits of the map after the first
MIN_MATCHES = 4             # peaks a map needs to be trusted (it has four unknowns)
MAX_RESIDUAL = 0.75         # cycles (RMS): matched peaks must agree with one linear map
MIN_SHIFT = 3.0             # cycles (RMS): smaller moves are the fabric's own uneven spacing
SHIFT_OVER_RESIDUAL = 2.0   # the move must stand clear of the map's own misfit
MAX_MAGNIFICATION = 1.2     # beyond: a framing the check refuses, or a harmonic of the lattice
START_SCAN_STEP = 0.015     # log step of the scanned starts: half START_TOLERANCE (each move well within one's reach)
SCANNED_MIN_MATCHES = 6     # a map only a scanned start finds: of many starts, 4-5 peaks can fit a wrong one by chance
SCANNED_MAX_SHEAR = 0.015   # and it must be a turn and a zoom (a phone's move) within this part: chance maps shear


@dataclass(frozen=True)
class Registration:
    """What :func:`register` did: ``matrix`` A (k_R = A k_T), the peaks matched, the fit's residual
    and the matched peaks' shift under A (RMS, cycles per image)."""

    matrix: tuple[tuple[float, float], tuple[float, float]]
    matches: int
    residual: float
    shift: float
    scanned: bool = False  # found from the scan of starts, not from the framing check's scale

    @property
    def scale(self) -> float:
        """How much denser the reflection's lattice is than the transmission's: sqrt(det A)."""
        return math.sqrt(float(np.linalg.det(np.asarray(self.matrix))))

    @property
    def moved(self) -> str:
        """The photo that was magnified: the one whose lattice is denser."""
        return "reflection" if self.scale > 1 else "transmission"

    @property
    def magnification(self) -> float:
        """How much the moved photo was magnified."""
        return max(self.scale, 1.0 / self.scale)

    @property
    def turn_deg(self) -> float:
        """The turn between the two lattices (degrees, the rotation part of A)."""
        a = np.asarray(self.matrix)
        return math.degrees(math.atan2(a[1, 0] - a[0, 1], a[0, 0] + a[1, 1]))

    @property
    def photo_map(self) -> np.ndarray:
        """M of the moved photo P: its registered image is P(c + M (x - c)) (A^-T for the reflection,
        A^T for the transmission; module docstring)."""
        a = np.asarray(self.matrix, dtype=float)
        return np.linalg.inv(a).T if self.moved == "reflection" else a.T

    def as_taken(self, image: np.ndarray) -> np.ndarray:
        """An image in the registered framing (a re-render) carried into the moved photo's own framing:
        image(c + M^-1 (y - c)), bicubic (a render has no noise for it to sharpen). Outside
        :meth:`seen_margin` it holds edge reflections."""
        return magnified(image, np.linalg.inv(self.photo_map), cv2.INTER_CUBIC)

    def seen_margin(self, size: int) -> int:
        """The margin (px) of the largest centred square of the moved photo (``size`` px) inside what
        its registered image holds: a square of half-width r maps into the registered one (half-width
        c = (size - 1) / 2) when r ||M^-1||_inf <= c (the row-sum norm)."""
        centre = (size - 1) / 2.0
        half = centre / float(np.abs(np.linalg.inv(self.photo_map)).sum(axis=1).max())
        return max(0, math.ceil(centre - half - 1e-9))

    def to_dict(self) -> dict:
        return {"matrix": [list(row) for row in self.matrix], "moved": self.moved, "matches": self.matches,
                "residual_cycles": round(self.residual, 4), "shift_cycles": round(self.shift, 4),
                "magnification": round(self.magnification, 5), "turn_deg": round(self.turn_deg, 4),
                "start": "scan" if self.scanned else "framing check"}


def lattice_map(reflection: np.ndarray, transmission: np.ndarray, scale: float, workers: int = 1
                ) -> tuple[np.ndarray, int, float, float] | None:
    """(A, peaks matched, residual, shift): the linear map of the transmission photo's spectral peaks
    onto the reflection's (module docstring), starting from the magnification ``scale``; None when
    fewer than three peaks match. The two photos' peaks are read on up to ``workers`` threads."""
    found = _fitted_map(*_peaks(reflection, transmission, workers), scale)
    return None if found is None else found[:4]


def _peaks(reflection: np.ndarray, transmission: np.ndarray, workers: int) -> tuple[np.ndarray, ...]:
    """(reflection peaks, their peakness, transmission peaks, theirs): (K, 2) cycles per image and (K,)."""
    out = []
    for peaks in ordered_map(spectral_peaks, (reflection, transmission), workers):
        out += [np.array([(p.fx, p.fy) for p in peaks], dtype=float).reshape(-1, 2),
                np.array([p.strength for p in peaks], dtype=float)]
    return tuple(out)


def _fitted_map(ref: np.ndarray, ref_strength: np.ndarray, trans: np.ndarray, trans_strength: np.ndarray,
                scale: float) -> tuple[np.ndarray, int, float, float, float] | None:
    """:func:`lattice_map` of the peaks, and the matched peaks' strength (the sum over the matches of
    the weaker peakness of the two)."""
    if len(ref) < 3 or len(trans) < 3:
        return None
    matrix = scale * np.eye(2)
    for round_ in range(ROUNDS + 1):
        predicted = trans @ matrix.T
        tolerance = START_TOLERANCE * np.linalg.norm(ref, axis=1) if round_ == 0 else np.full(len(ref), MATCH_CYCLES)
        q, p, strength = _matched(ref, predicted, trans, tolerance, ref_strength, trans_strength)
        if len(q) < 3:
            return None
        matrix = np.linalg.lstsq(q, p, rcond=None)[0].T
    residual = float(np.sqrt(np.mean(np.sum((q @ matrix.T - p) ** 2, axis=1))))
    shift = float(np.sqrt(np.mean(np.sum((q @ (matrix - np.eye(2)).T) ** 2, axis=1))))
    return matrix, len(q), residual, shift, strength


def _clear(found, min_matches: int = MIN_MATCHES) -> bool:
    """Whether a :func:`_fitted_map` is clear evidence of a move (module docstring)."""
    if found is None:
        return False
    matrix, matches, residual, shift = found[:4]
    det = float(np.linalg.det(matrix))
    return (matches >= min_matches and residual <= MAX_RESIDUAL and shift > MIN_SHIFT
            and shift > SHIFT_OVER_RESIDUAL * residual and det > 0
            and 1 / MAX_MAGNIFICATION ** 2 <= det <= MAX_MAGNIFICATION ** 2)


def scanned_starts() -> np.ndarray:
    """The starting magnifications of the scan (module docstring): a log grid over
    [1 / MAX_MAGNIFICATION, MAX_MAGNIFICATION] at START_SCAN_STEP."""
    span = math.log(MAX_MAGNIFICATION)
    return np.exp(np.arange(-span, span + 1e-9, START_SCAN_STEP))


def shear(matrix: np.ndarray) -> float:
    """How far A is from a turn and a zoom: |A - S| / sqrt(det S), S = [[p, -q], [q, p]] the nearest
    similarity (p, q the means of A's diagonal and of its antisymmetric part)."""
    a = np.asarray(matrix, dtype=float)
    p, q = 0.5 * (a[0, 0] + a[1, 1]), 0.5 * (a[1, 0] - a[0, 1])
    return float(np.linalg.norm(a - np.array([[p, -q], [q, p]])) / math.hypot(p, q))


def _scanned_map(peaks: tuple[np.ndarray, ...]):
    """Of the clear maps (:func:`_clear`, SCANNED_MIN_MATCHES peaks, SCANNED_MAX_SHEAR) found from
    :func:`scanned_starts`, the one with the strongest matched peaks; None where there is none."""
    found = [_fitted_map(*peaks, float(start)) for start in scanned_starts()]
    clear = [f for f in found if _clear(f, SCANNED_MIN_MATCHES) and shear(f[0]) <= SCANNED_MAX_SHEAR]
    return max(clear, key=lambda f: f[4]) if clear else None


def _matched(ref: np.ndarray, predicted: np.ndarray, trans: np.ndarray, tolerance: np.ndarray,
             ref_strength: np.ndarray, trans_strength: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(transmission peaks, reflection peaks, their strength) matched: each reflection peak with the
    nearest predicted transmission peak (either sign: a spectrum is symmetric) within its tolerance;
    the strength is the sum over the matches of the weaker peakness of the two."""
    q, p, strength = [], [], 0.0
    for k, peak in enumerate(ref):
        plus = np.linalg.norm(predicted - peak, axis=1)
        minus = np.linalg.norm(predicted + peak, axis=1)
        distance = np.minimum(plus, minus)
        best = int(np.argmin(distance))
        if distance[best] <= tolerance[k]:
            q.append(trans[best] if plus[best] <= minus[best] else -trans[best])
            p.append(peak)
            strength += min(float(ref_strength[k]), float(trans_strength[best]))
    return np.asarray(q, dtype=float).reshape(-1, 2), np.asarray(p, dtype=float).reshape(-1, 2), strength


def magnified(image: np.ndarray, matrix: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    """``image`` sampled at c + M (x - c) (pixel centres, x = (column, row)): bilinear unless told,
    edges reflected (a turn can reach a few pixels past a corner)."""
    h, w = image.shape[:2]
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    affine = np.hstack([matrix, (centre - matrix @ centre)[:, None]]).astype(np.float64)
    out = cv2.warpAffine(np.ascontiguousarray(image, dtype=np.float32), affine, (w, h),
                         flags=interpolation | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT)
    return out.astype(image.dtype, copy=False)


def register(reflection: np.ndarray, transmission: np.ndarray, scale: float | None, workers: int = 1
             ) -> tuple[np.ndarray, np.ndarray, Registration | None]:
    """The pair with one photo magnified onto the other's framing (module docstring), and what was
    done (None, and the photos as they are, when the evidence is not clear). ``scale``: the framing
    check's (None: the check did not compare the photos, and they are left as they are)."""
    if scale is None:
        return reflection, transmission, None
    peaks = _peaks(reflection, transmission, workers)
    found = _fitted_map(*peaks, scale) if 1 / MAX_MAGNIFICATION <= scale <= MAX_MAGNIFICATION else None
    scanned = not _clear(found)
    if scanned:
        found = _scanned_map(peaks)
    if found is None:
        return reflection, transmission, None
    matrix, matches, residual, shift = found[:4]
    done = Registration(tuple(tuple(float(x) for x in row) for row in matrix), matches, residual, shift, scanned)
    if done.moved == "reflection":
        return magnified(reflection, done.photo_map), transmission, done
    return reflection, magnified(transmission, done.photo_map), done
