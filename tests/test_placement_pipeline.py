"""The placement as a declared pipeline (backend.texture.placement): each hypothesis generator on small
synthetic spectra, the selection's rules on hand-made hypotheses, the checks against the unturned
sample and the sieve's turn, and the whole placement's stability under noise far below a sensor's."""
import dataclasses

import numpy as np
import pytest

from backend.core.params import FabricParams
from backend.core.priors import FIT_PATTERNS
from backend.core.rig import DEFAULT_RIG, CaptureRig
from backend.image.photos import load_pair
from backend.image.spectrum import Peak
from backend.model.render import render_pair
from backend.texture import gates, placement
from backend.texture.candidates import Candidate, Read
from backend.texture.frequencies import fold, turned_frequencies
from backend.texture.gates import GATES
from backend.texture.lattice import Lattice
from backend.texture.placement import checks, select
from backend.texture.placement.mapped import mapped
from backend.texture.placement.paired import angle_pairs, paired, sheared
from backend.texture.placement.peaked import peaked
from backend.texture.placement.scan import Placement, Scan
from backend.texture.placement.turned import turned
from backend.texture.spectra import Spectra

SPAN = (10.0, 240.0)


def synthetic_spectra(a, b, rotation, skew=0.0, peaks_of=None, size=512, photos=2, seed=0):
    """Spectra of photos showing only the lattice (a, b) turned and sheared: every harmonic (m, n),
    |m|, n <= 4, a peak of strength 16 / (1 + |m| + n) (the 24 strongest of a photo, as
    spectral_peaks keeps them) and a blob on the twice zero-padded peakness map. ``peaks_of``:
    (a, b, rotation) of another lattice whose peaks the sieves read instead (the maps stay)."""
    rng = np.random.default_rng(seed)
    pad = 2
    yy, xx = np.mgrid[0:size * pad, 0:size * pad]
    harmonics = {(m, n): 16.0 / (1 + abs(m) + n) for m in range(-4, 5) for n in range(5) if n > 0 or m > 0}

    def folded(lattice_a, lattice_b, turn, shear, m, n):
        fx, fy = turned_frequencies(m * lattice_a, n * lattice_b, turn, shear)
        return float(fold(fx, size)), float(fold(fy, size))

    peaks, maps = [], []
    for _ in range(photos):
        q = 0.02 * rng.random((size * pad, size * pad))
        found = []
        for (m, n), strength in harmonics.items():
            fx, fy = folded(a, b, rotation, skew, m, n)
            for sx, sy in ((fx, fy), (-fx, -fy)):
                q += strength * np.exp(-((xx - size - sx * pad) ** 2 + (yy - size - sy * pad) ** 2) / (2 * pad ** 2))
            if peaks_of is not None:
                fx, fy = folded(*peaks_of, 0.0, m, n)
            sign = 1.0 if fy > 0 or (fy == 0 and fx > 0) else -1.0
            found.append(Peak(sign * fx, sign * fy, strength))
        peaks.append(sorted(found, key=lambda p: -p.strength)[:24])
        maps.append(q)
    return Spectra(size, peaks, maps, [np.zeros((size, size))] * photos)


def best(placements):
    return max(placements, key=lambda p: p.score)


@pytest.fixture(scope="module")
def turned_scan():
    return Scan(synthetic_spectra(40.0, 50.0, 2.0), SPAN, SPAN)


@pytest.fixture(scope="module")
def sheared_scan():
    return Scan(synthetic_spectra(40.0, 50.0, 1.5, 3.5), SPAN, SPAN)


def test_the_summed_sieves_find_a_turned_lattice(turned_scan):
    assert turned_scan.sieve_turn_deg == 2.0
    found = best(turned(turned_scan))
    assert (found.rotation_deg, found.skew_deg) == pytest.approx((2.0, 0.0), abs=0.05)
    assert (found.lattice.a, found.lattice.b) == pytest.approx((40.0, 50.0), rel=0.002)


