"""A fit's progress over its whole run (backend/core/progress.py): its phases read from the protocol's
events, one bar, the time left. Times are given to it, so every check here is replayable."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.core import progress, protocol  # noqa: E402
from backend.core.progress import MIN_REMAINDER, PHASES, FitProgress, duration_words, replay  # noqa: E402

VARIATION_COUNTS = 17  # the variation stage's readings and settling steps (backend.fit.pipeline._with_variation)


def progress_event(stage: str, iteration: int, total: int) -> dict:
    return {"event": "progress", "stage": stage, "iteration": iteration, "total": total}


def counts(stage: str, start: float, end: float, total: int, first: int = 1) -> list:
    """Events ``first``..``total`` of a stage, evenly from ``start`` to ``end``."""
    steps = total - first
    return [(start + (end - start) * (k - first) / max(steps, 1), stage, k, total) for k in range(first, total + 1)]


def optimiser_work(first: int, stop: int = 100) -> list[float]:
    """The work of the optimiser's steps ``first``..``stop`` of 100, in steps: each discrete search
    (after the steps PHASES declares, not after the last) as long as SEARCH_COUNTS steps."""
    optimiser = next(p for p in PHASES if p.pauses)
    return [1 + optimiser.pause_counts * (k in optimiser.pauses and k < 100) for k in range(first, stop + 1)]


def optimiser_events(start: float, unit: float, first: int, stop: int = 100, best_at: int | None = None) -> list:
    """The optimiser's events from ``start``, its steps ``first``..``stop`` of 100 ``unit`` seconds
    each (:func:`optimiser_work`); stopping before 100, its last event says 100 of 100. With
    ``best_at``, each event says the steps since its best last moved (every step a new best up to
    that one), else nothing."""
    at, events = start, []
    for k, units in zip(range(first, stop + 1), optimiser_work(first, stop)):
        at += units * unit
        since = None if best_at is None else max(0, k - best_at)
        events.append((at, "optimise", 100 if k == stop else k, 100, None, since))
    return events


def fit_timeline(wall: float = 100.0, duel: bool = True, stop: int = 100, best_at: int | None = None) -> list:
    """A fit whose every phase lasts its share of ``wall``, its counts evenly spaced, in the fit's order of
    events: each stage's first event of iteration 0, the search's counter starting again for the
    starting points, the trials and the duel (each with the count its share is for), then the
    optimiser's steps (the duel's 10 first; :func:`optimiser_events`), the variation's readings. An
    optimiser that stops at step ``stop`` before its 100 keeps the pace of its share for 100: it ends
    sooner, and the fit."""
    shares = {phase.name: phase.share for phase in PHASES}
    if not duel:
        shares["optimise"] += shares.pop("duel")
    first = 11 if duel else 1
    unit = shares["optimise"] * wall / sum(optimiser_work(first))
    shares["optimise"] *= sum(optimiser_work(first, stop)) / sum(optimiser_work(first))
    ends, at = {}, 0.0
    for name in (p.name for p in PHASES if p.name in shares):
        at += shares[name] * wall
        ends[name] = at
    events = [(0.0, "load", 0, 1), (ends["load"], "load", 1, 1), (ends["load"], "search", 0, 1)]
    n = {phase.name: phase.counts for phase in PHASES}
    events += counts("search", ends["placement"], ends["starts"], n["starts"])
    events += counts("search", ends["starts"] + (ends["trials"] - ends["starts"]) / n["trials"], ends["trials"],
                     n["trials"])
    previous = ends["trials"]
    if duel:
        step = (ends["duel"] - ends["trials"]) / n["duel"]
        events += counts("search", ends["trials"] + step, ends["duel"], n["duel"])
        previous = ends["duel"]
    events += optimiser_events(previous, unit, first, stop, best_at)
    events += [(ends["optimise"], "variation", 0, VARIATION_COUNTS)]
    events += counts("variation", ends["optimise"] + (ends["variation"] - ends["optimise"]) / VARIATION_COUNTS,
                     ends["variation"], VARIATION_COUNTS)
    events += [(ends["variation"], "render", 0, 1)]
    events += counts("render", ends["variation"] + (ends["render"] - ends["variation"]) / 10, ends["render"], 10)
    events += [(ends["render"], "report", 0, 1), (ends["report"], "report", 1, 1)]
    return events


def follow(events: list, until: float | None = None) -> FitProgress:
    fit = FitProgress(started=0.0)
    for t, stage, iteration, total, *optional in events:
        if until is not None and t > until:
            break
        loss, since_best = (*optional, None, None)[:2]
        fit.update({**progress_event(stage, iteration, total), "loss": loss, "since_best": since_best}, t)
    return fit


def test_the_phases_follow_the_protocols_stages_and_share_the_whole_fit():
    order = [protocol.STAGES.index(phase.stage) for phase in PHASES]
    assert order == sorted(order)
    assert sum(phase.share for phase in PHASES) == pytest.approx(1.0, abs=1e-9)
    assert all(phase.share > 0 and phase.words for phase in PHASES)


def test_the_events_are_placed_in_the_phases_the_fit_runs():
    fit = FitProgress(started=0.0)
    seen = []
    for t, stage, iteration, total, *_ in fit_timeline():
        fit.update(progress_event(stage, iteration, total), t)
        if not seen or seen[-1] != fit.phase.name:
            seen.append(fit.phase.name)
    assert seen == [p.name for p in PHASES]
    assert not fit.skipped and not fit.finished
    fit.update({"event": "result"}, 100.0)
    assert fit.finished and fit.fraction(100.0) == 1.0 and fit.seconds_left(100.0) == 0.0
    assert sum(fit.durations.values()) == pytest.approx(100.0)


def test_the_starting_points_hand_over_to_the_trials_when_their_count_is_complete():
    """The first trial's work (and the camera-blur scan) comes before the first trial's event."""
    fit = follow([(0.0, "load", 0, 1), (1.0, "load", 1, 1), (1.0, "search", 0, 1), (10.0, "search", 1, 2),
                  (11.0, "search", 2, 2)])
    assert fit.phase.name == "trials" and fit.current.started == 11.0
    fit.update(progress_event("search", 1, 2), 20.0)   # the trials' own count goes on in the same phase
    assert fit.phase.name == "trials" and fit.describe(20.0).startswith("Comparing weaves, 1 of 2")
    fit.update(progress_event("search", 2, 2), 29.0)
    assert fit.phase.name == "duel"


def test_a_fit_at_the_search_size_passes_the_duel_by_and_gives_its_time_to_the_optimiser():
    events = fit_timeline(duel=False)
    fit = follow(events)
    assert fit.skipped == {"duel"} and "duel" not in fit.durations
    trials_done = [t for t, stage, *_ in events if stage == "search"][-1]
    optimised = next(t for t, stage, iteration, *_ in events if (stage, iteration) == ("optimise", 100))
    assert fit.durations["optimise"] == pytest.approx(optimised - trials_done)


def test_the_time_left_is_the_truth_where_the_fit_keeps_its_shares():
    """A fit that runs every phase at its share of the wall time, at one pace: the estimate is the
    truth from the end of the first phase on, whatever that pace (a busy machine, a fast one), but
    in the last MIN_REMAINDER of a phase without a count (a few percent of what is left)."""
    for wall in (60.0, 1000.0):
        result = replay(fit_timeline(wall), wall, from_fraction=0.0)
        assert abs(result.worst_eta_error) < 0.03 and abs(result.worst_bar_error) < 0.02, (wall, result)
        assert result.shares == pytest.approx({p.name: p.share for p in PHASES})


def test_the_bar_moves_through_a_phase_that_counts_nothing():
    start, length = PHASES[0].share * 100.0, PHASES[1].share * 100.0   # the placement, in fit_timeline's 100 s
    early, middle, late = (start + part * length for part in (0.25, 0.5, 0.75))
    fit = follow(fit_timeline(), until=middle)
    assert fit.phase.name == "placement"
    assert fit.fraction(early) < fit.fraction(middle) < fit.fraction(late)
    assert fit.seconds_left(early) > fit.seconds_left(middle)


def test_a_phase_past_its_expected_length_keeps_a_part_of_it_to_go():
    """MIN_REMAINDER: a phase without a count that runs three times as long as expected still has a
    tenth of its expected length to go: the bar keeps moving, ever slower, short of the phase's end."""
    fit = follow(fit_timeline(), until=5.0)
    placement = next(p for p in PHASES if p.name == "placement")
    pace = fit.durations["load"] / PHASES[0].share
    expected = pace * placement.share
    now = fit.current.started + 3 * expected
    to_come = sum(p.share for p in PHASES[2:])
    assert fit.seconds_left(now) == pytest.approx(MIN_REMAINDER * expected + pace * to_come)
    end_of_phase = sum(p.share for p in PHASES[:2])
    assert fit.fraction(now) < fit.fraction(now + 10.0) < fit.fraction(now + 20.0) < end_of_phase


