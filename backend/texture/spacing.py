"""The yarn spacing over the whole photo: a lattice's mean frequency read from the phase of its harmonics.

The spectral lattice (:mod:`.lattice`) reads peaks of a Hann-windowed spectrum, which weights the
photo's centre. A phone photo's yarn spacing is not even (a sample not quite flat, lens
distortion), so the centre's spacing can be a percent or more from the sample's mean, which is
what the material needs (yarns per cm) and what a re-render must match at the photo's edges.

The mean spacing is in the phase of the harmonics. For a harmonic h = (m, n) of the lattice (a, b)
(cycles per image), at image frequency f_h = turned(m a, n b) (:func:`.frequencies.turned_frequencies`),

    z_h(p)  = G_s * [ y(p) exp(-2 pi i f_h . p / N) ]          demodulated and low-passed
    s_h(p)  = z_h(p + e_x) conj(z_h(p))
    delta_x = N / (2 pi) arg sum_p s_h(p) / max(|s_h(p)|, median_p |s_h(p)|)   (and delta_y down the image)

where y is the high-passed luminance: the phase of z_h advances by 2 pi (f_true - f_h) . e per pixel
step e, and the sum averages it over the whole photo, every pixel where the harmonic shows at least
as strongly as at the median pixel alike (``EVEN_QUANTILE``), those where it is weaker less (there
noise, which has no steady phase, takes over): the harmonic's frequency is read as g_h = f_h + delta.
The plain sum, weighted by |z_h|^2, would read the spacing where the harmonic is strongest, and in
a transmission photo that is the centre, where the lamp's glow lights the gaps.

The yarn vectors' directions, which can decide the sample's turn
(:mod:`backend.texture.placement.votes`), are read from the power-weighted sum instead (g'_h, the
same steps s_h summed as they are): a candidate of the wrong pattern demodulates where its
harmonics barely show, and read evenly its vectors could come out unsheared at a wrong turn and
vote for it.

The harmonics read are the ``HARMONICS`` with the most power |Y_h|^2 in the Hann-windowed y, among
those whose power is ``SHOWN`` times the mean frequency bin's. Their frequencies g_h = m u + n v are
solved, least squares weighted by w = |Y_h|^2, for the yarn vectors u = a' (cos theta_1, -sin theta_1)
and v = b' (sin theta_2, cos theta_2); a' = |u| and b' = |v|. The lengths do not depend on the
placement's angles (turned back at angles a fraction of a degree off, one axis's frequency would
leak into the other's). Where the harmonics read do not pin both vectors (fewer than two independent
(m, n)), each axis's harmonics are turned back at the given angles
(:func:`.frequencies.fabric_frequencies`: (f1, f2)) and a' = sum w m f1 / sum w m^2, and b' likewise
with n. The power of the line itself weighs, not the mean of |z_h|^2: what the low-passed z holds
beyond a harmonic's own line, noise or a neighbour's tail, has no steady phase.

The filter G_s keeps the other harmonics out: the nearest one lies d cycles away, and s = 0.64 N / d
pixels puts it ``SEPARATION_SIGMAS`` standard deviations of the filter's response away. The
neighbours that count carry power: the pattern's signature and their mirrors (-f_h included),
folded at Nyquist, and the photo's light, which the high-pass of N / 64 px leaves up to
``LIGHT_BAND`` cycles from DC. A harmonic with a neighbour closer than ``MIN_SEPARATION`` cycles is
not read. Two passes: the second demodulates at the first's lattice.

Only the transmission photo is read (the reflection joins in when the transmission alone does not
pin both vectors): in reflection a harmonic rides on glints whose place on a yarn follows the half
vector, which turns across the photo, so its phase drifts by a fraction of a cycle over the image,
while light through the gaps shows where the yarns are.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..core.rig import placement_of
from ..image.spectrum import hann
from .frequencies import fabric_frequencies, fold, turned_frequencies, yarn_vector_angles
from .lattice import Lattice, Signature

HARMONICS = 4            # the strongest usable harmonics of a photo that are read
MIN_SEPARATION = 5.0     # cycles per image to the nearest other lattice harmonic
SEPARATION_SIGMAS = 4.0  # the nearest other harmonic, in standard deviations of the filter's response
PASSES = 2
SOLVABLE = 1e-3          # det / trace^2 of the harmonics' normal matrix below which they do not pin both axes
SHOWN = 10.0             # a harmonic is read when its power is this many times the mean frequency bin's
LIGHT_BAND = 64 / (2 * math.pi)  # cycles per image: the photo's light, as far as the high-pass of N / 64 px leaves it
EVEN_QUANTILE = 0.5      # pixels where a harmonic shows at least as strongly as at this quantile weigh alike


@dataclass(frozen=True)
class MeanSpacing:
    """A lattice at the mean spacing (:func:`mean_lattice`) and, where the harmonics read pin both
    yarn vectors, the placement they show: (rotation, skew) in degrees from the vectors' directions
    (u at theta_1 = rotation + skew / 2, v at theta_2 = rotation - skew / 2), read from the
    transmission alone or, where that does not pin both, with the reflection (``from_transmission``)."""

    lattice: Lattice
    placement: tuple[float, float] | None
    from_transmission: bool


def mean_lattice(transmission: np.ndarray, reflection: np.ndarray, start: Lattice,
                 signatures: tuple[Signature, Signature], rotation_deg: float = 0.0,
                 skew_deg: float = 0.0) -> MeanSpacing:
    """``start`` (a, b) moved to the mean spacing over the whole photo (module docstring), read from
    the transmission photo (``signatures``: the pattern's (reflection, transmission) signatures;
    the reflection joins in when the transmission alone does not pin both axes). ``transmission``
    and ``reflection`` are the photos' high-passed luminances y
    (:func:`backend.image.spectrum.highpassed_luminance` at N / 64 px, as :class:`.spectra.Spectra`
    keeps them). The score is ``start``'s; the placement is the last pass's."""
    a, b = start.a, start.b
    for _ in range(PASSES):
        read = _read(transmission, a, b, signatures[1], rotation_deg, skew_deg)
        from_transmission = read.solvable
        if not from_transmission:
            read = read + _read(reflection, a, b, signatures[0], rotation_deg, skew_deg)
        a, b = read.lattice(a, b)
    return MeanSpacing(Lattice(a, b, start.score), read.placement(), from_transmission)


@dataclass(frozen=True)
class _Reading:
    """The weighted sums of the harmonics read (w their power, g their frequency read evenly over the
    photo, g' read where they are strongest): ``normal`` sum w [[m m, m n], [n m, n n]], ``moments``
    sum w [[m g], [n g]] (2 x 2), ``turn_moments`` likewise with g', and ``projected`` sum w (m f1,
    m m, n f2, n n) with (f1, f2) = g turned back at the given angles."""

    normal: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    moments: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    turn_moments: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    projected: np.ndarray = field(default_factory=lambda: np.zeros(4))

    def __add__(self, other: "_Reading") -> "_Reading":
        return _Reading(self.normal + other.normal, self.moments + other.moments,
                        self.turn_moments + other.turn_moments, self.projected + other.projected)

    @property
    def solvable(self) -> bool:
        """Whether the harmonics read pin both yarn vectors (two independent (m, n) among them)."""
        trace = float(np.trace(self.normal))
        return trace > 0.0 and float(np.linalg.det(self.normal)) > SOLVABLE * trace ** 2

    def _solved(self, moments: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The yarn vectors (u, v) solved from g = m u + n v (cycles per image), None where the
        harmonics read do not pin both."""
        if not self.solvable:
            return None
        u, v = np.linalg.solve(self.normal, moments)
        return u, v

    def lattice(self, a: float, b: float) -> tuple[float, float]:
        """(a', b'): the lengths of the yarn vectors u, v read evenly; without two independent
        harmonics, each axis's harmonics turned back at the given angles (a or b as they were where
        none was read)."""
        vectors = self._solved(self.moments)
        if vectors is not None:
            u, v = vectors
            return float(np.hypot(*u)), float(np.hypot(*v))
        sum_m, m2, sum_n, n2 = (float(v) for v in self.projected)
        return (sum_m / m2 if m2 > 0.0 else a), (sum_n / n2 if n2 > 0.0 else b)

    def placement(self) -> tuple[float, float] | None:
        """(rotation, skew), degrees, of the yarn vectors u = |u| (cos theta_1, -sin theta_1),
        v = |v| (sin theta_2, cos theta_2) read where the harmonics are strongest (module docstring);
        None where the harmonics read do not pin both."""
        vectors = self._solved(self.turn_moments)
        if vectors is None:
            return None
        return placement_of(*yarn_vector_angles(*vectors))