def test_a_shear_is_found_and_confirmed_only_where_the_yarns_are_sheared(turned_scan, sheared_scan):
    shear = best(sheared(sheared_scan, angle_pairs(sheared_scan)))
    assert (shear.rotation_deg, shear.skew_deg) == pytest.approx((1.5, 3.5), abs=0.1)
    assert (shear.lattice.a, shear.lattice.b) == pytest.approx((40.0, 50.0), rel=0.005)
    assert select.shear_confirmed(sheared_scan, shear, best(turned(sheared_scan)))
    # an unsheared sample's best shear explains its maps no better than its turn does
    unsheared = best(sheared(turned_scan, angle_pairs(turned_scan)))
    assert not select.shear_confirmed(turned_scan, unsheared, best(turned(turned_scan)))


def test_paired_angles_also_give_a_turn_at_their_middle(sheared_scan):
    pairs = angle_pairs(sheared_scan)
    warp, weft, _ = pairs[0]
    middle = paired(sheared_scan, pairs[:1])[0]
    assert middle.skew_deg == 0.0
    # refined twice, each time by up to refine_reach_deg
    assert middle.rotation_deg == pytest.approx((warp + weft) / 2, abs=2 * GATES.refine_reach_deg + 1e-9)


def test_the_maps_give_a_turn_where_the_sieves_read_peaks_elsewhere():
    # The sieves read peaks of a lattice turned -3 degrees (peaks smeared elsewhere); the maps show it
    # turned +2: the summed scan peaks at -3, the map scan finds +2.
    scan = Scan(synthetic_spectra(40.0, 50.0, 2.0, peaks_of=(40.0, 50.0, -3.0)), SPAN, SPAN)
    assert scan.sieve_turn_deg == -3.0
    found = best(mapped(scan))
    assert found.rotation_deg == pytest.approx(2.0, abs=0.05)
    assert (found.lattice.a, found.lattice.b) == pytest.approx((40.0, 50.0), rel=0.002)


def test_the_map_scan_refines_only_the_maxima_the_summed_scan_has_not():
    class Recorder:
        angles = np.arange(8.0)
        turn_maxima = [3, 7]
        multiples = [[Lattice(1.0, 1.0, score)] for score in (1.0, 5.0, 2.0, 9.0, 1.0, 4.0, 3.0, 8.0)]

        def refined_at(self, ks):
            self.asked = ks
            return []

    scan = Recorder()
    mapped(scan)
    assert scan.asked == [1, 5]  # the map scan's maxima, best first, less the summed scan's (3, 7)


def test_two_strong_peaks_give_a_turn_the_sieves_miss():
    # A plain at 2-3 px per yarn keeps only its (1, 1) and (-1, 1) harmonics and an aliased yarn
    # harmonic: the sieves find no comb, two peaks pin the lattice and its turn.
    a, b, turn = 99.0, 97.5, -2.9
    spectra = synthetic_spectra(a, b, turn)
    strong = {(1, 1): 7.0, (-1, 1): 6.5}

    def peak(m, n, strength):
        fx, fy = turned_frequencies(m * a, n * b, turn)
        sign = 1.0 if fy > 0 or (fy == 0 and fx > 0) else -1.0
        return Peak(sign * fx, sign * fy, strength)

    spectra = dataclasses.replace(spectra, peaks=[[peak(m, n, s) for (m, n), s in strong.items()]
                                                  + [Peak(512 - 2 * a, 6.0, 5.0)], []])
    found = best(peaked(Scan(spectra, SPAN, SPAN)))
    assert found.rotation_deg == pytest.approx(turn, abs=0.05)
    assert (found.lattice.a, found.lattice.b) == pytest.approx((a, b), rel=0.005)


