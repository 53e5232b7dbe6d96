"""The yarn variation a photo pair shows, estimated after the fit from the texture power its
regular weave leaves unexplained.

A fitted weave is perfectly regular; a real fabric's yarns differ in width, thickness, place and
brightness, and thicken and thin along their length (:mod:`backend.core.variation`). The photos hold
that irregularity as texture power at every scale, which a regular render lacks: the texture gap
(:func:`backend.image.metrics.texture_gap_db`). A pixel loss cannot ask for it (a random yarn pattern
never lines up with the photo's, so any amplitude raises the loss), and a camera blur can only widen
the gap; so the variation is read from power alone.

Each kind k is a zero-mean random field, independent of the lattice and of the other kinds, so for
moderate amplitudes their powers add. Per octave band b of each photo::

    S(a)[b] = S_0[b] + sum_k a_k^2 V_k[b]

with S_0 the regular render's power and V_k what kind k adds per unit amplitude squared (one render
with that kind alone at PROBE_AMPLITUDE). x_k = a_k^2 in [0, hi_k^2] is the bounded least-squares
solution of the relative errors (S(a)[b] - P[b]) / P[b] over both photos' bands (P: the photos'
power; :func:`bounded_least_squares`). The relative error weighs too much texture above too
little (a band short of all its power counts 1, one with twice too much counts 1 already), which is
the point: a random yarn pattern never lines up with the photo's, so every bit of it it adds is
pixel error too; where the kinds' band profiles cannot match the photos' (a blurred fit holds no
power in the top band), it fills what it can without overshooting the rest (the symmetric
measure, the squared log errors, was tried: it overshot where the profiles cannot match).
A render's power is read without its Monte Carlo noise: as the cross-power of two renders with
independent samples (:func:`backend.image.metrics.band_power` with ``other``), which at a few
samples per pixel would otherwise read as texture the render lacks.

The estimate is kept where a render at it (read the same way) has a smaller texture gap than the
regular weave's by at least MIN_GAIN_DB; else the fit keeps none. Warp and weft get the same
amplitudes (octave bands do not tell them apart), each kind the length of :func:`read_length`.
Cost: 2 (kinds + 2) renders at READ_SIZE, without gradients.

=================  =======  ==================================================================
name               value    what it guards
=================  =======  ==================================================================
PROBE_AMPLITUDE    0.1      amplitude of the one-kind renders: large enough that its power
                            stands clear of the cross-power's scatter, small enough to be linear
MIN_GAIN_DB        0.5      texture gap (dB) the estimate must close to be kept: a smaller gain
                            is within the reading's scatter and not worth a random pattern
GAP_FLOOR          1e-3     a band where a render holds less than this part of the photo's power
                            counts as 30 dB short (a cross-power can be 0 or negative)
READ_SIZE          256      px of the readings' renders: a quarter of a 512-px working size's cost,
                            and every band still below Nyquist
READ_SPP           4        samples per pixel of each render of a reading (the cross-power takes
                            its noise out; fewer samples only scatter it more)
READ_SEED_OFFSET   1000     the readings' jitter seeds above the fit's: samples independent of it
=================  =======  ==================================================================
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from ..core.params import SPECS, FabricParams
from ..core.variation import KINDS, amplitude_name, length_name
from ..image.metrics import band_power, power_db
from ..model.imaging import downsample_linear
from .objective import Objective, Target

PROBE_AMPLITUDE = 0.1
MIN_GAIN_DB = 0.5
GAP_FLOOR = 1e-3         # 30 dB: the most a band's gap counts (module docstring, _gap_db)
READ_SIZE = 256          # px of the readings' renders (the bands scale with the size)
READ_SPP = 4             # samples per pixel of each of the two renders of a reading
READ_SEED_OFFSET = 1000  # the readings' jitter seeds are the fit's plus this and one more: other samples
READINGS = len(KINDS) + 2  # the regular weave, each kind alone, the estimate: progress(done) counts them


def read_length(kind: str) -> float:
    """The correlation length a reading gives ``kind`` (yarns; crossings for the slub): the geometric
    centre of its declared prior. A variation's power moves to lower bands as its length grows, so a
    reading at one length misreads the amplitude of a variation at another; the centre of the prior
    (on the log scale the bands are on) misreads the least over the lengths it allows."""
    low, high = SPECS[length_name(kind)].prior
    return math.sqrt(low * high)


def read_lengths(amplitudes: dict[str, float]) -> dict[str, float]:
    """The correlation length (:func:`read_length`) of each kind read with an amplitude."""
    return {k: read_length(k) for k, a in amplitudes.items() if a > 0}


@dataclass
class VariationEstimate:
    """The amplitudes read (``amplitudes``: kind -> value, warp and weft alike), the texture gap
    (dB, both photos' bands) of the regular weave and of the varied one, and whether it was kept
    (``dropped``: why not, where the fit dropped it after settling)."""

    amplitudes: dict[str, float]
    gap_before_db: float
    gap_after_db: float
    kept: bool
    band_gaps_db: dict[str, list[float]] = field(default_factory=dict)  # varied (if read kept) - photo
    dropped: str | None = None  # why a variation read was dropped after all (the fit's pipeline: "colour")
    # each settling of the fit's pipeline: {"scale": the part of ``amplitudes`` it settled at, "colour_shift":
    # per photo (R, T), how much further its overall colour is from the photo's than the regular weave's}
    settled: list[dict] = field(default_factory=list)

    @property
    def colour_shift(self) -> tuple[float, float] | None:
        """The last settling's colour shift (None where the pipeline settled none)."""
        return self.settled[-1]["colour_shift"] if self.settled else None

    @property
    def scale(self) -> float | None:
        """The part of ``amplitudes`` the fit keeps: the last settling's, 0 where it dropped them after
        settling (None where the pipeline settled none)."""
        if not self.settled:
            return None
        return self.settled[-1]["scale"] if self.kept else 0.0

    @property
    def lengths(self) -> dict[str, float]:
        """The correlation length of each kind read (:func:`read_lengths`)."""
        return read_lengths(self.amplitudes)

    def to_dict(self) -> dict:
        return {"amplitudes": {k: round(v, 4) for k, v in self.amplitudes.items()},
                "lengths": dict(self.lengths),
                "gap_before_db": round(self.gap_before_db, 2), "gap_after_db": round(self.gap_after_db, 2),
                "kept": self.kept, "dropped": self.dropped,
                "colour_shift": None if self.colour_shift is None else [round(x, 5) for x in self.colour_shift],
                "scale": None if self.scale is None else round(self.scale, 4),
                "settled": [{"scale": round(s["scale"], 4), "colour_shift": [round(x, 5) for x in s["colour_shift"]]}
                            for s in self.settled],
                "band_gaps_db": {k: [round(x, 2) if np.isfinite(x) else None for x in v]  # None: past Nyquist
                                 for k, v in self.band_gaps_db.items()}}


def with_amplitudes(params: FabricParams, amplitudes: dict[str, float],
                    lengths: dict[str, float] | None = None) -> FabricParams:
    """``params`` with each kind's amplitude (and correlation length, where given) set for warp and
    weft alike."""
    return params.replace(**{amplitude_name(k): (a, a) for k, a in amplitudes.items()},
                          **{length_name(k): (n, n) for k, n in (lengths or {}).items()})


def with_scaled_variation(params: FabricParams, scale: float) -> FabricParams:
    """``params`` with every kind's amplitude (warp and weft) times ``scale``; the lengths as they are."""
    if scale == 1.0:
        return params
    return params.replace(**{amplitude_name(k): tuple(a * scale for a in getattr(params, amplitude_name(k)))
                             for k in KINDS})


def bounded_least_squares(a: np.ndarray, b: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """argmin |a x - b| over 0 <= x <= ``upper``, exactly: each of the 3^n states of the unknowns
    (at 0, at its bound, free) solved by least squares on the free ones, the best feasible kept
    (n is the five kinds: 243 tiny solves)."""
    n = a.shape[1]
    best, best_cost = np.zeros(n), float(np.sum(b ** 2))
    for states in itertools.product((0, 1, 2), repeat=n):
        x = np.where(np.asarray(states) == 1, upper, 0.0)
        free = [j for j in range(n) if states[j] == 2]
        if free:
            rest = b - a @ x
            solution = np.linalg.lstsq(a[:, free], rest, rcond=None)[0]
            if (solution < 0).any() or (solution > upper[free]).any():
                continue
            x[free] = solution
        cost = float(np.sum((a @ x - b) ** 2))
        if cost < best_cost - 1e-15:
            best, best_cost = x, cost
    return best


class _Powers:
    """The noise-free band power of a parameter set's renders as the photos show them, at READ_SIZE
    (or the working size where it is smaller): the cross-power of two renders with independent
    samples; and the photos' power there."""

    def __init__(self, objective: Objective, blur: float, seed: int):
        target, gamma = objective.target, objective.rig.gamma
        if target.size > READ_SIZE:
            target = Target(downsample_linear(target.reflection, READ_SIZE, gamma),
                            downsample_linear(target.transmission, READ_SIZE, gamma))
        self.objectives = [Objective(target, objective.renderer.like(target.size, READ_SPP, seed + k), objective.rig,
                                     fit_light=objective.fit_light) for k in (0, 1)]
        self.blur = blur
        self.photo = np.stack([band_power(t.cpu().numpy()) for t in (target.reflection, target.transmission)])

    def __call__(self, params: FabricParams) -> np.ndarray:
        """(2 photos, bands) power."""
        with torch.no_grad():
            pairs = [o.rendered(params, self.blur)[0] for o in self.objectives]
        images = [[p.reflection.cpu().numpy(), p.transmission.cpu().numpy()] for p in pairs]
        return np.stack([band_power(one, other) for one, other in zip(*images)])


def _gap_db(power: np.ndarray, photo: np.ndarray) -> float:
    """The texture gap (dB) of a render's noise-free power against the photos', a band where the
    render holds less than GAP_FLOOR of the photo's read at that floor (a cross-power can be 0 or
    less where the render holds nothing)."""
    return float(np.nanmean(np.abs(power_db(np.maximum(power, GAP_FLOOR * photo)) - power_db(photo))))


def estimate_variation(params: FabricParams, objective: Objective, blur: float, seed: int = 0,
                       progress: Callable[[int], None] | None = None) -> tuple[FabricParams, VariationEstimate]:
    """(``params`` with the variation the photos show, or without any where none is kept; the
    reading) at the camera blur ``blur`` (module docstring). ``progress(done)`` after each of the
    READINGS readings."""
    progress = progress or (lambda done: None)
    regular = with_amplitudes(params, {k: 0.0 for k in KINDS})
    powers = _Powers(objective, blur, seed + READ_SEED_OFFSET)
    photo = powers.photo
    base = powers(regular)
    progress(1)
    added = []
    for k in KINDS:
        probe = with_amplitudes(regular, {k: PROBE_AMPLITUDE}, {k: read_length(k)})
        added.append(np.maximum(powers(probe) - base, 0.0) / PROBE_AMPLITUDE ** 2)
        progress(1 + len(added))
    seen = np.isfinite(photo.reshape(-1)) & (photo.reshape(-1) > 0)  # bands below the readings' Nyquist corner
    scale = photo.reshape(-1)[seen]
    design = np.stack([v.reshape(-1)[seen] for v in added], axis=1) / scale[:, None]
    upper = np.array([SPECS[amplitude_name(k)].hi ** 2 for k in KINDS])
    squares = bounded_least_squares(design, 1.0 - base.reshape(-1)[seen] / scale, upper)
    amplitudes = {k: float(np.sqrt(x)) for k, x in zip(KINDS, squares)}
    varied = with_amplitudes(regular, amplitudes, read_lengths(amplitudes))
    after = powers(varied) if squares.any() else base
    progress(READINGS)
    before_db, after_db = _gap_db(base, photo), _gap_db(after, photo)
    kept = after_db <= before_db - MIN_GAIN_DB
    shown = after if kept else base
    reading = VariationEstimate(amplitudes, before_db, after_db, kept,
                                {tag: list(power_db(np.maximum(shown[i], GAP_FLOOR * photo[i])) - power_db(photo[i]))
                                 for i, tag in enumerate("RT")})
    return (varied if kept else regular), reading
