"""The search stage's decisions: which weave, at what density, from where, with how much camera blur.

Values in, values out: the pipeline (:mod:`backend.fit.pipeline`) evaluates the objective and runs
the trials, and hands the numbers to these functions, which never call back.

1. Candidates: one (pattern, tiles) per preset from the photos' spectra
   (:func:`backend.texture.candidates.propose`); an initialisation network may rate them, each
   pattern on every lattice proposed in its family (:func:`family_lattices`), and those it gives
   less than ``min_pattern_probability`` are dropped (:func:`rated_candidates`), unless they are of
   a family it keeps and their lattice makes far more of the photos' peaks than every kept
   candidate's.
2. Starting points: the network's guess for a candidate, or the pattern's typical parameters with
   the albedos scaled to the photos' mean colour (:func:`colour_matched`) and the best of a few gap
   scales (:func:`gap_variants`, :func:`lowest`); ranked by loss (:func:`ranked`).
3. Camera blur: fixed when given; none for photos whose noise is as white as a render's
   (:mod:`backend.image.camera_blur`); otherwise the best of a scan (:func:`blur_scan`,
   :func:`best_blur`) within :func:`blur_range`: never below the blur the photos' noise shows, and
   where asked, at most BLUR_ALLOWANCE_PX above it; the range also bounds the optimiser.
4. Trials: the best ``trials`` starts get a short fit each (:func:`trial_plan`); the pattern is the
   one whose trial ends lowest in

       selection = trial loss + spectrum_weight * (1 - spectrum correlation of render and photo)

   (:func:`trial`): the loss reads harmonics at each candidate's own lattice, so a lattice twice too
   coarse would not be charged for the photo's odd harmonics; the spectrum sees every peak. Only
   trials whose lattice makes nearly as much of the photos' peak strength as the best trial's are
   eligible (:func:`chosen`): a lattice too fine on one axis compares fewer, easier harmonics, and
   its trial can end lowest while the photos' strongest peak is none of its harmonics. A weave
   shortlisted on two lattices within NEAR_LATTICE of each other (the proposals of one photo peak)
   has one trial, on the lattice of the lower starting loss (:func:`trial_plan`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..core import priors, weave
from ..core.params import PARAMETERS, FabricParams
from ..core.rig import MAX_CAMERA_BLUR_PX, CaptureRig
from ..image.camera_blur import SOFT_PHOTO_PX, photo_blur_px
from ..texture.candidates import Candidate, tile_range
from ..texture.frequencies import yarns_in_view
from .settings import FitSettings

if TYPE_CHECKING:
    from .optimise import Run

GAP_SCAN = (0.75, 0.85, 0.9, 0.95, 1.0)
BASE_SIZE, BASE_SPP = 256, 16
BASE_ITERATIONS, FINE_ITERATIONS = 150, 100
MIN_PIXELS_PER_YARN = 2.5
BLUR_SCAN = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0)  # film pixels
# film px a fitted camera blur may lie above the photos' reading under a ceiling (FitSettings.blur_ceiling):
# the reading's under-reads of a phone's blur (up to 0.83 px on photo-like pairs), little room beyond
BLUR_ALLOWANCE_PX = 1.0
COVERAGE_MARGIN = 0.3  # eligible: a peak coverage at most this far below the best trial's (chosen)
LATTICE_MATCH = 0.01  # two candidates' tiles within 1 % on both axes are one lattice
# one weave on two lattices this close (relative, both axes) has one trial, the better start's, and a weave
# and its face twin this close none (trial_plan): the trial steps never move the lattice, and at this
# distance the starting loss ranks the lattices as the trials do
NEAR_LATTICE = 0.03

# Why a shortlisted start gets no trial steps (its summary's "skipped"; trial_plan)
FEW_PEAKS = "its lattice makes far less of the photos' peaks than the best start's"
FACE_TWINS = "a weave and its face twin: the duel at the working size chooses"
NEARBY = "the same weave on a nearby lattice starts lower: its trial stands for both"


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

    @property
    def nearby(self) -> bool:
        """Whether its weave's trial on a nearby lattice stands for it (NEARBY): it cannot win."""
        return self.summary.get("skipped") == NEARBY


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


def family_lattices(found: list[Candidate], rig: CaptureRig) -> list[Candidate]:
    """``found`` with each pattern also on every lattice proposed for another pattern of its family
    (plain, twill, satin) that its tile range allows (:func:`backend.texture.candidates.tile_range`),
    once per lattice: each pattern's own candidate, then the others in the order of ``found``.

    The lattice of a preset comes from the harmonics its typical render shows, and face twins can be
    proposed on different lattices; the network, shown every pattern on every lattice of its family,
    rates each where the photos put it."""
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