def test_no_estimate_before_a_phase_has_ended():
    fit = follow([(0.0, "load", 0, 1)])
    assert fit.seconds_left(5.0) is None and fit.fraction(5.0) == 0.0
    assert fit.describe(5.0) == "Reading the photos"
    assert FitProgress(started=0.0).describe(1.0) == "Starting the fit"


def test_the_words_of_the_bar():
    shares = {p.name: p.share for p in PHASES}
    trials = 100.0 * (shares["load"] + shares["placement"] + shares["starts"] + shares["trials"] * 0.75)
    fit = follow(fit_timeline(), until=trials)
    assert fit.describe(trials).startswith("Comparing weaves, 1 of 2, about ")
    assert [duration_words(s) for s in (3, 41, 89, 95, 3600 + 5 * 60 + 10)] == \
        ["5 s", "40 s", "90 s", "2 min", "1 h 05 min"]


def test_the_addon_reads_this_module_without_torch():
    from blender_addon.core import declarations

    assert Path(declarations.fit_progress().__file__).resolve() == Path(progress.__file__).resolve()


def test_trials_with_nothing_to_compare_leave_the_shares():
    """PASSED_BY_BELOW: trials whose counts come at once (a lone start, a weave and its face twin)
    did no work of their own: their share leaves the bar and the time left, their moments go to the duel."""
    events = [(0.0, "load", 0, 1), (1.0, "load", 1, 1), (1.0, "search", 0, 1), (10.0, "search", 1, 2),
              (11.0, "search", 2, 2), (11.2, "search", 1, 2), (11.2, "search", 2, 2)]
    fit = follow(events)
    assert fit.skipped == {"trials"} and fit.phase.name == "duel" and fit.current.started == 11.0
    shares = {p.name: p.share for p in PHASES}
    run = sum(shares.values()) - shares["trials"]
    done = shares["load"] + shares["placement"] + shares["starts"]
    assert fit.fraction(11.2) == pytest.approx(done / run, rel=0.05)


