"""A fit's progress over its whole run, read from its protocol events (plain Python: the add-on reads
it too, through blender_addon/core/declarations.py).

The fit command reports each stage with its own counter (:mod:`backend.core.protocol`: stage,
iteration, total), and the search stage's counter starts again for each of its steps. Read in
order, the events still say where a fit is: :data:`PHASES` lists what a fit does, in the order it
does it, each with its words and its share of a fit's time. :class:`FitProgress` follows one fit
and gives, at any moment, the phase in words with its count ("Comparing weaves, 2 of 3"), the
time left over all the phases, and one bar:

    pace(kind) = seconds / shares of the phases done of that kind (those the photos alone set, or
                 those the search and the working size set), with the current one's work so far
    left       = remainder of the current phase + sum over the phases to come of share * pace(kind)
    remainder  = before its second count: max(share * pace - its time so far, MIN_REMAINDER * share * pace)
                 from then on: its seconds per count * its work left - the time since its last count
    work left  = its counts to come and its pauses before them (the optimiser's discrete searches,
                 SEARCH_COUNTS counts each), to its total or, for the optimiser, to where it ends
                 once its best loss has held for its patience, where that is the likelier end
    bar        = (shares of the phases done + share of the current one * its time so far
                  / (its time so far + remainder)) / shares of the phases the fit runs

The optimiser says in its events how many steps its best loss has held (``since_best``) and its
patience; after s steps without a new best the chance of holding to a patience P is taken as
(s + 1) / (P + 1) (Laplace's rule of succession: :meth:`FitProgress.work_left`). A phase a fit
passes by (the duel where the working size is the search's, trials with nothing to compare) leaves
the shares. The bar moves as the clock does where the shares hold, also through a phase that
reports no count, and never runs ahead of the phase the fit is in; where the time left grows (a
new best after a long hold) it may step back, which a caller showing it holds (the add-on does).

The shares and SEARCH_COUNTS were measured on some of the benchmark's real pairs by
``tools/fit_timeline.py``, which records when each event arrives and replays the records through
this module (``replay --tune``: the other recorded fits are held out; the figures are in the results
ledger, ``devtools/bench/results/fit-timeline.jsonl``), on the fit's CPU clock: a busy machine
stretches the seconds, not the shares. Times are given by the caller (``now``, seconds on
any monotonic clock), so that a recorded fit replays exactly.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Phase:
    """One step of a fit as its events show it.

    stage: the protocol stage whose events it has; words: what the bar says; share: its part of a
    fit's wall time, where it runs; fixed: whether the photos alone set its work (reading them,
    placing the weave, the re-renders at the film size, the report), else the search and the
    working size do; counted: whether its events count its work (else only its start is known);
    optional: whether a fit may pass it by without an event (the duel runs only where the working
    size is above the search's); counts: the count its share is for, where its work grows with its
    count (a fit with five trials has five halves of the two trials' share); patience: the counts
    without a better loss after which it ends early, though not before count ``ends_from`` (the
    optimiser: FitSettings.patience, and its first discrete search, FitSettings.first_search);
    pauses: the counts after which it does extra work before its next event, unless it has reached
    its total (the optimiser's discrete searches: FitSettings.first_search, search_every,
    max_searches), each as long as ``pause_counts`` of its counts.
    """

    name: str
    stage: str
    words: str
    share: float
    fixed: bool = False
    counted: bool = True
    optional: bool = False
    counts: int = 0
    patience: int = 0
    ends_from: int = 0
    pauses: tuple[int, ...] = ()
    pause_counts: float = 0.0


# A discrete search of the optimiser (20 loss evaluations) takes as long as this many of its steps
# (measured by tools/fit_timeline.py replay on the fits it tunes on).
SEARCH_COUNTS = 16.6
# In the order a fit runs them. An event of iteration 0 starts a stage and counts nothing. A
# counted phase ends where its count is complete (the next one begins then: the work of its first
# count comes before that count's event) or where its counter starts again (the iteration goes
# back, or the total changes); an uncounted one where its stage's next phase counts.
PHASES: tuple[Phase, ...] = (
    Phase("load", "load", "Reading the photos", 0.0082, fixed=True),
    Phase("placement", "search", "Finding the weave in the photos", 0.0535, fixed=True, counted=False),
    Phase("starts", "search", "Trying starting points", 0.0037, counts=2),
    Phase("trials", "search", "Comparing weaves", 0.2092, counts=2),
    Phase("duel", "search", "Checking the weave at full size", 0.1738, counts=30, optional=True),
    Phase("optimise", "optimise", "Optimising", 0.3995, patience=20, ends_from=25, pauses=(25, 50, 75),
          pause_counts=SEARCH_COUNTS),
    # its counts are not alike (quick readings, then steps at the working size): its share, not its count, paces it
    Phase("variation", "variation", "Reading the yarns' irregularity", 0.081, counted=False, optional=True),
    Phase("render", "render", "Rendering the result", 0.0635, fixed=True),
    Phase("report", "report", "Writing the report", 0.0076, fixed=True, counted=False),
)
NAMES = tuple(phase.name for phase in PHASES)
MIN_REMAINDER = 0.1  # a phase near or past its expected length still has this part of that length to go
# A counted phase done in less than this part of its expected length did no work of its own (the
# trials a search passes by: a lone start, or a weave and its face twin, which the duel tells apart).
PASSED_BY_BELOW = 0.1
# The optimiser is expected to stop when its patience runs out where its best is at least this likely
# to hold until then (held_to_patience), else to run to its total: the likelier of the two ends.
LIKELIER = 0.5


@dataclass
class _Current:
    """The phase a fit is in: when it began, and its first and last counts (time, iteration)."""

    index: int = -1               # into PHASES; -1: before the first event
    started: float = 0.0          # on the caller's clock
    first: tuple[float, int] | None = None
    last: tuple[float, int] | None = None
    total: int = 0
    heard: bool = False           # an event of its own has come (else the phase before it ended into it)
    best: tuple[float, int] | None = None   # its lowest loss so far, and the count that reached it
    since_best: int | None = None   # counts since its best loss last moved (the fit's, else read from its losses)
    patience: int | None = None     # counts without a new best after which it ends (the fit's, else its Phase's)


@dataclass
class FitProgress:
    """Follows one fit: call :meth:`update` with each protocol event (progress and result events
    count; the others are passed by) and read :meth:`fraction`, :meth:`seconds_left` and
    :meth:`describe`."""

    started: float
    current: _Current = field(default_factory=_Current)
    durations: dict[str, float] = field(default_factory=dict)   # phases done -> seconds
    totals: dict[str, int] = field(default_factory=dict)        # phases done -> their count's total
    skipped: set[str] = field(default_factory=set)
    finished: bool = False

    # -- reading events -----------------------------------------------------------------------
    def update(self, event: dict, now: float) -> None:
        if event.get("event") == "result":
            self._enter(len(PHASES), now)
            self.finished = True
        if event.get("event") != "progress":
            return
        iteration, total = int(event.get("iteration") or 0), int(event.get("total") or 0)
        index = self._phase_of(str(event.get("stage")), iteration, total)
        if index is None:
            return
        if index != self.current.index:
            self._enter(index, now)
        self.current.heard = True
        if iteration <= 0 or not PHASES[index].counted:
            return
        current = self.current
        current.first = current.first or (now, iteration)
        current.last, current.total = (now, iteration), total
        loss = event.get("loss")
        if isinstance(loss, (int, float)) and (current.best is None or loss < current.best[0]):
            current.best = (float(loss), iteration)
        since_best, patience = event.get("since_best"), event.get("patience")
        if isinstance(patience, int):
            current.patience = patience
        if isinstance(since_best, int):
            current.since_best = since_best
        elif current.best is not None:   # a fit that does not say: where its reported loss was lowest
            current.since_best = iteration - current.best[1]
        if 0 < total <= iteration:   # complete: the next phase's work begins now
            self._enter(index + 1, now)

    def _phase_of(self, stage: str, iteration: int, total: int) -> int | None:
        """The phase an event belongs to: the current one while it goes on, else the next of its stage;
        None for a late event of a stage the fit has left (a stage that says its end twice: counted
        against the phase after it, it would end that one at once)."""
        index, current = self.current.index, self.current
        later = [k for k, p in enumerate(PHASES) if p.stage == stage and k > index]
        if not 0 <= index < len(PHASES) or PHASES[index].stage != stage:
            if later:
                return later[0]
            return None if any(p.stage == stage for p in PHASES[:max(index, 0)]) else max(index, 0)
        phase = PHASES[index]
        if not phase.counted:
            goes_on = iteration <= 0
        else:
            goes_on = (iteration <= 0 or current.last is None
                       or (iteration > current.last[1] and total == current.total))
        return index if goes_on or not later else later[0]

    def _enter(self, index: int, now: float) -> None:
        """Ends the current phase at ``now`` and begins phase ``index``; those between are passed by.
        A phase that did no work of its own (:meth:`_passed_by`) counts as passed by: its time goes
        to the next one."""
        started = now
        if 0 <= self.current.index < len(PHASES):
            phase = PHASES[self.current.index]
            if self._passed_by(phase, now):
                self.skipped.add(phase.name)
                started = self.current.started
            else:
                self.durations[phase.name] = now - self.current.started
                self.totals[phase.name] = self.current.total
        self.skipped.update(p.name for p in PHASES[self.current.index + 1:index])
        self.current = _Current(index, started)

    def _passed_by(self, phase: Phase, now: float) -> bool:
        """An optional phase left without a count (one that counts nothing: without an event of its
        own), or a counted one done in less than :data:`PASSED_BY_BELOW` of its expected length."""
        if not phase.counted:
            return phase.optional and not self.current.heard
        if self.current.last is None:
            return phase.optional
        pace = self._pace(phase.fixed, with_current=False)
        return pace is not None and now - self.current.started < PASSED_BY_BELOW * pace * self.share(phase)

    # -- what the bar shows -------------------------------------------------------------------
    @property
    def phase(self) -> Phase | None:
        return PHASES[self.current.index] if 0 <= self.current.index < len(PHASES) else None

    def share(self, phase: Phase) -> float:
        """A phase's share in this fit: for one whose work grows with its count, scaled by its count's
        total (once known) over the count its share is for."""
        total = self.totals.get(phase.name) or (self.current.total if phase is self.phase else 0)
        return phase.share * total / phase.counts if phase.counts and total else phase.share

    def _pace(self, fixed: bool, with_current: bool = True) -> float | None:
        """Seconds per share of the phases whose work the photos set (``fixed``), or of those the
        search and working size set: from the phases of that kind done and (``with_current``) the
        current one's counts from its second on, else from the other kind's; None before a phase
        has ended."""
        seconds, shares = 0.0, 0.0
        for kind in (fixed, not fixed):
            for phase in PHASES:
                if phase.fixed == kind and phase.name in self.durations:
                    seconds, shares = seconds + self.durations[phase.name], shares + self.share(phase)
            current = self.current
            if with_current and self.phase is not None and self.phase.fixed == kind and current.first is not None \
                    and current.total > current.last[1] > current.first[1]:
                # the phase's work is its counts after the first (whose event begins it)
                seconds += current.last[0] - current.first[0]
                done = self._work(current.first[1], current.last[1]) / self._work(current.first[1], current.total)
                shares += self.share(self.phase) * done
            if shares > 0:
                return seconds / shares
        return None

    def _remainder(self, pace: float, now: float) -> float:
        """The current phase's time left: until its second count, its share at the fit's pace less
        its time so far (but at least :data:`MIN_REMAINDER` of that share: a phase that overruns keeps
        the bar moving, ever slower, short of its end); from then on its own pace per count times
        the work it is expected to do still (:meth:`work_left`: its counts to come and its pauses
        before them), less the time since its last count."""
        current = self.current
        if current.first is None or current.last[1] <= current.first[1]:
            expected = pace * self.share(self.phase)
            return max(expected - (now - current.started), MIN_REMAINDER * expected)
        per_count = (current.last[0] - current.first[0]) / self._work(current.first[1], current.last[1])
        return max(per_count * self.work_left() - (now - current.last[0]), 0.0)

    def _work(self, after: int, to: int) -> float:
        """The current phase's work from its count ``after`` to its count ``to``, in counts: one each,
        and :attr:`Phase.pause_counts` for each of its pauses between (none after its total)."""
        phase, total = self.phase, self.current.total
        pauses = sum(after < k <= to and k < total for k in phase.pauses)
        return (to - after) + phase.pause_counts * pauses

    def work_left(self) -> float:
        """The current phase's work to come, in counts (:meth:`_work`): to its total, or, for a phase
        that ends early once its best loss has held for its patience P (the optimiser), to where it
        ends if its best holds from now on (P counts after the best, but not before count
        ``ends_from``) where that is the likelier end. The chance is read from how long the best
        has held already (s counts): with the chance of a new best at a count unknown, every value
        as likely as another (a uniform prior: Laplace's rule of succession), the chance of P - s
        more counts without one after s without one is (s + 1) / (P + 1), at least one half
        (:data:`LIKELIER`) from s = (P - 1) / 2 on. The likelier end, not the mean of the two: the
        time left is promised within a part of the truth (:data:`ETA_CHECK`), which a mean of two
        ends far apart misses at both. After a new best the phase may run on again, and its time
        left grows back."""
        current, phase = self.current, self.phase
        last = current.last[1] if current.last is not None else 0
        patience = phase.patience if current.patience is None else current.patience
        if patience and current.since_best is not None and held_to_patience(current.since_best, patience) >= LIKELIER:
            stop = min(current.total, max(last + patience - max(current.since_best, 0), phase.ends_from, last))
            return self._work(last, stop)
        return self._work(last, current.total)

    def seconds_left(self, now: float) -> float | None:
        """The estimated time left (None before a phase has ended: no pace yet)."""
        if self.finished:
            return 0.0
        if self.phase is None or self._pace(True) is None:
            return None
        to_come = [p for p in PHASES[self.current.index + 1:] if p.name not in self.skipped]
        return self._remainder(self._pace(self.phase.fixed), now) + sum(p.share * self._pace(p.fixed) for p in to_come)

    def fraction(self, now: float) -> float:
        """The bar: the shares of the phases done, and of the current one the part its time so far is
        of its time so far and left, in_phase / (in_phase + remainder). It moves as the clock does
        where the shares hold, never stops while the fit runs, and never runs ahead of the phase the
        fit is in (early on the pace rests on a short first phase). 0 until there is a pace, 1 once
        the fit has ended."""
        if self.finished:
            return 1.0
        pace = None if self.phase is None else self._pace(self.phase.fixed)
        if pace is None:
            return 0.0
        run = [p for p in PHASES if p.name not in self.skipped]
        whole = sum(map(self.share, run))
        before = sum(self.share(p) for p in run if PHASES.index(p) < self.current.index)
        in_phase = now - self.current.started
        remainder = self._remainder(pace, now)
        within = in_phase / (in_phase + remainder) if in_phase + remainder > 0 else 1.0
        return (before + self.share(self.phase) * within) / whole

    def describe(self, now: float) -> str:
        """One line: 'Comparing weaves, 2 of 3, about 4 min left'."""
        phase = self.phase
        if phase is None:
            return "Fit finished" if self.finished else "Starting the fit"
        text = phase.words
        if phase.counted and self.current.last is not None and self.current.total > 1:
            text += f", {self.current.last[1]} of {self.current.total}"
        left = self.seconds_left(now)
        return text + (f", about {duration_words(left)} left" if left is not None else "")


def held_to_patience(since_best: int, patience: int) -> float:
    """The chance that a best loss that has held for ``since_best`` counts holds until ``patience``
    (Laplace's rule of succession: :meth:`FitProgress.work_left`)."""
    return min(1.0, (max(since_best, 0) + 1) / (patience + 1))


def duration_words(seconds: float) -> str:
    """'40 s', '3 min', '1 h 05 min': a time left, as precise as an estimate deserves."""
    seconds = max(0, round(seconds))
    if seconds < 90:
        return f"{max(5, round(seconds / 5) * 5)} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60:02d} min"


@dataclass(frozen=True)
class Replay:
    """How the bar did on one recorded fit (:func:`replay`)."""

    shares: dict[str, float]          # phase -> its part of the fit's time, for the count its share is for
    worst_eta_error: float            # (estimate - truth) / truth of the time left, largest in size
    worst_bar_error: float            # bar - elapsed / whole time, largest in size
    within: float                     # the part of the checks whose estimate is within ETA_CHECK of the truth


ETA_CHECK = 0.25  # the promise of the bar's time left, checked by replay: within this part of the truth


def replay(events: list, total_s: float, from_fraction: float = 0.2, tail: float = 0.1) -> Replay:
    """Runs a recorded fit (``events``: (seconds, stage, iteration, total[, loss[, since_best[, patience]]])
    in arrival order, ``total_s`` when it ended, on the same clock) through :class:`FitProgress`, checking the
    estimate every second and at every event from ``from_fraction`` of the bar on (the bar as an
    artist sees it: it never goes back) until the last ``tail`` of the fit's time, where a few
    seconds are a large part of the truth."""
    follow = FitProgress(started=0.0)
    pending = list(events)
    errors, bar_errors, shown = [], [], 0.0
    for now in sorted({float(t) for t, *_ in events} | {float(s) for s in range(int(total_s))}):
        while pending and pending[0][0] <= now:
            t, stage, iteration, total, *optional = pending.pop(0)
            loss, since_best, patience = (*optional, None, None, None)[:3]
            follow.update({"event": "progress", "stage": stage, "iteration": iteration, "total": total,
                           "loss": loss, "since_best": since_best, "patience": patience}, t)
        left, truth = follow.seconds_left(now), total_s - now
        shown = max(shown, follow.fraction(now))
        if left is not None and shown >= from_fraction and truth >= max(tail * total_s, 1.0):
            errors.append((left - truth) / truth)
            bar_errors.append(shown - now / total_s)
    follow.update({"event": "result"}, total_s)
    shares = {phase.name: follow.durations.get(phase.name, 0.0) / total_s * phase.share / follow.share(phase)
              for phase in PHASES}
    within = sum(abs(error) <= ETA_CHECK for error in errors) / len(errors) if errors else 1.0
    return Replay(shares, max(errors, key=abs, default=0.0), max(bar_errors, key=abs, default=0.0), within)