def same_lattice(tiles, other, tolerance: float = LATTICE_MATCH) -> bool:
    return all(abs(t - o) <= tolerance * max(t, o) for t, o in zip(tiles, other))


def rated_candidates(shared: list[Candidate], probabilities: list[float], coverages: list[float], threshold: float
                     ) -> tuple[list[Candidate], dict[int, float], list[dict]]:
    """(kept candidates, probability by id(candidate), summaries of those ruled out) of the
    candidates on their family's lattices (:func:`family_lattices`), given the network's
    probability and the lattice's peak coverage (:func:`backend.texture.lattice.peak_coverage`) of
    each.

    The network rules out the candidates it gives less than ``threshold``
    (:func:`_kept_by_network`), but not one of a weave family it keeps whose lattice makes more than
    COVERAGE_MARGIN more of the photos' peak strength than every kept candidate
    (:func:`_kept_by_peaks`): :func:`chosen` would rule all the kept ones out once trialled beside
    it. Its family stands: the coverage is one-sided (a lattice too coarse explains every peak), so
    it cannot bring in another family."""
    network = _kept_by_network(shared, probabilities, threshold)
    kept = [k or p for k, p in zip(network, _kept_by_peaks(shared, coverages, network))]
    ruled_out = [{"pattern": c.pattern, "tiles": list(c.tiles), "lattice_score": c.score,
                  "peak_coverage": coverage, "probability": probability}
                 for c, coverage, probability, keep in zip(shared, coverages, probabilities, kept) if not keep]
    rated = {id(c): p for c, p in zip(shared, probabilities)}
    return [c for c, keep in zip(shared, kept) if keep], rated, ruled_out


def _kept_by_network(candidates: list[Candidate], probabilities: list[float], threshold: float) -> list[bool]:
    """Per candidate, whether the network gives it ``threshold`` or more (the most probable one
    where it gives none that much)."""
    kept = [p >= threshold for p in probabilities]
    if not any(kept):
        kept[int(np.argmax(probabilities))] = True
    return kept


def _kept_by_peaks(candidates: list[Candidate], coverages: list[float], kept: list[bool]) -> list[bool]:
    """Per candidate, whether it is of a family among the ``kept`` ones and its lattice's peak
    coverage is more than COVERAGE_MARGIN above every kept candidate's."""
    families = {priors.family(c.pattern) for c, keep in zip(candidates, kept) if keep}
    bar = max(coverage for coverage, keep in zip(coverages, kept) if keep) + COVERAGE_MARGIN
    return [priors.family(c.pattern) in families and coverage > bar for c, coverage in zip(candidates, coverages)]


def typical_start(candidate: Candidate) -> FabricParams:
    """The candidate's pattern's typical parameters on its tiles: the start where the network gives none."""
    return priors.typical(candidate.pattern).replace(tiles=candidate.tiles)


def colour_matched(params: FabricParams, ratios: tuple[list[float], list[float]]) -> FabricParams:
    """``params`` with the albedos scaled per channel by the photos' mean linear colour over the
    render's (``ratios``, R and T: :meth:`backend.fit.objective.Objective.colour_ratios`), within [0, 1]."""
    r_ratio, t_ratio = ratios

    def scaled(rgb, factors):
        return tuple(min(1.0, max(0.0, c * f)) for c, f in zip(rgb, factors))

    return FabricParams.clamped_from(
        pattern=params.pattern, weave=params.weave,
        **{**{s.name: getattr(params, s.name) for s in PARAMETERS},
           "diffuse_reflection": scaled(params.diffuse_reflection, r_ratio),
           "specular_albedo": tuple(scaled(yarn, r_ratio) for yarn in params.specular_albedo),
           "diffuse_transmission": scaled(params.diffuse_transmission, t_ratio)})


def gap_variants(params: FabricParams) -> list[FabricParams]:
    """``params`` at its own gap scale, then at each of GAP_SCAN (the same for warp and weft): the
    starting gap is scanned, as gaps change the transmission image more than anything."""
    return [params.replace(gap_scale=gap) for gap in (params.gap_scale,) + tuple((g, g) for g in GAP_SCAN)]


def lowest(losses: list[float], params: list[FabricParams]) -> tuple[float, FabricParams]:
    """(loss, parameters) of the lowest loss; the first of equal ones."""
    best = min(range(len(losses)), key=losses.__getitem__)
    return losses[best], params[best]