def test_the_re_renders_follow_the_photos_pace_and_the_optimiser_the_searchs():
    """Two paces: a search twice as slow as its shares say (a denser weave, a larger working size)
    makes the time left of the optimiser and of the variation (its readings and steps at the
    working size) twice as long, not the re-renders'."""
    shares = {p.name: p.share for p in PHASES}
    pace = 100.0  # seconds per share for the photos' phases; twice that for the search's
    t_load, t_place = shares["load"] * pace, (shares["load"] + shares["placement"]) * pace
    t_starts = t_place + 2 * pace * shares["starts"]
    t_trials = t_starts + 2 * pace * shares["trials"]
    events = [(0.0, "load", 0, 1), (t_load, "load", 1, 1), (t_load, "search", 0, 1), (t_place, "search", 1, 2),
              (t_starts, "search", 2, 2), ((t_starts + t_trials) / 2, "search", 1, 2), (t_trials, "search", 2, 2)]
    fit = follow(events)
    assert fit.phase.name == "duel"
    expected = (2 * pace * (shares["duel"] + shares["optimise"] + shares["variation"])
                + pace * (shares["render"] + shares["report"]))
    assert fit.seconds_left(t_trials) == pytest.approx(expected)


OPTIMISER = next(p for p in PHASES if p.name == "optimise")


def optimiser_after(since: list[int | None], losses: list[float] | None = None, patience: int | None = None):
    """A fit whose optimiser has had steps 1..len(since), one a second, each saying ``since`` (the
    steps since its best last moved; None: it does not say) and its ``losses`` where given."""
    fit = follow([(0.0, "load", 0, 1), (1.0, "load", 1, 1), (1.0, "search", 0, 1), (10.0, "search", 1, 1),
                  (20.0, "search", 1, 1)])
    for step, held in enumerate(since, start=1):
        event = {**progress_event("optimise", step, 100), "since_best": held, "patience": patience,
                 "loss": losses[step - 1] if losses else None}
        fit.update(event, 20.0 + step)
    return fit


def test_an_optimiser_whose_best_has_held_is_expected_to_stop_when_its_patience_runs_out():
    """The optimiser ends once its best loss has held for its patience P (after its first discrete
    search): after s steps without a new best, the chance of P - s more is (s + 1) / (P + 1), and the
    work left is to that stop where it is the likelier end, else to its total (each discrete search
    to come counted as SEARCH_COUNTS steps)."""
    patience, pause = OPTIMISER.patience, OPTIMISER.pause_counts
    whole = (100 - 30) + pause * 2   # from step 30: the searches after steps 50 and 75

    def held_for(s: int) -> list[int]:
        """30 steps whose best held for the last ``s``."""
        return [0] * (30 - s) + list(range(1, s + 1))

    likelier = next(s for s in range(patience) if progress.held_to_patience(s, patience) >= progress.LIKELIER)
    assert likelier == math.ceil((patience - 1) / 2)   # from s = (P - 1) / 2 on
    assert optimiser_after(held_for(0)).work_left() == optimiser_after(held_for(likelier - 1)).work_left() == whole
    assert optimiser_after(held_for(likelier)).work_left() == pytest.approx(patience - likelier)   # before step 50
    assert optimiser_after(held_for(patience - 1)).work_left() == pytest.approx(1)   # it ends with the next step
    # a new best after a long hold: it may run on again
    assert optimiser_after(held_for(patience - 1)[:-1] + [0]).work_left() == pytest.approx(whole)
    # its best held for its patience before the first search: it ends with that search, not before
    assert optimiser_after(list(range(12)) + [patience]).work_left() == pytest.approx((25 - 13) + pause)
    # a fit that says its patience is 0 runs every step; one that does not say reads its best from its losses
    assert optimiser_after(held_for(patience - 1), patience=0).work_left() == pytest.approx(whole)
    losses = [1.0 / k for k in range(1, 18)] + [1.0] * 13   # its best at step 17, held for 13
    assert optimiser_after([None] * 30, losses).work_left() == pytest.approx(optimiser_after(held_for(13)).work_left())


