"""The photo's uneven yarn spacing: the smooth warp of its lattice, read from the phase of its harmonics.

A lattice displaced by d(p) (pixels; the weave seen at p is the sample's at p + d(p),
:mod:`backend.model.spacing_warp`) shows each harmonic h, at image frequency f_h (cycles per image),
as y(p) ~ A_h(p) cos(2 pi f_h . (p + d(p)) / N + c_h(p)), where c_h drifts with the light: a
highlight's place on a yarn follows the half vector, which turns across the photo. A render of the
fabric without the warp drifts alike, so with s_{h,e}(p) the phase steps of the photo's
demodulated, low-passed signal along a pixel step e (:func:`.spacing.phase_steps`) and s'_{h,e}(p)
the render's,

    r_{h,e}(p) = N / (2 pi) arg (s_{h,e}(p) conj(s'_{h,e}(p))) = f_h . (d/de) d(p)    (e = across, down)

one equation per harmonic, step and pixel for the Jacobian of d. A render of another fabric than
the photo's drifts otherwise, and part of the difference reads as a warp, so the fit reads again as
its parameters improve (:mod:`backend.fit.warp`).

With d(p) = sum C B_a(x) B_b(y) (uniform cubic B-splines of INTERVALS spans), the equations are
solved for the control displacements C by weighted least squares,

    min_C  sum_{h, e, p} w_{h,e}(p) (f_h . (d/de) d(p) - r_{h,e}(p))^2  +  lambda |second differences of C|^2

with w = min(|s| / its median, |s'| / its median, 1) times the median of |s|: where the harmonic
shows at least as strongly as at the median pixel in both the steps weigh alike, where noise
takes over (no steady phase) less, and a stronger harmonic's steps more (|s| ~ |z_h|^2). The
penalty (SMOOTHNESS times the normal matrix's mean diagonal) spans what the harmonics leave open.
Of the solution only the part that is not affine is the warp. The affine part, as it shows evenly
over the photo (c + J p, least squares on a uniform grid), is the lattice's own: the photo shows
the render's yarn frequency vectors u, v (:func:`.lattice.turned_frequencies`) as (I + J)^T u and
(I + J)^T v, so the tiles are off by the *stretch*

    s_u = |(I + J)^T u| / |u| - 1,   s_v likewise

(J's turn and shear are left to the placement). This reads the spacing against a render, evenly
over the photo, where :mod:`.spacing` reads it from the photo alone before any render: weighted
towards where the harmonics show (a warp's denser or sparser part) and with the light's own phase
drift in it. Against a render of parameters still being fitted it can read a few tenths of a
percent off (:meth:`backend.fit.optimise.Run.update_warp` keeps it only where the loss is lower at
once). A stretch over ``MAX_STRETCH`` is not the lattice's: the placement's mean spacing reads
closer than that. One under ``NEGLIGIBLE_STRETCH`` is none; a warp under ``NEGLIGIBLE_PX`` (root
mean square) is none.

The photos' equations are summed (both show the sample's warp); each photo's own reading tells
whether they agree (:func:`read_warp`'s ``agreeing``). The harmonics are the lattice's strongest
(:func:`.spacing.strongest_harmonics`), so the low-pass that keeps their neighbours out also
smooths the warp read: over a few tens of pixels for a sparse lattice.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..model.spacing_warp import SpacingWarp, affine_part, bspline_basis, control_abscissae, grid_centres
from .frequencies import turned_frequencies
from .lattice import Signature
from .spacing import phase_steps, strongest_harmonics

INTERVALS = 12        # B-spline spans across the photo (43 px at 512): represents warps of periods >= 150 px within 3 %
STRIDE = 8            # pixels between the steps read (the signals are low-passed over >= 10 px)
SMOOTHNESS = 1e-2     # weight of the second differences of C, relative to the normal matrix's mean diagonal
RIDGE = 1e-6          # weight of C itself, likewise: pins what nothing else does
NEGLIGIBLE_PX = 0.05  # root mean square displacement below which the photo has no warp
AGREEMENT = 0.6       # correlation of two photos' own warps below which they show none of the sample's
NEGLIGIBLE_STRETCH = 1e-3  # relative change of a yarn frequency below which the photos show the render's lattice
MAX_STRETCH = 0.015        # ... and above which it is not the lattice's (the placement reads closer)


@dataclass(frozen=True)
class WarpReading:
    """What one photo's warp is read from: its high-passed luminance ``photo``, that of a render of
    the fabric as the fit has it (``render``, same size, no warp: the model's own phase drift), and
    the ``signature`` of the pattern's harmonics in that photo."""

    photo: np.ndarray
    render: np.ndarray
    signature: Signature


@dataclass(frozen=True)
class SpacingRead:
    """What the photos show beyond the renders (module docstring): the non-affine ``warp`` (film
    pixels; None where negligible) and the ``stretch`` (s_u, s_v) of the lattice's yarn frequencies
    ((0, 0) where negligible or out of reach)."""

    warp: SpacingWarp | None
    stretch: tuple[float, float]


def read_warp(readings: list[WarpReading], a: float, b: float, rotation_deg: float, skew_deg: float,
              film_size: int, agreeing: bool = False) -> SpacingRead | None:
    """The non-affine warp (film pixels) of the lattice (a, b) (cycles per image; turned and sheared by
    ``rotation_deg``, ``skew_deg``) that the photos show and the renders do not, and the stretch of
    the lattice itself, read from all of them at once (module docstring); None where no harmonic
    shows or both are negligible. With ``agreeing``, also None unless every photo shows a warp of its
    own and those agree (a correlation of at least AGREEMENT, pairwise)."""
    size = readings[0].photo.shape[0]
    equations = [_equations(reading, a, b, rotation_deg, skew_deg) for reading in readings]
    if agreeing and len(readings) > 1 and not _own_warps_agree(equations, size, film_size):
        return None
    found = [e for e in equations if e is not None]
    if not found:
        return None
    warp, affine = _solved(sum(e[0] for e in found), sum(e[1] for e in found), size, film_size)
    stretch = _stretch(affine, a, b, rotation_deg, skew_deg)
    return None if warp is None and stretch == (0.0, 0.0) else SpacingRead(warp, stretch)


def _own_warps_agree(equations: list, size: int, film_size: int) -> bool:
    """Whether every photo shows a warp of its own and those agree pairwise (``AGREEMENT``)."""
    own = [None if e is None else _solved(*e, size, film_size)[0] for e in equations]
    if any(w is None for w in own):
        return False
    return min(correlation(u, v, film_size) for k, u in enumerate(own) for v in own[k + 1:]) >= AGREEMENT


def _stretch(affine: np.ndarray, a: float, b: float, rotation_deg: float, skew_deg: float) -> tuple[float, float]:
    """(s_u, s_v) of the module docstring for the affine part's Jacobian ``affine`` (J, 2 x 2, rows
    (dx, dy), columns (x, y)); (0, 0) where both are under NEGLIGIBLE_STRETCH or either over MAX_STRETCH."""
    shown = (np.eye(2) + affine).T
    stretch = []
    for f1, f2 in ((a, 0.0), (0.0, b)):
        vector = np.array(turned_frequencies(f1, f2, rotation_deg, skew_deg), dtype=np.float64)
        stretch.append(float(np.linalg.norm(shown @ vector) / np.linalg.norm(vector) - 1.0))
    if max(map(abs, stretch)) < NEGLIGIBLE_STRETCH or max(map(abs, stretch)) > MAX_STRETCH:
        return 0.0, 0.0
    return stretch[0], stretch[1]


def correlation(u: SpacingWarp, v: SpacingWarp, film_size: int) -> float:
    """sum(d_u . d_v) / sqrt(sum |d_u|^2 sum |d_v|^2) over the film: 1 for warps of one shape."""
    (ux, uy), (vx, vy) = u.sampled(film_size), v.sampled(film_size)
    return float(np.sum(ux * vx + uy * vy) / np.sqrt(np.sum(ux ** 2 + uy ** 2) * np.sum(vx ** 2 + vy ** 2)))


def _equations(reading: WarpReading, a: float, b: float, rotation_deg: float, skew_deg: float
               ) -> tuple[np.ndarray, np.ndarray] | None:
    """The normal equations (matrix, right-hand side) of one photo's phase steps against its render's
    (module docstring), without the penalty; None where none of the lattice's harmonics shows."""
    size = reading.photo.shape[0]
    side = INTERVALS + 3
    unknowns = side * side
    normal = np.zeros((2 * unknowns, 2 * unknowns))
    rhs = np.zeros(2 * unknowns)
    sample = np.arange(STRIDE // 2, size - 1, STRIDE)
    # steps across sit between pixel centres (x + 1/2 of the sampled pixel's centre), those down likewise;
    # per step direction (across, down): the factors (of y, of x) of the design's rows at the sampled steps,
    # B_b(y) B'_a(x) for d/dx and B'_b(y) B_a(x) for d/dy
    value = bspline_basis(sample + 0.5, size, INTERVALS)
    slope = bspline_basis(sample + 1.0, size, INTERVALS, derivative=True)
    factors = ((value, slope), (slope, value))
    per_cycle = size / (2 * math.pi)
    harmonics = strongest_harmonics(reading.photo, a, b, reading.signature, rotation_deg, skew_deg)
    for h in harmonics:
        photo_steps = phase_steps(reading.photo, h.fx, h.fy, h.sigma)
        render_steps = phase_steps(reading.render, h.fx, h.fy, h.sigma)
        f = np.array([h.fx, h.fy])
        for (rows, cols), photo, render in zip(factors, photo_steps, render_steps):
            photo, render = photo[np.ix_(sample, sample)], render[np.ix_(sample, sample)]   # (y, x)
            weight = np.minimum(_evenly(photo), _evenly(render)) * float(np.median(np.abs(photo)))
            r = np.angle(photo * np.conj(render)) * per_cycle
            # the design is a product of one factor per axis: its Gram matrix and moments are sums of
            # products of those (sum_j rows rows sum_i w cols cols), not of dense rows of side^2 entries
            inner = weight @ (cols[:, :, None] * cols[:, None, :]).reshape(len(cols), -1)     # (j, a c)
            outer = (rows[:, :, None] * rows[:, None, :]).reshape(len(rows), -1)             # (j, b d)
            gram = (outer.T @ inner).reshape(side, side, side, side).transpose(0, 2, 1, 3).reshape(unknowns, unknowns)
            moment = (rows.T @ (weight * r) @ cols).reshape(unknowns)
            for i in range(2):
                rhs[i * unknowns:(i + 1) * unknowns] += f[i] * moment
                for j in range(2):
                    normal[i * unknowns:(i + 1) * unknowns, j * unknowns:(j + 1) * unknowns] += f[i] * f[j] * gram
    return (normal, rhs) if harmonics and np.trace(normal) > 0 else None


def _solved(normal: np.ndarray, rhs: np.ndarray, size: int, film_size: int) -> tuple[SpacingWarp | None, np.ndarray]:
    """The warp (film pixels) of the normal equations with the penalty (module docstring), less its
    affine part (None where negligible), and that affine part's Jacobian J (2 x 2: rows dx, dy;
    columns x, y)."""
    side = INTERVALS + 3
    unknowns = side * side
    second = np.diff(np.eye(side), 2, axis=0)
    curvature = np.kron(np.eye(side), second.T @ second) + np.kron(second.T @ second, np.eye(side))
    penalty = float(np.trace(normal)) / len(normal) * (SMOOTHNESS * curvature + RIDGE * np.eye(unknowns))
    normal = normal + np.kron(np.eye(2), penalty)
    solved = np.linalg.solve(normal, rhs)
    grids, affine = [], np.zeros((2, 2))
    for i in range(2):
        grid, affine[i] = _without_affine(solved[i * unknowns:(i + 1) * unknowns].reshape(side, side), size)
        grids.append(grid * (film_size / size))
    warp = SpacingWarp.from_grids(*grids)
    return (warp if warp.rms_px(film_size) >= NEGLIGIBLE_PX else None), affine


def _evenly(steps: np.ndarray) -> np.ndarray:
    """min(|s| / median |s|, 1): 1 where a harmonic shows at least as strongly as at the median pixel."""
    strength = np.abs(steps)
    return np.minimum(strength / max(float(np.median(strength)), 1e-300), 1.0)


def _without_affine(control: np.ndarray, size: int) -> tuple[np.ndarray, tuple[float, float]]:
    """Control displacements without the affine part of the warp they make (an affine warp's control
    values are its values at the :func:`control_abscissae`), and that part's slopes (c_x, c_y)."""
    basis = bspline_basis(grid_centres(size), size, INTERVALS)
    c, cx, cy = affine_part(basis @ control @ basis.T, size)
    at = control_abscissae(size, INTERVALS)
    return control - (c + cx * at[None, :] + cy * at[:, None]), (cx, cy)
