"""The search stage of a fit: which weave, at what density, from where, with how much camera blur.

1. Candidates: one (pattern, tiles) per preset from the photos' spectra
   (:func:`backend.texture.candidates.propose`); an initialisation network may rate them, each
   pattern on every lattice proposed in its family (:func:`family_lattices`), and those it gives
   less than ``min_pattern_probability`` are dropped (:func:`rated_candidates`), unless they are of
   a family it keeps and their lattice makes far more of the photos' peaks than every kept
   candidate's.
2. Starting points (:func:`starting_points`): the network's guess for a candidate, or the
   pattern's typical parameters with the albedos scaled to the photos' mean colour
   (:func:`colour_matched`) and the best of a few gap scales (:func:`best_gap`); ranked by loss.
3. Camera blur (:func:`camera_blur`): fixed when given; none for photos whose noise is as white as a
   render's (:mod:`backend.image.camera_blur`); otherwise the best of a scan (:func:`best_blur`),
   never below the blur the photos' noise shows, which also becomes the optimiser's lower bound.
4. Trials (:func:`trial_runs`): the best ``trials`` starts get a short fit each; the pattern is the
   one whose trial ends lowest in loss + ``spectrum_weight`` x (1 - spectrum correlation of render
   and photo): the loss reads harmonics at each candidate's own lattice, so a lattice twice too
   coarse would not be charged for the photo's odd harmonics; the spectrum sees every peak.
   Only trials whose lattice makes nearly as much of the photos' peak strength as the best trial's
   are eligible (:func:`chosen`): a lattice too fine on one axis compares fewer, easier harmonics,
   and its trial can end lowest while the photos' strongest peak is none of its harmonics.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from ..core import priors, weave
from ..core.params import PARAMETERS, FabricParams
from ..core.rig import MAX_CAMERA_BLUR_PX, CaptureRig
from ..image.camera_blur import SOFT_PHOTO_PX, photo_blur_px
from ..image.metrics import spectrum_corr
from ..texture.candidates import Candidate, tile_range
from ..texture.frequencies import yarns_in_view
from .objective import Objective
from .optimise import Run
from .settings import FitSettings

GAP_SCAN = (0.75, 0.85, 0.9, 0.95, 1.0)
BASE_SIZE, BASE_SPP = 256, 16
BASE_ITERATIONS, FINE_ITERATIONS = 150, 100
MIN_PIXELS_PER_YARN = 2.5
BLUR_SCAN = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0)  # film pixels
COVERAGE_MARGIN = 0.3  # eligible: a peak coverage at most this far below the best trial's (chosen)


@dataclass
class Start:
    loss: float
    order: int              # the candidate's place in the proposal (breaks ties)
    candidate: Candidate
    params: FabricParams


@dataclass
class Trial:
    start: Start
    run: Run
    summary: dict           # what params.json's fit.candidates records for it
    selection: float        # trial loss + spectrum mismatch: the lowest eligible one wins
    coverage: float         # the share of the photos' peak strength its lattice makes (lattice.peak_coverage)


def working_size(candidates: list[Candidate], photo_size: int, rig: CaptureRig) -> int:
    """The loss's working size: BASE_SIZE, or the photos' own size when a candidate's yarns would get
    fewer than MIN_PIXELS_PER_YARN pixels at BASE_SIZE (dense weaves: 2-3 px per yarn at 512 px, past
    the sampling limit at 256)."""
    yarns = max((y for c in candidates if (y := yarns_in_view(c.pattern, c.tiles, rig)) is not None), default=0.0)
    return photo_size if photo_size > BASE_SIZE and BASE_SIZE / max(yarns, 1e-9) < MIN_PIXELS_PER_YARN else BASE_SIZE


def samples_per_pixel(size: int) -> int:
    """BASE_SPP at BASE_SIZE, and as many samples per image at other sizes (at least 4: a 2 x 2 jitter)."""
    return max(4, round(BASE_SPP * (BASE_SIZE / size) ** 2))


def iterations_for(size: int) -> int:
    """The optimisation's default length: BASE_ITERATIONS at BASE_SIZE or below, FINE_ITERATIONS
    above, where a step costs about twice as much (same samples per image, four times the pixels to
    blur, transform and compare)."""
    return BASE_ITERATIONS if size <= BASE_SIZE else FINE_ITERATIONS


LATTICE_MATCH = 0.01  # two candidates' tiles within 1 % on both axes are one lattice


def family_lattices(found: list[Candidate], rig: CaptureRig) -> list[Candidate]:
    """``found`` with each pattern also on every lattice proposed for another pattern of its family
    (plain, twill, satin) that its tile range allows (:func:`backend.texture.candidates.tile_range`),
    once per lattice: each pattern's own candidate, then the others in the order of ``found``.

    The lattice of a preset comes from the harmonics its typical render shows, and twins differ there:
    photo-like satin0m_008 of seed 7 had satin0m proposed on tiles (46.1, 13.7), a lattice that makes
    0.28 of the photos' peak strength, while satin1m was on the true one (22.2, 40.9), 0.92. The
    network, shown every pattern on every lattice of its family, gives satin0m 0.99 on the true lattice
    (on its own, 0.0)."""
    lattices = {}
    for cand in found:
        lattices.setdefault(priors.family(cand.pattern), []).append(cand)
    shared: list[Candidate] = []

    def listed(pattern: str, tiles) -> bool:
        return any(c.pattern == pattern and same_lattice(c.tiles, tiles) for c in shared)

    for cand in found:
        if not listed(cand.pattern, cand.tiles):
            shared.append(cand)
        (u_lo, u_hi), (v_lo, v_hi) = tile_range(cand.pattern, rig)
        for origin in lattices[priors.family(cand.pattern)]:
            tu, tv = origin.tiles
            if u_lo <= tu <= u_hi and v_lo <= tv <= v_hi and not listed(cand.pattern, origin.tiles):
                shared.append(Candidate(cand.pattern, origin.tiles, origin.score))
    return shared


def same_lattice(tiles, other) -> bool:
    return all(abs(t - o) <= LATTICE_MATCH * max(t, o) for t, o in zip(tiles, other))


def rated_candidates(found: list[Candidate], pattern_probabilities, threshold: float,
                     coverage_of: Callable[[Candidate], float], rig: CaptureRig
                     ) -> tuple[list[Candidate], dict[int, float], list[dict]]:
    """(kept candidates, probability by id(candidate), summaries of those ruled out).

    The network rates every pattern on every lattice of its family (:func:`family_lattices`) and
    rules out the candidates it gives less than ``threshold``, but not one of a weave family it
    keeps (plain, twill, satin) whose lattice makes more than COVERAGE_MARGIN more of the photos' peak
    strength (``coverage_of``, :func:`backend.texture.lattice.peak_coverage`) than every kept
    candidate: :func:`chosen` would rule all the kept ones out once trialled beside it. The network
    reads the harmonics at each candidate's lattice, and can keep a family on a wrong lattice alone.
    Its family stands: the coverage is one-sided (a lattice too coarse explains every peak), so it
    cannot bring in another family (real twill1: a satin0 lattice too coarse, 0.94, beside the kept
    twills' 0.60, would have won)."""
    if pattern_probabilities is None or len(found) <= 1:
        return found, {}, []
    shared = family_lattices(found, rig)
    probabilities = pattern_probabilities(shared)
    if probabilities is None:
        return found, {}, []
    found = shared
    rated = {id(c): p for c, p in zip(found, probabilities)}
    coverage = {id(c): coverage_of(c) for c in found}
    kept = [c for c, p in zip(found, probabilities) if p >= threshold] or [found[int(np.argmax(probabilities))]]
    kept_ids = {id(c) for c in kept}
    families = {priors.family(c.pattern) for c in kept}
    bar = max(coverage[id(c)] for c in kept) + COVERAGE_MARGIN

    def keeps(c: Candidate) -> bool:
        return id(c) in kept_ids or priors.family(c.pattern) in families and coverage[id(c)] > bar

    ruled_out = [{"pattern": c.pattern, "tiles": list(c.tiles), "lattice_score": c.score,
                  "peak_coverage": coverage[id(c)], "probability": rated[id(c)]}
                 for c in found if not keeps(c)]
    return [c for c in found if keeps(c)], rated, ruled_out


def colour_matched(params: FabricParams, objective: Objective, camera_blur_px: float) -> FabricParams:
    """Scales the albedos so the render's mean linear colour matches the photos' (per channel)."""
    with torch.no_grad():
        pair = objective.renderer.render(params, camera_blur_px=camera_blur_px)
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


def best_gap(params: FabricParams, objective: Objective, camera_blur_px: float) -> tuple[float, FabricParams]:
    """The starting gap scale (same for warp and weft) with the lowest loss among GAP_SCAN and the
    current one, as (loss, params): gaps change the transmission image more than anything."""
    best = None
    for gap in (params.gap_scale,) + tuple((g, g) for g in GAP_SCAN):
        trial = params.replace(gap_scale=gap)
        loss = objective.value(trial, camera_blur_px)
        if best is None or loss < best[0]:
            best = (loss, trial)
    return best


def starting_points(candidates: list[Candidate], objective: Objective, camera_blur_px: float,
                    initial_for: Callable[[Candidate], FabricParams | None] | None,
                    on_start: Callable[[int, float], None]) -> list[Start]:
    """One start per candidate, lowest loss first; ``on_start(count, loss)`` after each."""
    starts = []
    for k, cand in enumerate(candidates):
        guess = initial_for(cand) if initial_for is not None else None
        if guess is not None:
            params = guess.replace(tiles=cand.tiles)
            loss = objective.value(params, camera_blur_px)
        else:
            params = colour_matched(priors.typical(cand.pattern).replace(tiles=cand.tiles), objective, camera_blur_px)
            loss, params = best_gap(params, objective, camera_blur_px)
        starts.append(Start(loss, k, cand, params))
        on_start(k + 1, loss)
    return sorted(starts, key=lambda s: (s.loss, s.order))


def best_blur(params: FabricParams, objective: Objective, floor: float, also: float | None = None) -> float:
    """The camera blur among ``floor``, the BLUR_SCAN values above it (and ``also``) with the lowest loss."""
    scan = (floor,) + tuple(b for b in BLUR_SCAN if b > floor)
    scan += (also,) if also is not None and also not in scan else ()
    losses = [objective.value(params, blur) for blur in scan]
    return scan[int(np.argmin(losses))]


def camera_blur(settings: FitSettings, reflection: np.ndarray, transmission: np.ndarray, film_size: int,
                best_start: FabricParams, objective: Objective) -> tuple[float, float | None]:
    """(camera blur to fit with, its lower bound while fitting, or None when it stays fixed).

    The blur is the loss's choice at the best starting parameters; the runs move it from there, by
    gradient with the continuous parameters and by the discrete searches' parabolic steps
    (:class:`backend.fit.optimise.Run`). Where the start is far
    from the photos, that choice can be a valley the fit stays in: photo-like seed 53's twill0_001
    (the phone's blur 1.04 px, the photos' reading 0.82) starts at 1.5 px and ends at 1.31 with loss
    1.19 and roughness MAE .175; the same fit started at 1.04 ends at 0.99 with loss 0.83 and MAE
    .052, and started at the reading, 0.82, with loss 0.77 and MAE .071. Yet starting every fit at the
    reading is worse on the dev real pairs: satin1 FLIP R / T .150 / .139 -> .193 / .234, colour L1 T
    .015 -> .051 (final loss 3.37 -> 3.66), twill1 spectrum T .678 -> .635 (2.91 -> 2.98). A re-scan at
    the run's parameters after 25 steps keeps twill0_001's 1.31 px: by then they have followed it.
    Hence a short duel of both starts at the working size (:func:`backend.fit.pipeline._finalist`)."""
    if settings.camera_blur is not None:
        return settings.camera_blur, None
    photo_blur = photo_blur_px(reflection, transmission, film_size)
    if photo_blur < SOFT_PHOTO_PX:
        return 0.0, None  # as sharp as a render: a blur would only hide model error
    floor = min(photo_blur, MAX_CAMERA_BLUR_PX)
    return best_blur(best_start, objective, floor), floor


def reranked(starts: list[Start], objective: Objective, camera_blur_px: float) -> list[Start]:
    """The starts ranked again by their loss at another camera blur."""
    rescored = [Start(objective.value(s.params, camera_blur_px), s.order, s.candidate, s.params) for s in starts]
    return sorted(rescored, key=lambda s: (s.loss, s.order))


def spectrum_similarity(params: FabricParams, objective: Objective, camera_blur_px: float) -> float:
    """Mean over R and T of the log-power-spectrum correlation between a render and the photo."""
    with torch.no_grad():
        pair = objective.renderer.render(params, camera_blur_px=camera_blur_px)
    target = objective.target
    return 0.5 * sum(spectrum_corr(photo.cpu().numpy(), render.cpu().numpy())
                     for photo, render in ((target.reflection, pair.reflection),
                                           (target.transmission, pair.transmission)))


def trial_runs(starts: list[Start], objective: Objective, settings: FitSettings, camera_blur_px: float,
               blur_floor: float | None, rated: dict[int, float], check_stop: Callable[[Run], None],
               on_trial: Callable[[int, int, float], None],
               coverage_of: Callable[[Candidate], float], restarted: bool = False) -> list[Trial]:
    """A short fit for each of the best ``settings.trials`` starts (none when only one is left);
    ``coverage_of(candidate)`` is its lattice's peak coverage (:func:`chosen`).

    The runs' learning-rate schedules span the trial and the final iterations: at a working size of
    BASE_SIZE or below the winner goes on (above it, ``restarted``, the fit starts the winner again
    at the working size from ``Trial.start``).

    A start whose lattice's coverage :func:`chosen` would rule out (below the best start's by more
    than COVERAGE_MARGIN) gets no steps: the coverage does not depend on them, so the winner and the
    eligible trials are those of a search that ran it (its summary keeps the start's loss, with
    ``"skipped"`` saying why). Where that leaves one eligible start and the winner restarts, it gets
    none either (a trial only chooses); at BASE_SIZE the lone trial still runs, as its steps go on
    in the fit. Measured on the dev real twill2: twill1 and twill1m on a lattice three times too
    fine (coverage 0.13) beside twill0 (0.93): 60 trial steps at 256 px spared, the same parameters,
    the fit 159 -> 142 s (one session, 2 cores).

    Where the winner restarts and the eligible starts are a weave and its face twin on one lattice
    (:func:`_face_twins`), none gets steps either: the trials at BASE_SIZE cannot tell the two apart
    (:func:`rival`), and the fit's duel at the working size chooses between them from their starts,
    whatever the trials did (``backend.fit.pipeline._finalist``); the trials only chose which of the
    two the twin must beat by ``duel_margin``, now the one with the lower starting loss. Measured
    (``bench fit``, the same session): on the dev real twill1, the five dev golden twills and seven
    of the eight twills of photo-like seed 53 (twill1_012 has one eligible start) the search at 256
    px spared 40 steps, and every fit came out bit-identical (the duels' losses,
    ``fine_trial_loss``, make the same finalist go on either way). The search stage less its
    lattice part, one fit alone on 2 cores: real twill1 37.6 -> 18.0 s and 26.1 -> 17.8 s (two
    runs), photo-like twill0m_006 32.6 -> 20.4 s (whole fits 100 -> 79 s, 91.5 -> 91.6 s with an
    optimisation 6 s slower, 117 -> 111 s: the machine is noisy); two benches side by side, 59-66 s
    -> 30-51 s on six of the seven.
    """
    shortlisted = starts[: max(1, settings.trials)]
    coverages = [coverage_of(start.candidate) for start in shortlisted]
    eligible = _within_coverage_margin(coverages)
    twins = restarted and _face_twins([start.candidate for start, keep in zip(shortlisted, eligible) if keep])
    compare = not twins and (sum(eligible) > 1 or (len(shortlisted) > 1 and not restarted))
    total = settings.iterations + settings.trial_iterations
    trials = []
    for index, (start, coverage, kept) in enumerate(zip(shortlisted, coverages, eligible)):
        run = Run(start.params, objective, settings, total, camera_blur_px, blur_floor)
        tried = compare and kept
        for _ in range(settings.trial_iterations if tried else 0):
            run.step()
            check_stop(run)
        trial_loss = run.best_loss if run.history else start.loss
        similarity = spectrum_similarity(run.best, objective, camera_blur_px) if tried else None
        selection = trial_loss + (0.0 if similarity is None else settings.spectrum_weight * (1.0 - similarity))
        on_trial(index + 1, len(shortlisted), selection)
        cand = start.candidate
        summary = {"pattern": cand.pattern, "tiles": list(cand.tiles), "lattice_score": cand.score,
                   "start_loss": start.loss, "trial_loss": trial_loss, "spectrum_corr": similarity,
                   "peak_coverage": coverage, "selection": selection, "probability": rated.get(id(cand))}
        if not kept:
            summary["skipped"] = "its lattice makes far less of the photos' peaks than the best start's"
        elif twins:
            summary["skipped"] = "a weave and its face twin: the duel at the working size chooses"
        trials.append(Trial(start, run, summary, selection, coverage))
    return trials


def _face_twins(candidates: list[Candidate]) -> bool:
    """Whether ``candidates`` are two: a weave and its face twin (:func:`face_twin`) on one lattice."""
    if len(candidates) != 2:
        return False
    first, second = candidates
    return face_twin(first) == second.pattern and same_lattice(first.tiles, second.tiles)


def chosen(trials: list[Trial]) -> Trial:
    """The trial with the lowest selection among the eligible ones: those whose lattice's peak
    coverage is within COVERAGE_MARGIN of the best trial's. (Replayed searches of the 20 photo-like
    pairs of seed 7 and the 11 dev goldens, coverage at the true placement: each trial on a wrong
    lattice was 0.58 or more below the best, and no winner changes; real twill2: twill1 on a lattice
    three times too fine down the image, 0.13, now loses to twill0 on the photos' own, 0.93.)"""
    return min(_eligible(trials), key=lambda t: (t.selection, trials.index(t)))


def _eligible(trials: list[Trial]) -> list[Trial]:
    return [t for t, kept in zip(trials, _within_coverage_margin([t.coverage for t in trials])) if kept]


def _within_coverage_margin(coverages: list[float]) -> list[bool]:
    """Per coverage, whether it is at most COVERAGE_MARGIN below the best of them."""
    best = max(coverages)
    return [c >= best - COVERAGE_MARGIN for c in coverages]


def rival(trials: list[Trial], winner: Trial) -> Trial | None:
    """The eligible trial of the winner's face twin on the winner's lattice
    (:func:`backend.core.weave.face_twin`: the same diagonal, the floats of the other yarn), or None.

    A weave and its face twin differ in which yarn floats, a detail of a pixel or two at BASE_SIZE on
    a dense weave: there the trials cannot tell them apart, and the working size decides between the
    two (the fit's coarse to fine). Measured (photo-like seed 53, twill0m_016, 42.8 x 27.7 tiles):
    the trials at 256 px ranked its face twin twill1 first (selection 2.18 against 2.24); whole fits
    at 512 px end at 1.91 for twill1 and 1.66 for twill0m."""
    return next((t for t in _eligible(trials) if _face_twins([winner.start.candidate, t.start.candidate])), None)


def untried_rival(ruled_out: list[dict], winner: Candidate) -> Candidate | None:
    """Where no trial is :func:`rival`'s: the winner's face twin on its lattice among the candidates
    the network ruled out (``ruled_out``: :func:`rated_candidates`' summaries), or None. The network
    reads a dense weave at the same 256 px as the trials: on photo-like seed 53 twill1_012 (44.9 x
    72.1 tiles) it kept the face twin twill0m alone (0.987) and gave the true twill1 0.013; whole fits
    at 512 px end at 1.80 for twill0m and 1.42 for twill1."""
    twin = face_twin(winner)
    found = next((c for c in ruled_out if c["pattern"] == twin and same_lattice(c["tiles"], winner.tiles)), None)
    return None if found is None else Candidate(found["pattern"], tuple(found["tiles"]), found["lattice_score"])


def face_twin(candidate: Candidate) -> str | None:
    """The face twin of the candidate's preset (None for a custom weave)."""
    return weave.face_twin(weave.PRESETS[candidate.pattern]) if candidate.pattern in weave.PRESETS else None
