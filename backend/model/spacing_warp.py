"""Uneven yarn spacing: a smooth displacement of the weave across the photo.

A real sample is never woven or laid quite evenly (a cloth not quite flat in its holder, yarns
pulled a little closer in one place, the lens's distortion), so its yarns are spaced 1-3 % more
or less densely from one part of the photo to another (the photo-like set draws such a warp:
:mod:`devtools.phone`). The lattice's mean spacing is the material's (``tiles``); the rest is this photo's,
and a render that lacks it shows each harmonic as one sharp line where the photo spreads it over a
few frequencies, with less modulation in every region than the photo keeps (the fit answers with
a smoother, rougher fabric).

The weave a render shows at film pixel p (x across, y down the image, film pixels) is the one at

    p + d(p),   d(p) = sum_ab C[b, a] B_a(x) B_b(y)

with B the uniform cubic B-splines of ``intervals`` spans across the film (``intervals + 3`` per
axis, :func:`bspline_basis`), and C the ``(intervals + 3)^2`` control displacements of each
component (film pixels). Only where the sample's yarns are looked up moves (the weave's place);
the light's and the camera's directions stay those of p, which a displacement of a pixel or less
does not change. The warp is the photos' (as the light falloff is: :mod:`.photo_light`), never the
material's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


def bspline_weights(t):
    """The four uniform cubic B-spline weights at fractions ``t`` in [0, 1) of a span (array or
    tensor, last axis of the result: the spans' control points i .. i + 3)."""
    lib = torch if isinstance(t, torch.Tensor) else np
    return lib.stack([(1 - t) ** 3 / 6, (3 * t ** 3 - 6 * t ** 2 + 4) / 6,
                      (-3 * t ** 3 + 3 * t ** 2 + 3 * t + 1) / 6, t ** 3 / 6], -1)


def span_of(coords, film_size: float, intervals: int):
    """(first control point index, fraction within the span) of film coordinates ``coords`` (pixels,
    0 .. film_size), clamped onto the film."""
    lib = torch if isinstance(coords, torch.Tensor) else np
    t = lib.clip(coords / film_size * intervals, 0.0, intervals - 1e-9)
    first = lib.floor(t)
    index = first.long() if isinstance(first, torch.Tensor) else first.astype(np.int64)
    return index, t - first


def bspline_slopes(t: np.ndarray) -> np.ndarray:
    """The derivatives of :func:`bspline_weights` with respect to the span fraction ``t``."""
    return np.stack([-(1 - t) ** 2 / 2, (3 * t ** 2 - 4 * t) / 2, (-3 * t ** 2 + 2 * t + 1) / 2, t ** 2 / 2], -1)


def bspline_basis(coords: np.ndarray, film_size: float, intervals: int, derivative: bool = False) -> np.ndarray:
    """(len(coords), intervals + 3): every basis function of one axis at film coordinates ``coords``
    (or, with ``derivative``, its slope per pixel)."""
    index, frac = span_of(np.asarray(coords, dtype=np.float64), film_size, intervals)
    basis = np.zeros((len(index), intervals + 3))
    weights = bspline_slopes(frac) * (intervals / film_size) if derivative else bspline_weights(frac)
    for k in range(4):
        basis[np.arange(len(index)), index + k] = weights[:, k]
    return basis


def control_abscissae(film_size: float, intervals: int) -> np.ndarray:
    """Where each control point sits on its axis (film pixels): an affine function of the coordinates
    is reproduced exactly by control values equal to it there (the Greville abscissae (i - 1) h)."""
    return (np.arange(intervals + 3) - 1.0) * film_size / intervals


GRID = 64  # cells per side of the grid a warp is compared and measured on


@dataclass(frozen=True)
class SpacingWarp:
    """A smooth displacement d(p) of the weave across the film (module docstring): ``dx`` and ``dy``
    the control displacements C (rows down the image, columns across), film pixels."""

    intervals: int
    dx: tuple[tuple[float, ...], ...]
    dy: tuple[tuple[float, ...], ...]

    def __post_init__(self):
        side = self.intervals + 3
        for name in ("dx", "dy"):
            grid = np.asarray(getattr(self, name), dtype=np.float64)
            if grid.shape != (side, side) or not np.all(np.isfinite(grid)):
                raise ValueError(f"spacing warp {name}: expected {side} x {side} finite numbers")
            object.__setattr__(self, name, tuple(tuple(float(v) for v in row) for row in grid))

    @classmethod
    def from_grids(cls, dx: np.ndarray, dy: np.ndarray) -> "SpacingWarp":
        return cls(int(np.shape(dx)[0]) - 3, np.asarray(dx).tolist(), np.asarray(dy).tolist())

    def displacement(self, x: torch.Tensor, y: torch.Tensor, film_size: int) -> tuple[torch.Tensor, torch.Tensor]:
        """d(p) (film pixels) at film coordinates (x across, y down, 0 .. ``film_size``; any shape).

        The 16 terms C[iy + b, ix + a] B_b(y) B_a(x) of the sample's span, summed in that order; each
        control value is read from the flattened grid at one index that both components share:
        bit-identical to 2D indexing per component and per term, in half the time.
        tests/test_spacing_warp.py checks the sums against the dense bases of each axis."""
        side = self.intervals + 3
        ix, fx = span_of(x, film_size, self.intervals)
        iy, fy = span_of(y, film_size, self.intervals)
        wx, wy = bspline_weights(fx), bspline_weights(fy)
        corner = iy * side + ix  # the span's first control point in the flattened grid
        controls = [torch.tensor(grid, dtype=x.dtype, device=x.device).flatten() for grid in (self.dx, self.dy)]
        out = [torch.zeros_like(x), torch.zeros_like(x)]
        for b in range(4):
            for a in range(4):
                weight, at = wy[..., b] * wx[..., a], corner + (b * side + a)
                for k, control in enumerate(controls):
                    out[k] = out[k] + weight * control.take(at)
        return out[0], out[1]

    def to_dict(self) -> dict:
        return {"intervals": self.intervals, "dx": [list(r) for r in self.dx], "dy": [list(r) for r in self.dy]}

    @classmethod
    def from_dict(cls, data: dict) -> "SpacingWarp":
        return cls(int(data["intervals"]), data["dx"], data["dy"])

    def sampled(self, film_size: int) -> tuple[np.ndarray, np.ndarray]:
        """(dx, dy) at the centres of a GRID x GRID grid of cells over the film (rows down the image)."""
        basis = bspline_basis(grid_centres(film_size), film_size, self.intervals)
        return basis @ np.asarray(self.dx) @ basis.T, basis @ np.asarray(self.dy) @ basis.T

    def rms_px(self, film_size: int) -> float:
        """The root mean square displacement over the film (film pixels)."""
        return rms(*self.sampled(film_size))

    def __add__(self, other: "SpacingWarp") -> "SpacingWarp":
        return SpacingWarp.from_grids(np.add(self.dx, other.dx), np.add(self.dy, other.dy))


def rms(dx: np.ndarray, dy: np.ndarray) -> float:
    """The root mean square length of displacements (dx, dy) sampled on a grid."""
    return float(np.sqrt(np.mean(np.asarray(dx) ** 2 + np.asarray(dy) ** 2)))


def grid_centres(film_size: float, n: int = GRID) -> np.ndarray:
    return (np.arange(n) + 0.5) * film_size / n


def affine_part(d: np.ndarray, film_size: float) -> tuple[float, float, float]:
    """(c, c_x, c_y) of the affine displacement c + c_x x + c_y y nearest to the displacements ``d``
    on an n x n grid over the film (:func:`grid_centres`), least squares: the part of a warp that is
    the lattice's own spacing and turn, which the tiles, rotation and skew carry."""
    g = grid_centres(film_size, d.shape[0])
    y, x = np.meshgrid(g, g, indexing="ij")
    design = np.stack((np.ones(x.size), x.ravel(), y.ravel()), 1)
    return tuple(float(v) for v in np.linalg.lstsq(design, d.ravel(), rcond=None)[0])


def non_affine(d: np.ndarray, film_size: float) -> np.ndarray:
    """Displacements ``d`` (on a grid over the film) less their :func:`affine_part`."""
    g = grid_centres(film_size, d.shape[0])
    y, x = np.meshgrid(g, g, indexing="ij")
    c, cx, cy = affine_part(d, film_size)
    return d - (c + cx * x + cy * y)