@dataclass(frozen=True)
class Harmonic:
    """A lattice harmonic (m, n) as a photo shows it: its image frequency (fx, fy) (cycles per image),
    the width ``sigma`` (pixels) of the low-pass that keeps its neighbours out of its demodulated
    signal, and its power |Y_h|^2 in the Hann-windowed photo."""

    m: int
    n: int
    fx: float
    fy: float
    sigma: float
    power: float


def strongest_harmonics(y: np.ndarray, a: float, b: float, signature: Signature, rotation_deg: float,
                        skew_deg: float) -> list[Harmonic]:
    """The HARMONICS usable harmonics of ``signature`` at the lattice (a, b) with the most power in the
    high-passed luminance ``y`` (strongest first), each shown SHOWN times above the mean frequency bin."""
    size = y.shape[0]
    usable = []
    for m, n in zip(signature.m.tolist(), signature.n.tolist()):
        separation = _separation(m, n, a, b, signature, size, rotation_deg, skew_deg)
        if separation >= MIN_SEPARATION:
            usable.append((m, n, *turned_frequencies(m * a, n * b, rotation_deg, skew_deg), separation))
    if not usable:
        return []
    windowed = y * hann(size, size)
    power = np.array([abs(np.sum(_demodulated(windowed, fx, fy))) ** 2 for _, _, fx, fy, _ in usable])
    shown = power > SHOWN * np.sum(windowed ** 2)   # Parseval: the sum is the mean frequency bin's power
    return [Harmonic(*usable[k][:4], SEPARATION_SIGMAS / (2 * math.pi) * size / usable[k][4], float(power[k]))
            for k in np.argsort(power)[::-1][:HARMONICS] if shown[k]]