def ranked(starts: list[Start]) -> list[Start]:
    """The starts, lowest loss first (ties in the proposal's order)."""
    return sorted(starts, key=lambda s: (s.loss, s.order))


def reranked(starts: list[Start], losses: list[float]) -> list[Start]:
    """The starts ranked again by their ``losses`` at another camera blur."""
    return ranked([Start(loss, s.order, s.candidate, s.params) for s, loss in zip(starts, losses, strict=True)])


@dataclass(frozen=True)
class BlurRange:
    """The camera blurs (film pixels) a fit may estimate: from ``floor`` to ``ceiling``."""

    floor: float
    ceiling: float

    def clamped(self, blur: float) -> float:
        return min(self.ceiling, max(self.floor, blur))


def blur_range(settings: FitSettings, reflection: np.ndarray, transmission: np.ndarray, film_size: int
               ) -> BlurRange | None:
    """The camera blurs the fit may estimate: from the blur the photos' noise shows (at most
    MAX_CAMERA_BLUR_PX) up to MAX_CAMERA_BLUR_PX, or with ``settings.blur_ceiling`` to BLUR_ALLOWANCE_PX
    above it; None where the blur stays fixed (:func:`fixed_blur`).

    The fit starts from the loss's choice at the best starting parameters (:func:`best_blur`), and
    the runs move it from there, by gradient and by the discrete searches' parabolic steps
    (:class:`backend.fit.optimise.Run`), at the working size from the loss's choice there
    (:func:`backend.fit.pipeline._fine_run`).

    Why a ceiling: a pixel loss falls wherever a softer render hides what the model cannot match
    (a yarn texture, speckle, a random yarn pattern), so without one a fit can blur a sharp photo's
    texture away; the photos' reading says how soft the camera is, and the fit's blur may add to it
    only what the reading can miss. Why not by default: the other parameters then make up for what
    the blur hid, and on a real satin the transmission's colour went far off (the benchmark's
    results)."""
    if settings.camera_blur is not None:
        return None
    photo_blur = photo_blur_px(reflection, transmission, film_size)
    if photo_blur < SOFT_PHOTO_PX:
        return None  # as sharp as a render: a blur would only hide model error
    floor = min(photo_blur, MAX_CAMERA_BLUR_PX)
    return BlurRange(floor, min(floor + BLUR_ALLOWANCE_PX, MAX_CAMERA_BLUR_PX) if settings.blur_ceiling
                     else MAX_CAMERA_BLUR_PX)


def fixed_blur(settings: FitSettings) -> float:
    """The camera blur of a fit that does not estimate it: the one given, else none (sharp photos)."""
    return 0.0 if settings.camera_blur is None else settings.camera_blur


def blur_scan(allowed: BlurRange, also: float | None = None) -> tuple[float, ...]:
    """The camera blurs to compare: the floor, the BLUR_SCAN values above it within the range, the
    ceiling where the range cuts some off (and ``also``)."""
    scan = (allowed.floor,) + tuple(b for b in BLUR_SCAN if allowed.floor < b <= allowed.ceiling)
    if any(b > allowed.ceiling for b in BLUR_SCAN) and allowed.ceiling not in scan:
        scan += (allowed.ceiling,)
    return scan + ((also,) if also is not None and also not in scan else ())


def best_blur(scan: tuple[float, ...], losses: list[float]) -> float:
    """The blur of :func:`blur_scan` with the lowest loss (the first of equal ones)."""
    return scan[int(np.argmin(losses))]


def shortlisted(starts: list[Start], trials: int) -> list[Start]:
    """The best ``trials`` starts (at least one): those given a trial."""
    return starts[: max(1, trials)]


def trial_plan(candidates: list[Candidate], coverages: list[float], restarted: bool
               ) -> list[tuple[bool, str | None]]:
    """Per shortlisted candidate, in the shortlist's order (lowest starting loss first), with its
    lattice's peak coverage: (whether its trial takes steps, why not where the summary says so:
    FEW_PEAKS, NEARBY, FACE_TWINS or None).

    A trial chooses; its steps also go on in the fit at BASE_SIZE, while above it (``restarted``)
    the winner starts again at the working size. A candidate that :func:`chosen` would rule out
    gets no steps: the coverage does not depend on them, so the winner is that of a search that ran
    it. Nor does one whose weave an eligible candidate before it has on a lattice within
    NEAR_LATTICE (:func:`_nearby`): that trial stands for both, and it cannot win. Where that
    leaves one eligible candidate and the winner restarts, it gets none either. Where the winner
    restarts and the eligible ones are a weave and its face twin on one lattice or two within
    NEAR_LATTICE (:func:`_face_twins`), neither gets steps: the trials at BASE_SIZE cannot tell them
    apart (:func:`rival`), the duel at the working size chooses (its twin is the one on the
    winner's own lattice), and the one with the lower starting loss is the one the twin must beat."""
    covered = _within_coverage_margin(coverages)
    nearby = _nearby(candidates, covered)
    eligible = [kept and not near for kept, near in zip(covered, nearby)]
    twins = restarted and _face_twins([c for c, kept in zip(candidates, eligible) if kept], NEAR_LATTICE)
    compare = not twins and (sum(eligible) > 1 or (len(candidates) > 1 and not restarted))
    return [(compare and kept, FEW_PEAKS if not cover else NEARBY if near else FACE_TWINS if twins else None)
            for kept, cover, near in zip(eligible, covered, nearby)]


