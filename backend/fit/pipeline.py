"""Fitting fabric parameters to a reflection/transmission photo pair: the stages in order, each
taking the values the one before returned.

    placement  the sample's rotation and skew in the holder, read from the photos' spectra (unless
               the rotation is given) and kept only when its lattice candidates score higher than
               the unturned sample's (:func:`backend.texture.candidates.placed`): the lattice, the
               loss's probes and the renders all use it
    search     candidates from the spectra, starting points, camera blur, short trial fits, the
               pattern chosen by comparing them, among those whose lattice makes the photos'
               peaks: this module evaluates the objective and runs the trials, and hands the values
               to the decisions of :mod:`backend.fit.search`
    optimise   the winner's run goes on (at the working size, from its start: see coarse to
               fine): Adam on the continuous parameters and, where it is estimated, the camera blur;
               after ``first_search`` iterations and then every ``search_every`` the photos' uneven
               yarn spacing read again against its renders and tried (:mod:`backend.fit.warp`) and a
               parabolic step on the discrete parameters (:mod:`backend.fit.optimise`), at the first
               after the back light's glow through the gaps is read where asked (``settings.estimate_glow``:
               :meth:`backend.fit.optimise.Run.scan_glow`); where the best loss stops moving
               (:func:`converged`) it ends early, at the schedule's last learning rate, or else
               goes on from its best at that rate; after the last discrete search it ends once its
               best loss gains next to nothing (:func:`plateaued`)
    variation  the yarn variation the photos show, read from the texture power the regular weave
               leaves unexplained (:mod:`backend.fit.variation_estimate`); where it is kept, the run
               goes on from it for ``settings.settle_steps`` steps, and once more from a part of it
               where it moved the photos' overall colour too far (:func:`_with_variation`)
    coarse to fine
               with a working size above BASE_SIZE (dense weaves), the search runs at BASE_SIZE with
               the same samples per image, its camera blur on sub-pixels (:func:`_coarse`), and only
               the winner's optimisation at the working size, from the winner's start and after a
               fresh camera-blur scan there; its first ``duel_iterations`` steps beside its face
               twin on its lattice, which the trials at BASE_SIZE cannot tell from it
               (:func:`_finalist`)
    result     the best parameters seen (with the variation), their loss and terms, the camera blur
               and glow,
               the photos' light falloff at those parameters and their spacing warp, the candidates
               compared, the variation reading, the loss history and stage timings

Every render compared with the photos is made as they show the fabric: with the camera blur, under
the photos' light falloff solved for it (:mod:`backend.model.photo_light`; unless
``settings.light_falloff`` is off), and, once it is read, with their uneven yarn spacing (unless
``settings.spacing_warp`` is off).

Each stage reports through ``progress(stage, iteration, total, loss, eta_s)``; the optimiser adds
``since_best`` and ``patience`` (from them the whole-fit progress bar reads how soon it may end).
Everything is deterministic for a given input, settings and seed (fixed jitter, no random steps).
"""
from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import Callable

import numpy as np
import torch

from ..core import priors
from ..core.params import FabricParams
from ..core.rig import CaptureRig
from ..model.render import Renderer
from ..texture.candidates import Candidate
from ..texture.frequencies import lattice_of
from ..texture.lattice import peak_coverage
from ..texture.placement import place
from ..texture.spectra import Spectra
from . import search
from .gram import GramDescriptor
from .objective import Objective, Target
from .optimise import LR_MILESTONES, Run
from .settings import OPTIMISED, FitCancelled, FitResult, FitSettings, Progress
from .variation_estimate import READINGS, VariationEstimate, estimate_variation, with_scaled_variation