def test_the_optimisers_patience_and_searches_are_the_fits():
    from backend.fit.settings import FitSettings

    settings = FitSettings()
    searches = tuple(settings.first_search + k * settings.search_every for k in range(settings.max_searches))
    assert (OPTIMISER.patience, OPTIMISER.ends_from, OPTIMISER.pauses) == \
        (settings.patience, settings.first_search, searches)


def test_an_early_stop_brings_the_time_left_close_and_never_below_zero():
    """A fit whose optimiser stops at step 45 (its best at step 25, held for its patience; its steps at
    the pace of its share for 100): once its best has held for half its patience the time left is
    within ETA_CHECK of the truth (before, the fit is expected to run on), closer over the whole fit
    than where it does not say how long its best has held; never below zero; the bar never goes back."""
    events = fit_timeline(200.0, stop=45, best_at=25)
    wall = events[-1][0]
    said = replay(events, wall)
    unsaid = replay([event[:4] for event in events], wall)
    assert said.within > unsaid.within, (said, unsaid)
    fit = FitProgress(started=0.0)
    pending, bar = list(events), 0.0
    for now in [t / 4 for t in range(int(wall * 4))]:
        while pending and pending[0][0] <= now:
            t, stage, iteration, total, *optional = pending.pop(0)
            loss, since = (*optional, None, None)[:2]
            fit.update({**progress_event(stage, iteration, total), "loss": loss, "since_best": since}, t)
        left = fit.seconds_left(now)
        assert left is None or left >= 0.0
        assert fit.fraction(now) >= bar - 1e-9, now
        bar = fit.fraction(now)
        settled = fit.phase is OPTIMISER and (fit.current.since_best or 0) >= OPTIMISER.patience / 2
        if settled or fit.phase is not None and fit.phase.fixed and fit.phase.name != "load" and now > wall / 2:
            assert abs(left - (wall - now)) <= progress.ETA_CHECK * (wall - now), now


def test_a_stage_that_says_its_end_twice_leaves_the_next_phase_alone():
    """A late event of a stage the fit has left (here the optimiser's end, said again while the
    re-renders count, in a fit without the variation stage) is passed by: read as the re-renders'
    count it would end them at once, and the bar would say "Writing the report" through them."""
    events = [e for e in fit_timeline() if e[1] != "variation"]
    end = next(k for k, e in enumerate(events) if e[1] == "optimise" and e[2] == e[3])
    first_render = next(k for k, e in enumerate(events) if e[1] == "render" and e[2] == 1)
    events.insert(first_render + 1, (events[first_render][0], *events[end][1:]))
    fit = follow(events, until=events[first_render + 2][0])
    assert fit.phase.name == "render" and fit.current.last[1] >= 1
    fit = follow(events)
    fit.update({"event": "result"}, 100.0)
    # the variation, entered as the optimiser ended but never heard from, is passed by: its time is the render's
    assert "variation" in fit.skipped
    assert fit.durations["render"] == pytest.approx(events[-3][0] - events[end][0])


def test_the_variation_is_paced_by_its_share_not_by_its_unlike_counts():
    """The variation stage's first counts are quick readings and its last steps at the working size:
    counts that come fast do not shorten its time left, which is its share at the search's pace."""
    shares = {p.name: p.share for p in PHASES}
    events = [e for e in fit_timeline() if e[1] not in ("variation", "render", "report")]
    fit = follow(events)
    start = events[-1][0]
    fit.update(progress_event("variation", 0, VARIATION_COUNTS), start)
    before = fit.seconds_left(start + 0.1)
    for k in range(1, 8):   # the readings: seven counts in a tenth of a second
        fit.update(progress_event("variation", k, VARIATION_COUNTS), start + k * 0.01)
    assert fit.phase.name == "variation" and fit.describe(start + 0.1).startswith("Reading the yarns' irregularity")
    assert fit.seconds_left(start + 0.1) == pytest.approx(before)
    pace = fit.durations["optimise"] / shares["optimise"]   # the timeline keeps its shares: one pace
    assert before == pytest.approx(pace * (shares["variation"] + shares["render"] + shares["report"]) - 0.1, rel=0.01)
