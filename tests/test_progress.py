"""A fit's progress over its whole run (backend/core/progress.py): its phases read from the protocol's
events, one bar, the time left. Times are given to it, so every check here is replayable."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.core import progress, protocol  # noqa: E402
from backend.core.progress import MIN_REMAINDER, PHASES, PLATEAU, FitProgress, duration_words, replay  # noqa: E402


def progress_event(stage: str, iteration: int, total: int) -> dict:
    return {"event": "progress", "stage": stage, "iteration": iteration, "total": total}


def counts(stage: str, start: float, end: float, total: int, first: int = 1) -> list:
    """Events ``first``..``total`` of a stage, evenly from ``start`` to ``end``."""
    steps = total - first
    return [(start + (end - start) * (k - first) / max(steps, 1), stage, k, total) for k in range(first, total + 1)]


def fit_timeline(wall: float = 100.0, duel: bool = True) -> list:
    """A fit whose every phase lasts its share of ``wall``, its counts evenly spaced, in the fit's order of
    events: each stage's first event of iteration 0, the search's counter starting again for the
    starting points, the trials and the duel (each with the count its share is for), then 100
    optimiser steps (the duel's 10 first)."""
    shares = {phase.name: phase.share for phase in PHASES}
    if not duel:
        shares["optimise"] += shares.pop("duel")
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
    first = 11 if duel else 1
    events += counts("optimise", previous + (ends["optimise"] - previous) / (101 - first), ends["optimise"], 100, first)
    events += [(ends["optimise"], "render", 0, 1)]
    events += counts("render", ends["optimise"] + (ends["render"] - ends["optimise"]) / 10, ends["render"], 10)
    events += [(ends["render"], "report", 0, 1), (ends["report"], "report", 1, 1)]
    return events


def follow(events: list, until: float | None = None) -> FitProgress:
    fit = FitProgress(started=0.0)
    for t, stage, iteration, total in events:
        if until is not None and t > until:
            break
        fit.update(progress_event(stage, iteration, total), t)
    return fit


def test_the_phases_follow_the_protocols_stages_and_share_the_whole_fit():
    order = [protocol.STAGES.index(phase.stage) for phase in PHASES]
    assert order == sorted(order)
    assert sum(phase.share for phase in PHASES) == pytest.approx(1.0, abs=1e-9)
    assert all(phase.share > 0 and phase.words for phase in PHASES)


def test_the_events_are_placed_in_the_phases_the_fit_runs():
    fit = FitProgress(started=0.0)
    seen = []
    for t, stage, iteration, total in fit_timeline():
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
    trials_done = [t for t, stage, iteration, total in events if stage == "search"][-1]
    optimised = next(t for t, stage, iteration, total in events if (stage, iteration) == ("optimise", 100))
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
    fit = follow(fit_timeline(), until=10.0)
    assert fit.phase.name == "placement"
    assert fit.fraction(8.0) < fit.fraction(10.0) < fit.fraction(12.0)
    assert fit.seconds_left(8.0) > fit.seconds_left(10.0)


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
    fit = follow(fit_timeline(), until=25.0)
    assert fit.describe(25.0).startswith("Comparing weaves, 1 of 2, about ")
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
    makes the optimiser's time left twice as long, not the re-renders'."""
    shares = {p.name: p.share for p in PHASES}
    pace = 100.0  # seconds per share for the photos' phases; twice that for the search's
    t_load, t_place = shares["load"] * pace, (shares["load"] + shares["placement"]) * pace
    t_starts = t_place + 2 * pace * shares["starts"]
    t_trials = t_starts + 2 * pace * shares["trials"]
    events = [(0.0, "load", 0, 1), (t_load, "load", 1, 1), (t_load, "search", 0, 1), (t_place, "search", 1, 2),
              (t_starts, "search", 2, 2), ((t_starts + t_trials) / 2, "search", 1, 2), (t_trials, "search", 2, 2)]
    fit = follow(events)
    assert fit.phase.name == "duel"
    expected = 2 * pace * (shares["duel"] + shares["optimise"]) + pace * (shares["render"] + shares["report"])
    assert fit.seconds_left(t_trials) == pytest.approx(expected)


def test_an_optimiser_whose_loss_has_settled_is_expected_to_stop_when_its_patience_runs_out():
    """PLATEAU: the optimiser ends once its best loss has not moved for its patience (FitSettings'),
    not before its first discrete search. Its loss unchanged for half its patience, the time left
    counts the steps to that end, not to its total; a loss still falling counts them all."""
    optimiser = next(p for p in PHASES if p.name == "optimise")
    start = [(0.0, "load", 0, 1), (1.0, "load", 1, 1), (1.0, "search", 0, 1), (10.0, "search", 1, 1),
             (20.0, "search", 1, 1)]

    def after(losses):
        fit = follow(start)
        for step, loss in enumerate(losses, start=1):
            fit.update({**progress_event("optimise", step, 100), "loss": loss}, 20.0 + step)
        return fit

    settled = 30 + round(PLATEAU * optimiser.patience)
    falling = after([1.0 / k for k in range(1, settled + 1)])
    flat = after([1.0 / min(k, 30) for k in range(1, settled + 1)])
    now = 20.0 + settled
    assert flat._last_count() == 30 + optimiser.patience and falling._last_count() == 100
    assert flat.seconds_left(now) < falling.seconds_left(now)
    assert after([1.0] * 12)._last_count() == optimiser.ends_from  # settled at once: not before the first search
    assert after([1.0] * 9)._last_count() == 100   # not yet half its patience


def test_the_optimisers_patience_is_the_fits():
    from backend.fit.settings import FitSettings

    optimiser = next(p for p in PHASES if p.name == "optimise")
    assert (optimiser.patience, optimiser.ends_from) == (FitSettings().patience, FitSettings().first_search + 1)