# The settling steps' learning rates as a part of the base rates (Run.start_over_from): the schedule's
# last, small steps that move the means back, where a run that stopped early would still take steps
# that search anew (and worsen the loss).
SETTLE_LR_FACTOR = 0.5 ** len(LR_MILESTONES)
# How far a settled varied fit may move either photo's overall colour from the photo's beyond where the
# regular weave has it (display units: one code value of an 8-bit image, a shift no display shows).
MEAN_COLOUR_SLACK = 1 / 255
# A variation that moved the colour too far is settled once more at a part of its amplitudes, chosen for a
# shift of this part of MEAN_COLOUR_SLACK (:func:`retreat_scale`): room for the settling's own scatter.
RETREAT_TARGET = 0.5
SETTLINGS = 2  # the variation's settlings at most: in full, then once at retreat_scale's part


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
    ``should_stop()`` is polled after every step: True raises :class:`FitCancelled` with the best
    parameters so far.
    """
    started = time.perf_counter()
    timings: dict[str, float] = {}
    torch.manual_seed(settings.seed)
    progress = progress or (lambda *args, **fields: None)
    patterns = priors.FIT_PATTERNS if settings.pattern == "auto" else (settings.pattern,)
    progress("search", 0, 1, None, None)
    spectra = Spectra.of([reflection, transmission], workers=torch.get_num_threads())
    (rotation, skew), found = place(spectra, rig, patterns, settings.sample_rotation,
                                   workers=torch.get_num_threads())
    rig = dataclasses.replace(rig, sample_rotation_deg=rotation, sample_skew_deg=skew)
    found = found or [Candidate(p, priors.typical(p).tiles, 0.0) for p in patterns]

    def check_stop(run: Run | None = None):
        if should_stop is not None and should_stop():
            raise FitCancelled(run.best if run is not None else None)

    @functools.cache  # by lattice: the search asks again for each pattern on it, and for each trial
    def coverage_at(tiles: tuple[float, float]) -> float:
        return peak_coverage(spectra, *lattice_of(tiles, rig), rotation, skew)

    def coverage_of(cand: Candidate) -> float:
        return coverage_at(tuple(cand.tiles))

    found, rated, ruled_out = _rated(found, pattern_probabilities, settings.min_pattern_probability, coverage_of, rig)
    timings["lattice_s"] = time.perf_counter() - started
    size = settings.size or search.working_size(found, np.asarray(reflection).shape[0], rig)
    settings = dataclasses.replace(settings, size=size, spp=settings.spp or search.samples_per_pixel(size),
                                   iterations=settings.iterations or search.iterations_for(size))
    coarse = _coarse(settings)
    objective = _objective(reflection, transmission, rig, coarse)

    def on_start(count, loss):
        progress("search", count, len(found), loss, None)
        check_stop()

    start_blur = rig.camera_blur_px if settings.camera_blur is None else settings.camera_blur
    starts = _starting_points(found, objective, start_blur, initial_for, on_start)
    blur, blur_range = _camera_blur(settings, reflection, transmission, rig.film_size, starts[0].params, objective)
    if blur_range is not None and len(starts) > 1:  # the starting losses change with the blur
        starts = search.reranked(starts, objective.values([s.params for s in starts], [blur] * len(starts)))
    trials = trial_runs(starts, objective, coarse, blur, blur_range, rated, check_stop,
                        lambda i, n, selection: progress("search", i, n, selection, None), coverage_of,
                        restarted=coarse is not settings)
    winner = search.chosen(trials)
    run, duel_steps = winner.run, 0
    if coarse is not settings:
        run, duel_steps = _finalist(winner, trials, ruled_out, _objective(reflection, transmission, rig, settings),
                                    objective, settings, blur, blur_range, initial_for, check_stop, progress)
    timings["search_s"] = time.perf_counter() - started

    loop_started = time.perf_counter()
    steps = _optimise(run, settings, check_stop, progress, duel_steps)
    timings["optimise_s"] = time.perf_counter() - loop_started
    timings["warp_s"] = run.warp_s  # of optimise_s
    variation_started = time.perf_counter()
    variation = _with_variation(run, settings, check_stop, progress) if settings.estimate_variation else None
    timings["variation_s"] = time.perf_counter() - variation_started
    with torch.no_grad():
        _, light = run.objective.rendered(run.best, run.best_blur)
    timings["total_s"] = time.perf_counter() - started
    return FitResult(run.best, run.best_loss, run.best_terms, [t.summary for t in trials] + ruled_out,
                     run.history, timings, run.best_blur, rotation, skew, light, settings.size, settings.spp,
                     settings.iterations, steps, run.objective.renderer.warp,
                     None if variation is None else variation.to_dict(), run.objective.renderer.rig.glow_strength,
                     None if blur_range is None else (blur_range.floor, blur_range.ceiling))


def _objective(reflection, transmission, rig: CaptureRig, settings: FitSettings) -> Objective:
    device = torch.device(settings.device)
    target = Target.from_arrays(reflection, transmission, settings.size, device)
    renderer = Renderer(rig, settings.size, settings.spp, settings.seed, device=device, compile=settings.compile,
                        gradient_inputs=OPTIMISED, subpixel_blur=settings.subpixel_blur)
    gram = GramDescriptor.load(settings.vgg_weights, device) if settings.vgg_weights else None
    return Objective(target, renderer, rig, settings.weights, settings.prior_weight, gram, settings.gram_weight,
                     settings.light_falloff)


def _rated(found: list[Candidate], pattern_probabilities, threshold: float,
           coverage_of: Callable[[Candidate], float], rig: CaptureRig) -> tuple[list[Candidate], dict, list[dict]]:
    """:func:`search.rated_candidates` of the network's probabilities and the lattices' peak coverages
    of every pattern on every lattice of its family, where a network rates more than one candidate;
    else (``found``, no probabilities, none ruled out)."""
    if pattern_probabilities is None or len(found) <= 1:
        return found, {}, []
    shared = search.family_lattices(found, rig)
    probabilities = pattern_probabilities(shared)
    if probabilities is None:
        return found, {}, []
    return search.rated_candidates(shared, probabilities, [coverage_of(c) for c in shared], threshold)


def _starting_points(candidates: list[Candidate], objective: Objective, camera_blur_px: float,
                     initial_for: Callable[[Candidate], FabricParams | None] | None,
                     on_start: Callable[[int, float], None]) -> list[search.Start]:
    """One start per candidate, lowest loss first; ``on_start(count, loss)`` after each. The
    network's guess (``initial_for``), or the pattern's typical parameters matched to the photos'
    colour at the best of a few gap scales (:mod:`backend.fit.search`, 2.)."""
    starts = []
    for k, cand in enumerate(candidates):
        guess = initial_for(cand) if initial_for is not None else None
        if guess is not None:
            tried = [guess.replace(tiles=cand.tiles)]
        else:
            typical = search.typical_start(cand)
            matched = search.colour_matched(typical, objective.colour_ratios(typical, camera_blur_px))
            tried = search.gap_variants(matched)
        loss, params = search.lowest(objective.values(tried, [camera_blur_px] * len(tried)), tried)
        starts.append(search.Start(loss, k, cand, params))
        on_start(k + 1, loss)
    return search.ranked(starts)


def _camera_blur(settings: FitSettings, reflection: np.ndarray, transmission: np.ndarray, film_size: int,
                 best_start: FabricParams, objective: Objective) -> tuple[float, search.BlurRange | None]:
    """(camera blur to fit with, the range it may move in while fitting, or None where it stays
    fixed): the scan's choice at the best start, in the range the photos allow
    (:func:`search.blur_range`)."""
    allowed = search.blur_range(settings, reflection, transmission, film_size)
    if allowed is None:
        return search.fixed_blur(settings), None
    return _best_blur(best_start, objective, allowed), allowed


def _best_blur(params: FabricParams, objective: Objective, allowed: search.BlurRange,
               also: float | None = None) -> float:
    """The camera blur of :func:`search.blur_scan` (in ``allowed``, and ``also``) with the lowest loss."""
    scan = search.blur_scan(allowed, also)
    return search.best_blur(scan, objective.values([params] * len(scan), scan))


def trial_runs(starts: list[search.Start], objective: Objective, settings: FitSettings, camera_blur_px: float,
               blur_range: search.BlurRange | None, rated: dict[int, float], check_stop: Callable[[Run], None],
               on_trial: Callable[[int, int, float], None],
               coverage_of: Callable[[Candidate], float], restarted: bool = False) -> list[search.Trial]:
    """The trials of the best ``settings.trials`` starts: a short fit of each that
    :func:`search.trial_plan` gives steps, its spectrum similarity, its selection
    (:func:`search.trial`); ``coverage_of(candidate)`` is its lattice's peak coverage,
    ``on_trial(count, total, selection)`` is called after each trial that takes steps (``total``: how
    many do; where none does, once, as (1, 1): the whole-fit progress paces the fit by the trials'
    work, and a start given no steps takes none).

    The runs' learning-rate schedules span the trial and the final iterations: at a working size of
    BASE_SIZE or below the winner goes on (above it, ``restarted``, the fit starts the winner again
    at the working size from ``Trial.start``)."""
    shortlisted = search.shortlisted(starts, settings.trials)
    coverages = [coverage_of(start.candidate) for start in shortlisted]
    plan = search.trial_plan([start.candidate for start in shortlisted], coverages, restarted)
    total = settings.iterations + settings.trial_iterations
    stepped, done = sum(tried for tried, _ in plan), 0
    trials = []
    for start, coverage, (tried, skipped) in zip(shortlisted, coverages, plan):
        run = Run(start.params, objective, settings, total, camera_blur_px, blur_range)
        for _ in range(settings.trial_iterations if tried else 0):
            run.step()
            check_stop(run)
        similarity = objective.spectrum_similarity(run.best, camera_blur_px) if tried else None
        trials.append(search.trial(start, run, coverage, similarity, rated.get(id(start.candidate)), skipped,
                                   settings.spectrum_weight))
        if tried:
            done += 1
            on_trial(done, stepped, trials[-1].selection)
    if not stepped:
        on_trial(1, 1, trials[0].selection)
    return trials


def _finalist(winner: search.Trial, trials: list[search.Trial], ruled_out: list[dict], fine: Objective,
              coarse: Objective, settings: FitSettings, blur: float, blur_range: search.BlurRange | None,
              initial_for, check_stop, progress: Progress) -> tuple[Run, int]:
    """(the run that goes on at the working size, the steps it has had), where the search ran coarse.

    The winner starts again from its start at the working size, as a lone candidate does: the trial
    steps at the base size chose the pattern, but where a yarn gets about a pixel there the loss
    reads an aliased weave, and going on from them can end worse. For the same reason the choice
    between a weave and its face twin on one lattice is made there (:func:`_finalists`): the twin
    runs beside the winner for ``duel_iterations`` steps, and goes on instead only where its loss is
    then lower by more than ``duel_margin`` (:func:`search.duelled`; while both adapt to the photos
    the lead can swing; the margin is twice the swing seen). The steps are the first of the
    optimisation's ``iterations``, so a winner that holds its place ends as it would have alone.
    Each finalist's summary records its loss there (``fine_trial_loss``).

    The winner starts at the camera blur the loss chooses at the working size (:func:`_fine_run`),
    not also from the photos' reading: a run from the reading beside it ended lower in one fit of
    26 measured, whose photo metrics it left the same within the fits' noise (the benchmark's
    results)."""
    finalists = _finalists(winner, trials, ruled_out, coarse, blur, initial_for, check_stop)
    # the schedule of a run at the base size (its trial steps and the optimiser's), though this one has
    # no trial steps: it ends at a quarter of the base rate, not an eighth (an eighth measured no
    # better: devtools/bench/results/history/fit.jsonl)
    total = settings.iterations + settings.trial_iterations
    runs = [_fine_run(params, fine, settings, total, blur, blur_range) for params, _ in finalists]
    steps = min(settings.duel_iterations, settings.iterations)
    if steps == 0 or len(runs) == 1:
        return runs[0], 0
    _duel_steps(runs, steps, check_stop, progress)
    for (_, summary), run in zip(finalists, runs):
        summary["fine_trial_loss"] = run.best_loss
    return runs[search.duelled([run.best_loss for run in runs], settings.duel_margin)], steps


def _finalists(winner: search.Trial, trials: list[search.Trial], ruled_out: list[dict], coarse: Objective,
               blur: float, initial_for, check_stop) -> list[tuple[FabricParams, dict]]:
    """(starting parameters, summary) of the winner and of its face twin on its lattice where there
    is one: a trial's (:func:`search.rival`), or else one the network ruled out, from its own start
    (:func:`search.untried_rival`)."""
    finalists = [(winner.start.params, winner.summary)]
    rival = search.rival(trials, winner)
    if rival is not None:
        finalists.append((rival.start.params, rival.summary))
    elif (untried := search.untried_rival(ruled_out, winner.start.candidate)) is not None:
        [start] = _starting_points([untried], coarse, blur, initial_for, lambda *_: check_stop())
        finalists.append((start.params, next(c for c in ruled_out if c["pattern"] == untried.pattern
                                             and tuple(c["tiles"]) == untried.tiles)))
    return finalists


def _fine_run(params: FabricParams, fine: Objective, settings: FitSettings, total: int, blur: float,
              blur_range: search.BlurRange | None) -> Run:
    """A run from ``params`` at the working size; where the blur is estimated, from the scan's choice
    there (the blur that matched at BASE_SIZE need not match at the working size)."""
    run = Run(params, fine, settings, total, blur, blur_range)
    if blur_range is not None:
        run.camera_blur_px = _best_blur(run.best, fine, blur_range, also=blur)
    return run


def _duel_steps(runs: list[Run], steps: int, check_stop, progress: Progress) -> None:
    """``steps`` steps of each run, one run after the other: the compiled renderer keeps to one weave
    at a time."""
    for k, run in enumerate(runs):
        for done in range(steps):
            run.step()
            check_stop(run)
            progress("search", k * steps + done + 1, len(runs) * steps, run.best_loss, None)


def _coarse(settings: FitSettings) -> FitSettings:
    """The settings of the search: BASE_SIZE with the same samples per image, its camera blur on
    sub-pixels, or ``settings`` itself when its size is not above BASE_SIZE.

    The photos the search reads are the area-downsample of photos blurred by the optics at the
    working size, so the search's renders are blurred on sub-pixels at twice BASE_SIZE before the same
    downsample (:mod:`backend.model.render`). Blurring the pixel means at BASE_SIZE instead keeps the
    aliases of a dense weave's yarn harmonics, which the photos' optics took off: the loss at the
    true parameters reads them as a mismatch, and the search can choose a weave on a coarser lattice.
    The working size's own renders blur as the settings say (the pixel means by default)."""
    if settings.size <= search.BASE_SIZE:
        return settings
    spp = max(1, round(settings.spp * (settings.size / search.BASE_SIZE) ** 2))
    return dataclasses.replace(settings, size=search.BASE_SIZE, spp=spp, subpixel_blur=True)


