"""One optimisation run: Adam on the continuous parameters, parabolic steps on the discrete ones.

- Adam on :data:`backend.fit.settings.OPTIMISED` (roughness, thickness, their multiple-scattering
  twins, height scale, albedos, diffuse weight, multiple weight), each with a learning rate
  ``lr * (hi - lo)`` of its declared range, halved at 50, 70 and 85 % of the run, or at
  once to the last of those rates where the run stalls above it (:meth:`Run.lower_rate`); every parameter is
  clamped into its range after each step; where the camera blur is estimated, Adam moves it too
  (:class:`Run`).
- :meth:`Run.discrete_search` (:func:`backend.fit.pipeline.search_due`): in the first, a joint coarse
  step on gap scale, then in each a parabolic step (:func:`parabolic_step`) per yarn on gap scale
  and twist, and on the camera blur when it is estimated; spans halve each round. Deterministic:
  a better use of evaluations than the paper's random +/- steps.
- :meth:`Run.scan_glow` (at the first discrete search, where the fit reads the glow): the back
  light's glow through the gaps at each strength of :data:`GLOW_SCAN`, the one whose transmission's
  colour term is lowest kept.
- The best parameters seen (with their loss, loss terms and camera blur) are kept.
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import torch

from ..core.params import SPECS, FabricParams
from ..core.rig import MAX_CAMERA_BLUR_PX
from ..model.param_tensors import ParamTensors, as_float
from ..model.render import GradientShare
from ..model.spacing_warp import SpacingWarp
from .objective import Objective
from .settings import OPTIMISED, FitSettings
from .warp import reread

if TYPE_CHECKING:
    from .search import BlurRange

LR_MILESTONES = (0.5, 0.7, 0.85)  # fractions of the run where the learning rates halve
# The joint steps of both yarns' gap scales that the first discrete search tries before its parabolic
# steps: a start's gap scale can lie further off than they reach. Later searches start from fitted
# gaps, where these wide steps seldom won (the benchmark's results) and each costs a render.
COARSE_GAP_STEPS = (-0.1, -0.05, 0.05, 0.1)
# The strengths of the back light's glow through the gaps (the rig's glow_strength; the spec's rig: 8)
# that Run.scan_glow tries: a real lamp seen through the yarns' gaps is as bright as its diffuser
# and the camera's focus make it, none where the fabric closes them.
GLOW_SCAN = (0.0, 2.0, 4.0, 8.0, 16.0)
GLOW_TERM = "colour_T"  # the loss term the glow is read by (Run.scan_glow); the loss where it is not weighed


@dataclass
class _WarpTrial:
    """A spacing warp on trial (:meth:`Run.update_warp`): the warp before it, the steps left, and the
    run's state before it (parameter values, Adam's state, camera blur, (best loss, best, its blur,
    its terms))."""

    warp: SpacingWarp | None
    steps: int
    values: dict[str, torch.Tensor]
    adam: dict
    camera_blur_px: float
    best: tuple


class Run:
    """Parameters (as tensors), their Adam state and the best parameters seen.

    ``camera_blur_px`` is the camera blur the run renders with. With a ``blur_range``
    (:class:`backend.fit.search.BlurRange`) it is estimated within it: Adam moves it with the
    continuous parameters (learning rate ``lr`` times the span from the floor to MAX_CAMERA_BLUR_PX,
    on the same schedule: the ceiling bounds the blur, it does not set its scale), and the discrete
    search by parabolic steps; with None it stays fixed. ``total`` is the number of Adam steps the
    learning-rate schedule spans.

    Why by gradient: the blur and the fabric trade off along a valley (a softer camera and sharper
    highlights, or the reverse), which steps on the blur alone, each at the parameters fitted to the
    blur before, cannot follow: the run ends where the scan put the blur, with the fabric bent to it.
    """

    def __init__(self, params: FabricParams, objective: Objective, settings: FitSettings, total: int,
                 camera_blur_px: float, blur_range: BlurRange | None = None):
        self.objective, self.settings, self.total = objective, settings, total
        self.blur_range = blur_range
        # float64: a fixed blur reads back as the number given; the renders take it as their sigma
        self._blur = torch.tensor(float(camera_blur_px), dtype=torch.float64, device=objective.renderer.device)
        self.base_lr = [settings.lr * (SPECS[n].hi - SPECS[n].lo) for n in OPTIMISED]
        if blur_range is not None:
            self.base_lr.append(settings.lr * (MAX_CAMERA_BLUR_PX - blur_range.floor))
        self.step_count = 0
        self.lr_factor: float | None = None  # in place of the schedule's factor (start_over_from)
        self.lowered = False  # at the schedule's last rates from a stall on (lower_rate)
        self.best_loss = math.inf
        self.best, self.best_blur = params, camera_blur_px
        self.best_terms: dict[str, float] = {}
        self.history: list[tuple[int, float]] = []
        self._warp_trial: _WarpTrial | None = None
        self.warp_s = 0.0  # seconds spent reading the photos' spacing warp
        self._start_from(params)

    @property
    def camera_blur_px(self) -> float:
        return as_float(self._blur)

    @camera_blur_px.setter
    def camera_blur_px(self, value: float) -> None:
        with torch.no_grad():
            self._blur.fill_(value)

    @property
    def estimates_blur(self) -> bool:
        return self.blur_range is not None

    def _start_from(self, params: FabricParams) -> None:
        self.fabric = ParamTensors.from_params(params, self.objective.renderer.device, requires_grad=OPTIMISED)
        groups = [{"params": [self.fabric.values[n]], "name": n} for n in OPTIMISED]
        if self.estimates_blur:
            self._blur = self._blur.detach().clone().requires_grad_(True)
            groups.append({"params": [self._blur], "name": "camera_blur_px"})
        self.optimiser = torch.optim.Adam([dict(group, lr=lr) for group, lr in zip(groups, self.base_lr)], eps=1e-6)

    def restart_from_best(self) -> None:
        """Fresh tensors and Adam state at the best parameters seen and their camera blur (the schedule
        goes on)."""
        if self.history:
            self.camera_blur_px = self.best_blur
            self._start_from(self.best)

    def start_over_from(self, params: FabricParams, lr_factor: float | None = None) -> None:
        """Fresh tensors and Adam state at ``params`` (at the current camera blur), which become the
        best, their loss counted afresh by the next step; the learning rates from now on are the base
        rates times ``lr_factor`` (None: the schedule's, which goes on)."""
        self.best, self.best_loss, self.best_blur, self.best_terms = params, math.inf, self.camera_blur_px, {}
        self.lr_factor = lr_factor
        self._start_from(params)

    def lower_rate(self) -> None:
        """Goes on from the best parameters seen (fresh Adam state) at the schedule's last learning
        rates from now on.

        Why: a run whose best loss has stalled above the last rate is not converged: its steps
        overshoot, the loss climbs away from its best and wanders back no lower, and an ending by
        patience there keeps a best that small steps from it better (one halving at a time stalls
        again and spends a patience at each level)."""
        self.lowered = True
        self.restart_from_best()

    @property
    def rate_level(self) -> int:
        """The halvings of the base rates now: the schedule's milestones passed, or all of them after
        :meth:`lower_rate`."""
        if self.lowered:
            return len(LR_MILESTONES)
        return sum(self.step_count / max(self.total, 1) >= p for p in LR_MILESTONES)

    @property
    def at_last_rate(self) -> bool:
        return self.rate_level >= len(LR_MILESTONES)

    def _schedule(self):
        factor = 0.5 ** self.rate_level if self.lr_factor is None else self.lr_factor
        for group, lr in zip(self.optimiser.param_groups, self.base_lr):
            group["lr"] = lr * factor

    def step(self, gradient_period: int = 1) -> float:
        """One Adam step; returns the loss of the parameters before the step. Its gradient comes
        through every ``gradient_period``-th block of film rows, a block further on each step
        (:class:`backend.model.render.GradientShare`; 1: through all)."""
        self._schedule()
        self.optimiser.zero_grad(set_to_none=True)
        share = GradientShare(self.step_count, gradient_period)
        with self.objective.renderer.gradient_share(share):
            terms = self.objective.terms(self.fabric, self._blur if self.estimates_blur else self.camera_blur_px)
        loss = terms["loss"]
        value = float(loss.detach())  # the step's one wait for the device (on a GPU)
        if not math.isfinite(value):
            bad = ", ".join(k for k, v in _on_host(terms).items() if not math.isfinite(v))
            raise FloatingPointError(f"the fit's loss is not finite ({bad}) at "
                                     f"{self.fabric.to_params().to_interchange()}")
        loss.backward()
        if value < self.best_loss:  # the parameters that produced this loss (before the step)
            self._keep_best(value, _on_host(terms))
        self.optimiser.step()
        self.fabric.clamp_()
        if self.estimates_blur:
            with torch.no_grad():
                self._blur.clamp_(self.blur_range.floor, self.blur_range.ceiling)
        self.history.append((self.step_count, value))
        self.step_count += 1
        if self._warp_trial is not None:
            self._warp_trial.steps -= 1
            if self._warp_trial.steps <= 0:
                self.end_warp_trial()
        return value

    def _keep_best(self, loss: float, terms: dict[str, float] | None = None) -> None:
        self.best_loss, self.best, self.best_blur = loss, self.fabric.to_params(), self.camera_blur_px
        if terms is not None:
            self.best_terms = terms

    def update_warp(self) -> None:
        """Reads the photos' uneven yarn spacing again against a render of the best parameters
        (:func:`backend.fit.warp.reread`: a warp, and the tiles stretched) and tries it: the run goes
        on under it, and after ``settings.warp_trial_steps`` steps keeps it where its best loss is
        then below the best loss before it, or else goes back to the state before (warp, parameters
        with the tiles, Adam's moments, best).

        Judged after a few steps, not at once: the parameters fitted without the warp make up for
        it (a smoother transmission, a wider blur), so at them the right warp first reads worse."""
        self.end_warp_trial()
        started = time.perf_counter()
        renderer = self.objective.renderer
        warp, tiles = reread(self.objective, self.best, self.best_blur)
        before = renderer.warp
        if warp is not before:   # set before the stretch is judged under it (each set remakes the samples)
            renderer.set_warp(warp)
        if tiles != self.best.tiles:
            tiles = self._stretch_kept(tiles)
        self.warp_s += time.perf_counter() - started
        if warp is before and tiles == self.best.tiles:
            return
        values = {n: v.detach().clone() for n, v in self.fabric.values.items()}
        self._warp_trial = _WarpTrial(before, self.settings.warp_trial_steps, values,
                                      copy.deepcopy(self.optimiser.state_dict()), self.camera_blur_px,
                                      (self.best_loss, self.best, self.best_blur, self.best_terms))
        with torch.no_grad():
            self.fabric.values["tiles"].copy_(torch.tensor(tiles, device=self.fabric.values["tiles"].device))
        self.best_loss = math.inf  # the best so far was under the warp before; what the trial finds is under this one

    def _stretch_kept(self, tiles: tuple[float, float]) -> tuple[float, float]:
        """``tiles`` (the best parameters' stretched, :func:`backend.fit.warp.reread`) where the best
        parameters, under the warp just read, have a lower loss at them than at their own tiles, else
        their own.

        Judged at once, unlike the warp: nothing else in the fabric makes up for a lattice that
        drifts out of phase with the photos. And judged apart from the warp's trial, which keeps
        what does no harm (five more steps lower the loss anyway): the stretch is read against a
        render of parameters still being fitted, a few tenths of a percent off where they are off,
        and kept only where the loss is lower at once."""
        losses = [self.objective.value(self.best.replace(tiles=t), self.best_blur) for t in (tiles, self.best.tiles)]
        return tiles if losses[0] < losses[1] else self.best.tiles

    def end_warp_trial(self) -> None:
        """Ends a warp's trial (:meth:`update_warp`) now: kept where the best loss under it is below
        the best before it, else undone."""
        trial, self._warp_trial = self._warp_trial, None
        if trial is None or self.best_loss < trial.best[0]:
            return
        self.objective.renderer.set_warp(trial.warp)
        with torch.no_grad():
            for name, value in trial.values.items():
                self.fabric.values[name].copy_(value)
        self.optimiser.load_state_dict(trial.adam)
        self.camera_blur_px = trial.camera_blur_px
        self.best_loss, self.best, self.best_blur, self.best_terms = trial.best

    def _loss(self, fabric: ParamTensors) -> float:
        return self.objective.value(fabric, self.camera_blur_px)

    def scan_glow(self) -> bool:
        """The back light's glow through the gaps as the photos show it: the transmission's colour
        term (:data:`GLOW_TERM`) at the current parameters at each strength of :data:`GLOW_SCAN` and
        the renderer's own, the lowest kept (the renderer's own where it ties). Where it changes, the
        current parameters become the best, with their loss under it (the best so far was judged
        under the other glow). Returns whether it changed.

        Why: with the spec's fixed strength a fit whose yarns leave gaps shows a round spot at the
        back light that a photo through a diffuser does not have; the fabric can only hide it by
        closing its gaps or blurring. Why the colour term, not the loss: at the fit's few samples per
        pixel the glow is a speckle (each pixel's share of samples through a gap) whose Monte Carlo
        noise the loss's spectrum term reads as excess texture, so the loss prefers a weaker glow
        than the photos show; a block mean has no such noise, though it reads a saturated spot high
        (the clamp of a pixel's few samples through gaps darkens it). Off by default
        (``FitSettings.estimate_glow``, fit option ``--glow``): the results' history says why."""
        renderer = self.objective.renderer
        if not renderer.options.glow:
            return False

        def terms() -> dict[str, float]:
            with torch.no_grad():
                return _on_host(self.objective.terms(self.fabric, self.camera_blur_px))

        before = renderer.rig.glow_strength
        found = {before: terms()}
        for strength in GLOW_SCAN:
            if strength not in found:
                renderer.set_glow(strength)
                found[strength] = terms()
        chosen = min(found, key=lambda strength: found[strength].get(GLOW_TERM, found[strength]["loss"]))
        renderer.set_glow(chosen)
        if chosen == before:
            return False
        self._keep_best(found[chosen]["loss"], found[chosen])
        return True

    def discrete_search(self, round_index: int) -> None:
        """In the first round a joint coarse step in gap scale (:data:`COARSE_GAP_STEPS`), then in
        every round parabolic steps on gap scale and twist per yarn (and on the camera blur when it is
        estimated), with spans halving each round."""
        current = self._loss(self.fabric)
        if round_index == 0:
            current = self._coarse_gap_step(current)
        spans = {"gap_scale": 0.04 / 2 ** round_index, "twist_deg": 4.0 / 2 ** round_index}
        for name, span in spans.items():
            spec = SPECS[name]
            for yarn in (0, 1):
                values = self.fabric.values[name]

                def clamped(v, spec=spec):
                    return min(spec.hi, max(spec.lo, v))

                def loss_at(v, values=values, yarn=yarn, name=name):
                    candidate = values.detach().clone()
                    candidate[yarn] = v
                    return self._loss(self.fabric.with_values(**{name: candidate}))

                x, current = parabolic_step(loss_at, float(values[yarn]), current, span, clamped)
                with torch.no_grad():
                    values[yarn] = x
        if self.estimates_blur:
            current = self._blur_step(current, 0.4 / 2 ** round_index)
        if current < self.best_loss:
            self._keep_best(current)

    def _coarse_gap_step(self, current: float) -> float:
        """The joint step of both yarns' gap scales by each of :data:`COARSE_GAP_STEPS` (clamped),
        the lowest loss kept where it is below ``current`` (the loss now); returns the loss kept."""
        gap = self.fabric.values["gap_scale"]
        spec = SPECS["gap_scale"]
        best_gap = None
        for offset in COARSE_GAP_STEPS:
            candidate = (gap.detach() + offset).clamp(spec.lo, spec.hi)
            value = self._loss(self.fabric.with_values(gap_scale=candidate))
            if value < current:
                current, best_gap = value, candidate
        if best_gap is not None:
            with torch.no_grad():
                gap.copy_(best_gap)
        return current

    def _blur_step(self, current: float, span: float) -> float:
        """The parabolic step of the discrete parameters, on the camera blur."""
        def loss_at(blur):
            return self.objective.value(self.fabric, blur)

        self.camera_blur_px, current = parabolic_step(loss_at, self.camera_blur_px, current, span,
                                                      self.blur_range.clamped)
        return current


def _on_host(terms: dict[str, torch.Tensor]) -> dict[str, float]:
    """The loss terms as numbers, brought from the device in one copy (each ``float`` of a GPU tensor
    is a copy of its own, and a wait)."""
    values = torch.stack([v.detach().reshape(()) for v in terms.values()]).cpu().tolist()
    return dict(zip(terms, values))


def parabolic_step(loss_at: Callable[[float], float], x: float, current: float, span: float,
                   clamped: Callable[[float], float]) -> tuple[float, float]:
    """One deterministic step on a discrete parameter: evaluate x - d and x + d (d = ``span``),
    then the minimum of the parabola through the three losses (at most 2 d away); returns the
    best of those points and x itself (``current`` is the loss at x), as (value, loss). Every
    value is passed through ``clamped`` before it is evaluated, and each value once: a point met
    again (x itself where the clamp holds it, or the parabola's step where a curvature of zero or
    less makes it +/- d) takes the loss it had (each evaluation renders the pair at the working
    size)."""
    seen = {x: current}

    def loss_at_clamped(value: float) -> float:
        value = clamped(value)
        if value not in seen:
            seen[value] = loss_at(value)
        return seen[value]

    lo, hi = loss_at_clamped(x - span), loss_at_clamped(x + span)
    curvature = lo + hi - 2 * current
    step = 0.5 * span * (lo - hi) / curvature if curvature > 1e-12 else (span if hi < lo else -span)
    step = max(-2 * span, min(2 * span, step))
    best_dx, best = min(((0.0, current), (-span, lo), (span, hi)), key=lambda t: t[1])
    value = loss_at_clamped(x + step)
    if value < best:
        best_dx, best = step, value
    return (clamped(x + best_dx), best) if best_dx != 0.0 else (x, current)