def test_only_a_placement_whose_lattices_miss_the_peaks_gives_way_and_only_to_one_that_makes_them(monkeypatch):
    a, b, turn = 40.0, 50.0, -4.0
    scale = DEFAULT_RIG.view_size / DEFAULT_RIG.plane_size

    def peak(m, n, strength):
        fx, fy = turned_frequencies(m * a, n * b, turn)
        return Peak(float(fx), float(fy), strength)

    spectra = Spectra(512, [[peak(1, 0, 5.0), peak(0, 1, 4.0), peak(1, 1, 3.0), peak(2, 1, 2.0)], []], [], [])
    true = Candidate("twill1", (a / scale, b / scale), 1.0)
    missing = Candidate("twill1", (1.2 * a / scale, 0.8 * b / scale), 1.0)   # none of its harmonics shows
    read_at, offered = [], [true]
    monkeypatch.setattr(checks, "read_at", lambda spectra, rig, at, *args, **kwargs: (
        read_at.append(at) or Read(list(offered), ["the sieve turn's readings"])))

    def rescued(at, found, sieve_turn=turn, rivals=None):
        return checks.rescued(spectra, DEFAULT_RIG, ("twill1",), 1, sieve_turn, at, Read(found, ["readings"]),
                              rivals or {}, 1)

    # placed where its lattices miss the peaks: the sieve's turn, whose lattices make them
    assert rescued((-0.32, 0.0), [missing]) == ((turn, 0.0), Read([true], ["the sieve turn's readings"]))
    assert read_at == [(turn, 0.0)]
    # a rival must make rescue_gain more of the peaks than the placement it would replace
    offered[:] = [missing]
    assert rescued((-0.32, 0.0), [missing]) == ((-0.32, 0.0), Read([missing], ["readings"]))
    # the placement compared with the unturned sample is a rival too, read already: the sieve's turn
    # is read only where no placement lies there, and the best rival wins
    read_at.clear()
    other = Read([true], ["its"])
    assert rescued((0.0, 0.0), [missing], rivals={(-3.9, 0.0): other}) == ((-3.9, 0.0), other)
    assert read_at == []
    offered[:] = [true]
    assert rescued((0.0, 0.0), [missing], rivals={(-2.0, 0.0): Read([missing], ["its"])})[0] == (turn, 0.0)
    # a placement whose lattices make the peaks is not questioned, nor an unsheared one at the sieve's
    # turn; a sheared one there is another placement
    read_at.clear()
    assert rescued((turn, 0.0), [true], sieve_turn=1.5)[0] == (turn, 0.0)
    assert rescued((-3.6, 0.0), [missing])[0] == (-3.6, 0.0)
    assert read_at == []
    assert rescued((-3.6, 2.0), [missing])[0] == (turn, 0.0)


@pytest.mark.parametrize("estimate, unturned_turn, turned_turn, placed_at", [
    (1.5, 1.40, 1.45, 1.45),    # both placements' yarn vectors show the turn: the turned one stands
    (1.5, None, None, 1.5),     # neither shows one: the turned estimate stands all the same
    (5.0, 0.03, 4.88, 0.03),    # they disagree: the comb scores decide
    (0.3, None, None, 0.0),     # a turn under min_turn_deg: the comb scores decide
    (1.5, 0.2, None, 0.2),      # only one shows a turn: that one
])
def test_a_turned_estimate_stands_where_the_yarn_vectors_do_not_contradict_it(monkeypatch, estimate, unturned_turn,
                                                                             turned_turn, placed_at):
    """place() between the unturned sample and the estimate's turn, the comb lattices scoring higher
    unturned (the scores of two placements do not compare): which placement it keeps, and the turn
    it returns."""
    unturned, turned_at = (0.0, 0.0), (estimate, 0.0)
    turns = {unturned: unturned_turn, turned_at: turned_turn}
    scores = {unturned: 2.9, turned_at: 1.6}
    monkeypatch.setattr(placement, "estimate", lambda *args: Placement(
        1.0, estimate, estimate, Lattice(40.0, 50.0, 1.0), sieve_turn_deg=0.0))  # yarn angles
    monkeypatch.setattr(checks, "comb_lattices", lambda spectra, rig, *args, **kwargs: {"twill1": [Lattice(
        40.0, 50.0, scores[rig.sample_rotation_deg, rig.sample_skew_deg])]})
    monkeypatch.setattr(checks, "read_combs", lambda spectra, rig, *args: Read(
        [Candidate("twill1", (40.0, 50.0), 1.0)], [(rig.sample_rotation_deg, rig.sample_skew_deg)]))
    vote = lambda readings, at, reflection_votes=1: turns[readings[0]]  # noqa: E731
    monkeypatch.setattr(checks, "yarn_turn", vote)
    monkeypatch.setattr(placement, "yarn_turn", vote)
    monkeypatch.setattr(checks, "rescued", lambda spectra, rig, patterns, per_pattern, sieve_turn, at, read, rivals,
                        workers: (at, read))
    (rotation, skew), _ = placement.place(None, DEFAULT_RIG, ("twill1",), None)
    assert (rotation, skew) == (placed_at, 0.0)