def _read(y: np.ndarray, a: float, b: float, signature: Signature, rotation_deg: float, skew_deg: float
          ) -> _Reading:
    """The :class:`_Reading` of the :func:`strongest_harmonics` of ``signature`` at the lattice (a, b)
    in the high-passed luminance ``y``."""
    reading = _Reading()
    for h in strongest_harmonics(y, a, b, signature, rotation_deg, skew_deg):
        even, strongest = _phase_slopes(y, h.fx, h.fy, h.sigma)
        g, g_turn = np.array([h.fx, h.fy]) + even, np.array([h.fx, h.fy]) + strongest
        f1, f2 = fabric_frequencies(g[0], g[1], rotation_deg, skew_deg)
        mn = np.array([h.m, h.n], dtype=float)
        reading += _Reading(h.power * np.outer(mn, mn), h.power * np.outer(mn, g), h.power * np.outer(mn, g_turn),
                            h.power * np.array([h.m * f1, h.m * h.m, h.n * f2, h.n * h.n]))
    return reading


def _separation(m: int, n: int, a: float, b: float, signature: Signature, size: int, rotation_deg: float,
                skew_deg: float) -> float:
    """Cycles per image from harmonic (m, n) of the lattice (a, b) to the nearest other harmonic that
    carries power (``signature``'s and their mirrors -f, (m, n)'s own included), all folded at
    Nyquist."""
    mm, nn = np.concatenate((signature.m, -signature.m)), np.concatenate((signature.n, -signature.n))
    others = (mm != m) | (nn != n)
    fx, fy = turned_frequencies(m * a, n * b, rotation_deg, skew_deg)
    ox, oy = turned_frequencies(mm[others] * a, nn[others] * b, rotation_deg, skew_deg)
    dx, dy = fold(fold(ox, size) - fold(fx, size), size), fold(fold(oy, size) - fold(fy, size), size)
    light = math.hypot(fold(fx, size), fold(fy, size)) - LIGHT_BAND
    return float(min(np.hypot(dx, dy).min(), light))


def _demodulated(y: np.ndarray, fx: float, fy: float) -> np.ndarray:
    size = y.shape[0]
    centres = np.arange(size) + 0.5
    return y * np.outer(np.exp(-2j * np.pi * fy * centres / size), np.exp(-2j * np.pi * fx * centres / size))


def phase_steps(y: np.ndarray, fx: float, fy: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The phase steps (s_x, s_y) of the module docstring: of ``y`` demodulated at (fx, fy) (cycles
    per image) and low-passed by a Gaussian of ``sigma`` pixels, across (H, W - 1) and down (H - 1, W)."""
    z = _demodulated(y, fx, fy)
    # float32: OpenCV's wide blur is several times faster on it; the sums below are float64
    z = (cv2.GaussianBlur(z.real.astype(np.float32), (0, 0), sigma).astype(np.float64)
         + 1j * cv2.GaussianBlur(z.imag.astype(np.float32), (0, 0), sigma))
    return z[:, 1:] * np.conj(z[:, :-1]), z[1:, :] * np.conj(z[:-1, :])


def _phase_slopes(y: np.ndarray, fx: float, fy: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """((delta_x, delta_y) read evenly, (delta_x, delta_y) weighted by |z_h|^2) of the module
    docstring, cycles per image."""
    steps = phase_steps(y, fx, fy, sigma)
    per_cycle = y.shape[0] / (2 * math.pi)
    even = np.array([np.angle(_evenly_summed(s)) for s in steps]) * per_cycle
    strongest = np.array([np.angle(np.sum(s)) for s in steps]) * per_cycle
    return even, strongest


def _evenly_summed(steps: np.ndarray) -> complex:
    """sum_p s(p) / max(|s(p)|, the EVEN_QUANTILE of |s|) of the phase steps s (module docstring)."""
    strength = np.abs(steps)
    # the quantile of a low-passed field: every 4th pixel each way reads it closely, at 1/16 of the cost
    floor = max(float(np.quantile(strength[::4, ::4], EVEN_QUANTILE)), 1e-300)  # (1e-300: a blank photo)
    return complex(np.sum(steps / np.maximum(strength, floor)))