def _nearby(candidates: list[Candidate], eligible: list[bool]) -> list[bool]:
    """Per candidate, whether an eligible candidate before it, not itself nearby, is of its weave on a
    lattice within NEAR_LATTICE of its own."""
    nearby: list[bool] = []
    for k, cand in enumerate(candidates):
        nearby.append(any(eligible[j] and not nearby[j] and other.pattern == cand.pattern
                          and same_lattice(other.tiles, cand.tiles, NEAR_LATTICE)
                          for j, other in enumerate(candidates[:k])))
    return nearby


def trial(start: Start, run: Run, coverage: float, similarity: float | None, probability: float | None,
          skipped: str | None, spectrum_weight: float) -> Trial:
    """The trial of ``start`` after its ``run``'s steps (its start's loss where it took none), with
    its selection (module docstring; the loss alone where no spectrum ``similarity`` was read) and
    the summary params.json records."""
    trial_loss = run.best_loss if run.history else start.loss
    selection = trial_loss + (0.0 if similarity is None else spectrum_weight * (1.0 - similarity))
    cand = start.candidate
    summary = {"pattern": cand.pattern, "tiles": list(cand.tiles), "lattice_score": cand.score,
               "start_loss": start.loss, "trial_loss": trial_loss, "spectrum_corr": similarity,
               "peak_coverage": coverage, "selection": selection, "probability": probability}
    if skipped is not None:
        summary["skipped"] = skipped
    return Trial(start, run, summary, selection, coverage)


def _face_twins(candidates: list[Candidate], tolerance: float = LATTICE_MATCH) -> bool:
    """Whether ``candidates`` are two: a weave and its face twin (:func:`face_twin`) on one lattice
    (tiles within ``tolerance``)."""
    if len(candidates) != 2:
        return False
    first, second = candidates
    return face_twin(first) == second.pattern and same_lattice(first.tiles, second.tiles, tolerance)


def chosen(trials: list[Trial]) -> Trial:
    """The trial with the lowest selection among the eligible ones: those whose lattice's peak
    coverage is within COVERAGE_MARGIN of the best trial's (a trial on a wrong lattice makes far
    less of the photos' peaks), and that no trial of their weave on a nearby lattice stands for
    (``Trial.nearby``)."""
    return min((t for t in _eligible(trials) if not t.nearby), key=lambda t: (t.selection, trials.index(t)))


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
    two (the fit's coarse to fine)."""
    return next((t for t in _eligible(trials) if _face_twins([winner.start.candidate, t.start.candidate])), None)


def duelled(losses: list[float], margin: float) -> int:
    """Which run of a duel goes on, given each one's best loss after the duel's steps (the winner's
    first): the lowest, where it is lower than the winner's by more than ``margin``, else the winner."""
    lowest = min(range(len(losses)), key=lambda k: (losses[k], k))
    return lowest if losses[lowest] < losses[0] - margin else 0


def untried_rival(ruled_out: list[dict], winner: Candidate) -> Candidate | None:
    """Where no trial is :func:`rival`'s: the winner's face twin on its lattice among the candidates
    the network ruled out (``ruled_out``: :func:`rated_candidates`' summaries), or None. The network
    reads a dense weave at the same BASE_SIZE as the trials, and can rule out the true weave beside
    its twin."""
    twin = face_twin(winner)
    found = next((c for c in ruled_out if c["pattern"] == twin and same_lattice(c["tiles"], winner.tiles)), None)
    return None if found is None else Candidate(found["pattern"], tuple(found["tiles"]), found["lattice_score"])


def face_twin(candidate: Candidate) -> str | None:
    """The face twin of the candidate's preset (None for a custom weave)."""
    return weave.face_twin(weave.PRESETS[candidate.pattern]) if candidate.pattern in weave.PRESETS else None