TWILL = FabricParams.from_interchange(
    "twill1_R_0.72,0.55_S_1.3,1.6_T_2.4,2.9_N_0.0_UV_92.0,131.0_Kd_0.32,0.18,0.11,0.26,0.14,0.08"
    "_G_0.88,0.9_Rm_0.7,0.45_Tm_2.2,2.6_W_0.6,0.9_Ks_0.62,0.38,0.25,0.55,0.33,0.22_Psi_-30.0,-30.0")


@pytest.fixture(scope="module")
def turned_twill():
    pair = render_pair(TWILL, CaptureRig(sample_rotation_deg=-2.5), size=512, spp=8, seed=3)
    return Spectra.of([pair.reflection.numpy(), pair.transmission.numpy()])


def test_the_sample_rotation_is_read_and_a_given_one_kept(turned_twill):
    found = placement.estimate(turned_twill, DEFAULT_RIG, FIT_PATTERNS)
    assert (found.rotation_deg, found.skew_deg) == pytest.approx((-2.5, 0.0), abs=0.25)
    (rotation, skew), found = placement.place(turned_twill, DEFAULT_RIG, ("twill1",), None)
    assert (rotation, skew) == pytest.approx((-2.5, 0.0), abs=0.25)
    assert found[0].tiles == pytest.approx(TWILL.tiles, rel=0.01)
    given, _ = placement.place(turned_twill, DEFAULT_RIG, ("twill1",), 1.0)
    assert given == (1.0, 0.0)
    unturned = render_pair(TWILL, size=512, spp=8, seed=3)
    found = placement.estimate(Spectra.of([unturned.reflection.numpy(), unturned.transmission.numpy()]),
                               DEFAULT_RIG, FIT_PATTERNS)
    assert (found.rotation_deg, found.skew_deg) == pytest.approx((0.0, 0.0), abs=0.25)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["satin1_s1", "satin1_s2"])
def test_dense_satins_get_their_own_lattice(golden_dir, golden_cases, name):
    # 0.7 px per yarn across: only aliased harmonics remain. The shrunk photos' comb and the unturned
    # placement are hypotheses too, judged by the pattern signature.
    truth = FabricParams.from_interchange(next(c for c in golden_cases if c["name"] == name)["params"])
    pair = load_pair(golden_dir / f"{name}_R.png", golden_dir / f"{name}_T.png", size=512)
    at, found = placement.place(Spectra.of([pair.reflection, pair.transmission]), DEFAULT_RIG, FIT_PATTERNS, None)
    satin = next(c for c in found if c.pattern == "satin1")
    assert at == pytest.approx((0.0, 0.0), abs=0.02)
    assert satin.tiles == pytest.approx(truth.tiles, rel=0.01)
    assert max(found, key=lambda c: c.score).pattern == "satin1"


def test_every_gate_is_declared_with_what_it_guards():
    table = gates.table()
    assert len(table) == len(dataclasses.fields(GATES)) > 30
    assert all(isinstance(guards, str) and len(guards) > 20 for _, _, guards in table)
    assert dict((name, value) for name, value, _ in table)["rival_turn_gain"] == GATES.rival_turn_gain