def _optimise(run: Run, settings: FitSettings, check_stop, progress: Progress, done: int = 0) -> int:
    """The winner's run goes on until it has had ``settings.iterations`` steps at the working size, or
    fewer where it has converged (:func:`converged`) or settled after its last discrete search
    (:func:`plateaued`); returns the steps it had there in all.

    ``done``: the steps it has had at the working size already (the duel's, :func:`_finalist`): it
    goes on from them as one run, so a winner that holds its place fits as it would have alone. With
    none (its steps were trial steps at the base size), it goes on from its best parameters so far
    with a fresh Adam state.

    Its steps take their gradients through a share of the film rows (``settings.gradient_period``,
    :class:`backend.model.render.GradientShare`), unlike the short runs before and after it (trials,
    duel, settling), whose ends are compared: a share's noise slows a run's first steps."""
    if done == 0:
        run.restart_from_best()
    loop_started = time.perf_counter()
    search_round = 0
    best, improved_at = run.best_loss, 0
    best_after: dict[int, float] = {}  # the best loss after each step here
    if done:  # where the best loss last moved in the steps it has had (each step keeps the loss before it)
        best = math.inf
        for step, (_, value) in enumerate(run.history, start=1):
            if value < best:
                best, improved_at = value, step
    for it in range(done, settings.iterations):
        value = run.step(settings.gradient_period)
        check_stop(run)
        done = it + 1
        if search_due(settings, done):
            if search_round == 0 and settings.estimate_glow and run.scan_glow():
                best, improved_at = run.best_loss, done   # the losses before were under another glow
            if settings.spacing_warp:
                run.update_warp()
            run.discrete_search(search_round)
            search_round += 1
        if run.best_loss < best:
            best, improved_at = run.best_loss, done
        best_after[done] = run.best_loss
        ended = plateaued(settings, done, best_after)
        if not ended and converged(settings, done, improved_at, search_round):
            if run.at_last_rate:
                ended = True
            else:   # a stall above the last rate: from the best, at the last rate
                run.end_warp_trial()
                run.lower_rate()
                improved_at = done
        if ended:
            run.end_warp_trial()
            progress("optimise", settings.iterations, settings.iterations, value, 0.0,
                     since_best=done - improved_at, patience=settings.patience)
            return done
        eta = (time.perf_counter() - loop_started) / done * (settings.iterations - done)
        # patience 0 while a stall would lower the rate, not end the run (the progress bar reads it)
        progress("optimise", done, settings.iterations, value, eta, since_best=done - improved_at,
                 patience=settings.patience if run.at_last_rate else 0)
    run.end_warp_trial()
    return done


