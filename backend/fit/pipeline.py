"""Fitting fabric parameters to a reflection/transmission photo pair.

Stages (each reported through ``progress(stage, iteration, total, loss, eta_s)``):

1. *search*: one (pattern, tiles) candidate per preset from the photos' spectra
   (:mod:`backend.texture.candidates`); every candidate starts from its pattern's typical parameters (or a given
   initial guess) with colours matched to the photos (candidates an initialisation network rates
   below ``min_pattern_probability`` are dropped first), and the best ``trials`` of them (by that
   starting loss) get a short fit. The pattern is chosen by comparing those fits: trial loss plus
   ``spectrum_weight`` x (1 - correlation of the log power spectra of render and photo). The loss
   reads harmonics at each candidate's own lattice, so a lattice twice too coarse would not be
   charged for the photo's odd harmonics; the spectrum sees every peak, whatever the lattice.
2. *optimise*: Adam on the continuous parameters (roughness, thickness, their multiple-scattering
   twins, height scale, albedos, diffuse weight, multiple weight), each with a learning rate
   proportional to its declared range and halved at 50, 70 and 85 % of the run; every parameter
   is clamped into its range after each step. Every ``search_every`` iterations the discrete
   parameters (gap scale and twist, per yarn) take a deterministic parabolic step on the loss:
   evaluate x - d, x, x + d, move to the parabola's minimum if that lowers the loss (a better
   use of evaluations than the paper's random +/- steps). Tiles come from the lattice, which pins
   them to a fraction of a percent, and stay fixed.
   The camera's blur (the rig's ``camera_blur_px``: a phone photo is softer than a sharp render,
   and without it the fit washes the yarns out to match): unless the settings fix it, photos whose
   noise spectrum is as flat as a render's (:mod:`backend.image.camera_blur`) get none; softer ones get a
   scan before the trial fits and the same parabolic step in every round, never below the blur
   their noise shows.
3. the best parameters seen are returned (with the camera blur, the loss history and timings).

Everything is deterministic for a given input, settings and seed (fixed jitter, no random steps).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from ..core import priors
from ..image.camera_blur import SOFT_PHOTO_PX, photo_blur_px
from ..texture.features import LossWeights
from .objective import Objective, Target
from ..model.param_tensors import ParamTensors
from ..core.params import PARAMETERS, SPECS, FabricParams
from ..model.render import Renderer
from ..core.rig import MAX_CAMERA_BLUR_PX, CaptureRig
from ..texture.candidates import Candidate, propose

OPTIMISED = tuple(s.name for s in PARAMETERS if s.optimised)
Progress = Callable[[str, int, int, float | None, float | None], None]


class FitCancelled(Exception):
    """Raised from inside the loop when the caller asks to stop; carries the best parameters so far."""

    def __init__(self, params: FabricParams | None):
        super().__init__("cancelled")
        self.params = params


@dataclass(frozen=True)
class FitSettings:
    pattern: str = "auto"            # a preset name, or "auto" to choose by comparing fits
    iterations: int = 150
    size: int = 256                  # working size of the loss (photos are area-downsampled to it)
    spp: int = 16
    seed: int = 0
    trials: int = 5                  # candidates given a short fit in the search stage
    trial_iterations: int = 20
    spectrum_weight: float = 1.0     # weight of the spectrum mismatch when choosing between trials
    min_pattern_probability: float = 0.02  # candidates the network rules out get no trial fit
    search_every: int = 25
    lr: float = 0.02                 # Adam step as a fraction of each parameter's range
    weights: LossWeights = LossWeights()
    prior_weight: float = 0.002
    device: str = "cpu"
    compile: bool | None = None      # None: torch.compile where a C++ compiler is found
    vgg_weights: str | None = None   # adds the paper's VGG-19 Gram loss (user-supplied weights)
    gram_weight: float = 1.0
    camera_blur: float | None = None  # film pixels; None: estimated from the photos


@dataclass
class FitResult:
    params: FabricParams
    loss: float
    terms: dict[str, float]
    candidates: list[dict]
    history: list[tuple[int, float]]
    timings: dict[str, float] = field(default_factory=dict)
    camera_blur_px: float = 0.0


def _number(value) -> float:
    """A loss term as a float (a tensor is detached first: it may carry the graph)."""
    return float(value.detach()) if isinstance(value, torch.Tensor) else float(value)


def _colour_matched(params: FabricParams, objective: Objective) -> FabricParams:
    """Scales the albedos so the render's mean linear colour matches the photos' (per channel)."""
    with torch.no_grad():
        pair = objective.renderer.render(params)
    gamma = objective.rig.gamma

    def ratio(render, photo):
        r = render.clamp_min(0).pow(gamma).mean(dim=(0, 1))
        p = photo.clamp_min(0).pow(gamma).mean(dim=(0, 1))
        return (p / r.clamp_min(1e-4)).clamp(0.05, 20.0).tolist()

    r_ratio = ratio(pair.reflection, objective.target.reflection)
    t_ratio = ratio(pair.transmission, objective.target.transmission)

    def scaled(rgb, factors):
        return tuple(min(1.0, max(0.0, c * f)) for c, f in zip(rgb, factors))

    return FabricParams.clamped_from(
        pattern=params.pattern, weave=params.weave,
        **{**{s.name: getattr(params, s.name) for s in PARAMETERS},
           "diffuse_reflection": scaled(params.diffuse_reflection, r_ratio),
           "specular_albedo": tuple(scaled(yarn, r_ratio) for yarn in params.specular_albedo),
           "diffuse_transmission": scaled(params.diffuse_transmission, t_ratio)})


GAP_SCAN = (0.75, 0.85, 0.9, 0.95, 1.0)
BLUR_SCAN = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0)  # film pixels


def _best_blur(params: FabricParams, objective: Objective, device, floor: float) -> float:
    """The camera blur among ``floor`` and the BLUR_SCAN values above it with the lowest loss for
    ``params`` (set on the renderer)."""
    fabric = ParamTensors.from_params(params, device)
    losses = []
    scan = (floor,) + tuple(b for b in BLUR_SCAN if b > floor)
    for blur in scan:
        objective.renderer.camera_blur_px = blur
        with torch.no_grad():
            losses.append(float(objective(fabric)))
    objective.renderer.camera_blur_px = scan[int(np.argmin(losses))]
    return objective.renderer.camera_blur_px


def _best_gap(params: FabricParams, objective: Objective, device) -> tuple[float, FabricParams]:
    """The starting gap scale (same for warp and weft) with the lowest loss among GAP_SCAN and the
    current one: gaps change the transmission image more than anything, so start near the right one."""
    best = None
    for gap in (params.gap_scale,) + tuple((g, g) for g in GAP_SCAN):
        trial = params.replace(gap_scale=gap)
        with torch.no_grad():
            loss = float(objective(ParamTensors.from_params(trial, device)))
        if best is None or loss < best[0]:
            best = (loss, trial)
    return best


def _spectrum_similarity(params: FabricParams, objective: Objective) -> float:
    """Mean over R and T of the log-power-spectrum correlation between a render and the photo."""
    from ..image.metrics import spectrum_corr

    with torch.no_grad():
        pair = objective.renderer.render(params)
    target = objective.target
    return 0.5 * sum(spectrum_corr(photo.cpu().numpy(), render.cpu().numpy())
                     for photo, render in ((target.reflection, pair.reflection), (target.transmission, pair.transmission)))


class _Run:
    """One optimisation run: parameters, Adam state, best-so-far tracking."""

    def __init__(self, params: FabricParams, objective: Objective, settings: FitSettings, total: int,
                 blur_floor: float | None = None):
        self.objective, self.settings, self.total = objective, settings, total
        self.fabric = ParamTensors.from_params(params, objective.renderer.device, requires_grad=OPTIMISED)
        groups = [{"params": [self.fabric.values[n]], "lr": settings.lr * (SPECS[n].hi - SPECS[n].lo),
                   "name": n} for n in OPTIMISED]
        self.optimiser = torch.optim.Adam(groups, eps=1e-6)
        self.base_lr = [g["lr"] for g in groups]
        self.step_count = 0
        self.best_loss = math.inf
        self.best = params
        self.best_blur = objective.renderer.camera_blur_px
        self.blur_floor = blur_floor  # None: the camera blur stays as it is
        self.best_terms: dict[str, float] = {}
        self.history: list[tuple[int, float]] = []
        self.selection = math.inf

    def _schedule(self):
        progress = self.step_count / max(self.total, 1)
        factor = 0.5 ** sum(progress >= p for p in (0.5, 0.7, 0.85))
        for group, lr in zip(self.optimiser.param_groups, self.base_lr):
            group["lr"] = lr * factor

    def step(self) -> float:
        self._schedule()
        self.optimiser.zero_grad(set_to_none=True)
        terms = self.objective.terms(self.fabric)
        loss = terms["loss"]
        value = float(loss.detach())
        if not math.isfinite(value):
            bad = ", ".join(k for k, v in terms.items() if not math.isfinite(_number(v)))
            raise FloatingPointError(f"the fit's loss is not finite ({bad}) at {self.fabric.to_params().to_interchange()}")
        loss.backward()
        if value < self.best_loss:  # the parameters that produced this loss (before the step)
            self.best_loss, self.best = value, self.fabric.to_params()
            self.best_blur = self.objective.renderer.camera_blur_px
            self.best_terms = {k: _number(v) for k, v in terms.items()}
        self.optimiser.step()
        self.fabric.clamp_()
        self.history.append((self.step_count, value))
        self.step_count += 1
        return value

    def evaluate(self, fabric: ParamTensors) -> float:
        with torch.no_grad():
            return float(self.objective(fabric))

    def discrete_search(self, round_index: int):
        """A joint coarse step in gap scale, then parabolic steps on gap scale and twist per yarn,
        with spans shrinking each round."""
        current = self.evaluate(self.fabric)
        gap = self.fabric.values["gap_scale"]
        spec = SPECS["gap_scale"]
        best_gap = None
        for offset in (-0.1, -0.05, 0.05, 0.1):
            candidate = (gap.detach() + offset).clamp(spec.lo, spec.hi)
            value = self.evaluate(self.fabric.with_values(gap_scale=candidate))
            if value < current:
                current, best_gap = value, candidate
        if best_gap is not None:
            with torch.no_grad():
                gap.copy_(best_gap)
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
                    return self.evaluate(self.fabric.with_values(**{name: candidate}))

                x, current = _parabolic_step(loss_at, float(values[yarn]), current, span, clamped)
                with torch.no_grad():
                    values[yarn] = x
        if self.blur_floor is not None:
            current = self._blur_step(current, 0.4 / 2 ** round_index)
        if current < self.best_loss:
            self.best_loss, self.best = current, self.fabric.to_params()
            self.best_blur = self.objective.renderer.camera_blur_px

    def _blur_step(self, current: float, span: float) -> float:
        """The parabolic step of the discrete parameters, on the renderer's camera blur."""
        renderer = self.objective.renderer

        def clamped(blur):
            return min(MAX_CAMERA_BLUR_PX, max(self.blur_floor, blur))

        def loss_at(blur):
            renderer.camera_blur_px = blur
            return self.evaluate(self.fabric)

        renderer.camera_blur_px, current = _parabolic_step(loss_at, renderer.camera_blur_px, current, span, clamped)
        return current