class Judged:
    """A stand-in scan for the selection: the summed sieve scan's strongest turn, and which
    hypotheses explain each photo better than the summed-scan turn."""

    def __init__(self, sieve_turn_deg, beaten_on_each_photo=()):
        self.sieve_turn_deg = sieve_turn_deg
        self.beaten = set(beaten_on_each_photo)

    def beats_on_each_photo(self, placement, rivals):
        return placement.rotation_deg in self.beaten


def turn(rotation, score):
    return Placement(score, rotation, rotation, Lattice(40.0, 50.0, score))


def test_a_rival_is_measured_against_the_summed_scans_turn_whatever_the_others():
    summed, mapped_turn, peak_turn = turn(4.76, 1.03), turn(5.9, 1.13), turn(2.73, 1.095)
    scan = Judged(2.75, beaten_on_each_photo=(5.9, 2.73))
    # the peak-pair turn agrees with the sieves (the summed turn does not): it needs no gain; the map
    # turn does not, and 1.13 is under rival_turn_gain x 1.03
    assert select.select_turn(scan, [summed], [], [mapped_turn], [peak_turn]) == peak_turn
    # both qualify: the standing decides (1.1 x 1.095 against 1.15), whichever generator proposed which
    stronger = turn(5.9, 1.15)
    assert select.select_turn(scan, [summed], [], [stronger], [peak_turn]) == peak_turn
    assert select.select_turn(scan, [summed], [], [peak_turn], [stronger]) == peak_turn
    strongest = turn(5.9, 1.1 * 1.095 + 0.01)
    assert select.select_turn(scan, [summed], [strongest], [], [peak_turn]) == strongest
    # a rival that agrees with the sieves as the summed turn does needs the gain as well
    assert select.select_turn(Judged(4.75, (4.6,)), [summed], [], [], [turn(4.6, 1.1)]) == summed


def test_summed_scan_turns_scoring_alike_give_the_smallest_turn():
    alike, stronger = turn(4.42, 1.0153), turn(-0.26, 1.0152)
    assert select.incumbent([alike, stronger]) == stronger
    assert select.incumbent([turn(4.42, 1.0152 * GATES.tie_ratio + 1e-4), stronger]).rotation_deg == 4.42
    assert select.select_turn(Judged(4.5), [alike, stronger], [], [], []) == stronger


def test_map_and_peak_turns_must_explain_each_photo_better_paired_ones_need_not():
    summed, rival = turn(0.0, 1.0), turn(2.0, 1.5)
    assert select.select_turn(Judged(0.0), [summed], [], [rival], []) == summed        # not beaten on each photo
    assert select.select_turn(Judged(0.0, (2.0,)), [summed], [], [rival], []) == rival
    assert select.select_turn(Judged(0.0), [summed], [], [], [rival]) == summed
    assert select.select_turn(Judged(0.0), [summed], [rival], [], []) == rival         # paired angles
    assert select.select_turn(Judged(0.0), [summed], [turn(2.0, 1.09)], [], []) == summed


NOISE_FAR_BELOW_A_SENSOR = 1e-4  # of full scale: a phone's noise at mid-grey is about 1e-2


@pytest.mark.slow
@pytest.mark.parametrize("seed, index", [(61, 5), (31, 6)])  # photo-like pairs whose placement was on an edge
def test_the_placement_does_not_move_with_noise_far_below_a_sensors(tmp_path, seed, index):
    from devtools.bench import photolike

    case = photolike.make_item(tmp_path, seed=seed, index=index)
    pair = load_pair(tmp_path / f"{case['name']}_R.png", tmp_path / f"{case['name']}_T.png")
    placed = []
    for k in range(3):
        scale = NOISE_FAR_BELOW_A_SENSOR if k else 0.0
        noise = scale * np.random.default_rng(k).standard_normal((2, *pair.reflection.shape))
        spectra = Spectra.of([pair.reflection + noise[0], pair.transmission + noise[1]])
        placed.append(placement.place(spectra, DEFAULT_RIG, FIT_PATTERNS, None)[0])
    rotations, skews = zip(*placed)
    assert max(rotations) - min(rotations) <= 0.1 and max(skews) - min(skews) <= 0.1, placed