def _with_variation(run: Run, settings: FitSettings, check_stop, progress: Progress) -> VariationEstimate:
    """The yarn variation the photos show, read at the run's best parameters and blur
    (:func:`backend.fit.variation_estimate.estimate_variation`). Where it is kept the run goes on
    from the varied parameters for ``settings.settle_steps`` steps at SETTLE_LR_FACTOR of the base
    learning rates, its best loss counted afresh: the variation moves the images' means (a
    yarn's transmission is convex in its thickness and width), which the albedos and thicknesses
    make up for. Where the settled fit's overall colour of either photo is still more than
    MEAN_COLOUR_SLACK further from the photo's than the regular weave's, the run settles once more
    from the regular weave's best at a part of the amplitudes read (:func:`retreat_scale`); where
    that part moves the colour too far as well, the variation is dropped and the regular weave
    kept (``reading.dropped``): the settling steps do not always bring a varied transmission's mean
    back. ``reading.scale`` is the part of the amplitudes read that the fit keeps, and
    ``reading.settled`` each settling's (scale, colour shift).

    Why the overall colour and not the loss's 16 x 16 colour term: a random yarn pattern never lies
    where the photo's does, so in blocks of a few yarns even the true variation adds colour error
    (two independent patterns differ by more than either differs from their mean), and that term
    dropped the variation of most photos that have it; over the whole image the pattern averages
    out and what is left is the shift of the fabric's colour the guard is for. Why a part before
    none: the shift grows with the square of the amplitudes where the one it has to make up for is
    the convexity's, so a smaller variation keeps most of the texture the photos show at a
    fraction of the shift."""
    total = READINGS + settings.settle_steps

    def counted(done: int, of: int = total) -> None:
        check_stop(run)
        progress("variation", done, of, run.best_loss, None)

    progress("variation", 0, total, run.best_loss, None)
    varied, reading = estimate_variation(run.best, run.objective, run.best_blur, settings.seed, counted)
    if reading.kept:
        regular = (run.best_loss, run.best, run.best_blur, run.best_terms)
        start_blur, scale, before = run.camera_blur_px, 1.0, None
        for settling in range(SETTLINGS):
            run.camera_blur_px = start_blur
            done = READINGS + settling * settings.settle_steps
            _settle(run, with_scaled_variation(varied, scale), settings,
                    lambda step: counted(done + 1 + step, max(total, done + settings.settle_steps)))
            if before is None:  # the regular weave's, read once (after the first settling, as it always was)
                before = run.objective.mean_colour_errors(regular[1], regular[2])
            after = run.objective.mean_colour_errors(run.best, run.best_blur)
            shift = tuple(a - b for a, b in zip(after, before))
            reading.settled.append({"scale": scale, "colour_shift": shift})
            if max(shift) <= MEAN_COLOUR_SLACK:
                break
            run.best_loss, run.best, run.best_blur, run.best_terms = regular
            scale = retreat_scale(max(shift))
        else:
            reading.kept, reading.dropped = False, "colour"
        total = READINGS + len(reading.settled) * settings.settle_steps
    progress("variation", total, total, run.best_loss, 0.0)
    return reading