def _parabolic_step(loss_at: Callable[[float], float], x: float, current: float, span: float,
                    clamped: Callable[[float], float]) -> tuple[float, float]:
    """One deterministic step on a discrete parameter: evaluate x - d and x + d (d = ``span``),
    then the minimum of the parabola through the three losses (at most 2 d away); returns the
    best of those points and x itself (``current`` is the loss at x), as (value, loss). Every
    value is passed through ``clamped`` before it is evaluated."""
    lo, hi = loss_at(clamped(x - span)), loss_at(clamped(x + span))
    curvature = lo + hi - 2 * current
    step = 0.5 * span * (lo - hi) / curvature if curvature > 1e-12 else (span if hi < lo else -span)
    step = max(-2 * span, min(2 * span, step))
    best_dx, best = min(((0.0, current), (-span, lo), (span, hi)), key=lambda t: t[1])
    value = loss_at(clamped(x + step))
    if value < best:
        best_dx, best = step, value
    return (clamped(x + best_dx), best) if best_dx != 0.0 else (x, current)


def fit(reflection: np.ndarray, transmission: np.ndarray, rig: CaptureRig = CaptureRig(),
        settings: FitSettings = FitSettings(), progress: Progress | None = None,
        initial_for: Callable[[Candidate], FabricParams | None] | None = None,
        pattern_probabilities: Callable[[list[Candidate]], list[float] | None] | None = None,
        should_stop: Callable[[], bool] | None = None) -> FitResult:
    """Fits parameters to a photo pair (display-space float arrays (N, N, 3) in [0, 1]).

    ``initial_for(candidate)`` may give the starting parameters of a (pattern, tiles) candidate (the
    initialisation network does); None, or no callback, starts from the pattern's typical values.
    ``pattern_probabilities(candidates)`` may rate the candidates (the network's pattern softmax):
    those below ``settings.min_pattern_probability`` are dropped before the trial fits.
    """
    started = time.perf_counter()
    timings: dict[str, float] = {}
    torch.manual_seed(settings.seed)
    progress = progress or (lambda *args: None)
    device = torch.device(settings.device)
    target = Target.from_arrays(reflection, transmission, settings.size, device)
    renderer = Renderer(rig, settings.size, settings.spp, settings.seed, device=device, compile=settings.compile)
    gram = None
    if settings.vgg_weights:
        from .gram import GramDescriptor

        gram = GramDescriptor.load(settings.vgg_weights, device)
    objective = Objective(target, renderer, rig, settings.weights, settings.prior_weight, gram, settings.gram_weight)

    def check_stop(best: FabricParams | None):
        if should_stop is not None and should_stop():
            raise FitCancelled(best)

    # -- search: candidates from the spectrum, ranked by their starting loss, short fits --------
    patterns = priors.PATTERNS if settings.pattern == "auto" else (settings.pattern,)
    progress("search", 0, 1, None, None)
    found = propose(reflection, transmission, rig, patterns, per_pattern=1)
    if not found:
        found = [Candidate(p, priors.typical(p).tiles, 0.0) for p in patterns]
    ruled_out, rated = [], {}
    if pattern_probabilities is not None and len(found) > 1:
        probabilities = pattern_probabilities(found)
        if probabilities is not None:
            rated = {id(c): p for c, p in zip(found, probabilities)}
            kept = [c for c, p in zip(found, probabilities) if p >= settings.min_pattern_probability]
            ruled_out = [{"pattern": c.pattern, "tiles": list(c.tiles), "lattice_score": c.score,
                          "probability": p} for c, p in zip(found, probabilities)
                         if p < settings.min_pattern_probability]
            found = kept or [found[int(np.argmax(probabilities))]]
    timings["lattice_s"] = time.perf_counter() - started
    starts = []
    for k, cand in enumerate(found):
        guess = initial_for(cand) if initial_for is not None else None
        if guess is not None:
            params = guess.replace(tiles=cand.tiles)
            with torch.no_grad():
                loss = float(objective(ParamTensors.from_params(params, device)))
        else:
            params = _colour_matched(priors.typical(cand.pattern).replace(tiles=cand.tiles), objective)
            loss, params = _best_gap(params, objective, device)
        starts.append((loss, k, cand, params))
        progress("search", k + 1, len(found), loss, None)
        check_stop(None)
    starts.sort(key=lambda t: (t[0], t[1]))
    blur_floor = None
    if settings.camera_blur is not None:
        renderer.camera_blur_px = settings.camera_blur
    elif (photo_blur := photo_blur_px(reflection, transmission, rig.film_size)) < SOFT_PHOTO_PX:
        renderer.camera_blur_px = 0.0  # as sharp as a render: a blur would only hide model error
    else:
        blur_floor = min(photo_blur, MAX_CAMERA_BLUR_PX)
        _best_blur(starts[0][3], objective, device, blur_floor)
        if len(starts) > 1:  # the starting losses change with the blur: rank the candidates again
            with torch.no_grad():
                starts = sorted(((float(objective(ParamTensors.from_params(p, device))), k, c, p)
                                 for _, k, c, p in starts), key=lambda t: (t[0], t[1]))
    shortlisted = starts[: max(1, settings.trials)]
    runs, summary = [], []
    total = settings.iterations + settings.trial_iterations
    for index, (loss, _, cand, params) in enumerate(shortlisted):
        run = _Run(params, objective, settings, total, blur_floor)
        for it in range(settings.trial_iterations if len(shortlisted) > 1 else 0):
            run.step()
            check_stop(run.best)
        trial_loss = run.best_loss if run.history else loss
        similarity = _spectrum_similarity(run.best, objective) if len(shortlisted) > 1 else 1.0
        run.selection = trial_loss + settings.spectrum_weight * (1.0 - similarity)
        progress("search", index + 1, len(shortlisted), run.selection, None)
        runs.append(run)
        summary.append({"pattern": cand.pattern, "tiles": list(cand.tiles), "lattice_score": cand.score,
                        "start_loss": loss, "trial_loss": trial_loss, "spectrum_corr": similarity,
                        "selection": run.selection, "probability": rated.get(id(cand))})
    summary += ruled_out
    best_run = min(runs, key=lambda r: (r.selection, runs.index(r)))
    timings["search_s"] = time.perf_counter() - started

    # -- optimise the winner ------------------------------------------------------------------
    run = best_run
    run.fabric = ParamTensors.from_params(run.best, device, requires_grad=OPTIMISED) if run.history else run.fabric
    run.optimiser = torch.optim.Adam([{"params": [run.fabric.values[n]], "lr": lr, "name": n}
                                      for n, lr in zip(OPTIMISED, run.base_lr)], eps=1e-6)
    loop_started = time.perf_counter()
    search_round = 0
    for it in range(settings.iterations):
        value = run.step()
        check_stop(run.best)
        if settings.search_every and (it + 1) % settings.search_every == 0 and it + 1 < settings.iterations:
            run.discrete_search(search_round)
            search_round += 1
        done = it + 1
        eta = (time.perf_counter() - loop_started) / done * (settings.iterations - done)
        progress("optimise", done, settings.iterations, value, eta)
    timings["optimise_s"] = time.perf_counter() - loop_started
    timings["total_s"] = time.perf_counter() - started
    return FitResult(run.best, run.best_loss, run.best_terms, summary, run.history, timings, run.best_blur)