def _settle(run: Run, varied: FabricParams, settings: FitSettings, on_step: Callable[[int], None]) -> None:
    """The run goes on from ``varied`` for ``settings.settle_steps`` steps at SETTLE_LR_FACTOR of the
    base learning rates, its best counted afresh (:func:`_with_variation`)."""
    run.start_over_from(varied, SETTLE_LR_FACTOR)
    for step in range(settings.settle_steps):
        run.step()
        on_step(step)


def retreat_scale(shift: float) -> float:
    """The part of a variation's amplitudes to settle again where, in full, it moved an overall colour
    by ``shift`` (> MEAN_COLOUR_SLACK): the shift taken as growing with the amplitudes' square, the
    part that moves it by RETREAT_TARGET of the slack."""
    return math.sqrt(RETREAT_TARGET * MEAN_COLOUR_SLACK / shift)


def search_due(settings: FitSettings, done: int) -> bool:
    """Whether a discrete search follows step ``done`` (counted from 1): after ``first_search``
    steps, then every ``search_every``, ``max_searches`` in all, never after the last step (the
    defaults, 25, 25 and 3, give searches after 25, 50 and 75 steps at 512 px and at 256 px)."""
    after = done - settings.first_search
    return (bool(settings.search_every) and 0 <= after and done < settings.iterations
            and after % settings.search_every == 0 and after // settings.search_every < settings.max_searches)


def last_search(settings: FitSettings) -> int:
    """The step after which the run's last discrete search comes (:func:`search_due`; 0: none)."""
    return max((done for done in range(1, settings.iterations) if search_due(settings, done)), default=0)


def plateaued(settings: FitSettings, done: int, best_after: dict[int, float]) -> bool:
    """Whether the optimisation has settled after ``done`` steps (``best_after[k]``: its best loss after
    step k): no discrete search is left, the last was ``settings.plateau_window`` steps ago or more,
    and over the last window its best loss gained less than ``settings.plateau_gain`` of itself.

    Why: after the last search the run only refines at a quarter of the base rate, and a window's
    gain falls below the loss's own mean change from one step to the next (the gradient shares'
    scatter); those steps cost as much as any other (the benchmark's results)."""
    window = settings.plateau_window
    if not settings.plateau_gain or window <= 0 or done - last_search(settings) < window:
        return False
    before, now = best_after.get(done - window), best_after[done]
    return before is not None and before - now < settings.plateau_gain * abs(now)


def converged(settings: FitSettings, done: int, improved_at: int, searches: int) -> bool:
    """Whether the optimisation has stalled after ``done`` steps: the best loss has not moved for
    ``settings.patience`` steps (it last moved after step ``improved_at``), and where a discrete
    search is due in the run, at least one (``searches``) has had its turn: a search can move the
    loss after a stall. A stalled run ends at the schedule's last learning rate; above it, it goes
    on from its best at that rate (:meth:`backend.fit.optimise.Run.lower_rate`)."""
    if not settings.patience or done - improved_at < settings.patience:
        return False
    return searches > 0 or not search_due(settings, settings.first_search)  # none falls inside the run
