"""The lattice reading's scores (texture.lattice, .sieve, .candidates) against slow references written from their
definitions: the fast paths evaluate every harmonic, tooth and lattice at once."""
import numpy as np
import pytest

from backend.core.priors import typical
from backend.core.rig import DEFAULT_RIG, CaptureRig, placement_of
from backend.image.spectrum import Peak
from backend.model.render import render_pair
from backend.texture import candidates, frequencies, lattice, sieve
from backend.texture.gates import GATES
from backend.texture.spectra import Spectra


def reference_signature_score(maps, signatures, a, b, size, rotation_deg, skew_deg):
    """One harmonic at a time: the signature-weighted peakness at each turned, folded harmonic
    (m a, n b), halved where the pixel grid folds it."""
    total = np.zeros(np.broadcast(a, b).shape)
    for q, sig in zip(maps, signatures):
        weights = np.sqrt(sig.weight) / np.sqrt(sig.weight).sum()
        for m, n, weight in zip(sig.m, sig.n, weights):
            fx, fy = frequencies.turned_frequencies(m * a, n * b, rotation_deg, skew_deg)
            folded = (np.abs(fx) > size / 2) | (np.abs(fy) > size / 2)
            fx, fy = np.broadcast_arrays(frequencies.fold(fx, size), frequencies.fold(fy, size))
            looked_up = lattice._lookup(q, fx.ravel(), fy.ravel(), size).reshape(fx.shape)
            total = total + weight * np.where(folded, 0.5, 1.0) * looked_up
    return total


def reference_comb_scores(freqs, strengths, periods, size, sigma=0.35, reach=1.6):
    """Each peak's strength times its best Gaussian hit over every tooth m * spacing within reach."""
    scores = np.zeros(len(periods))
    for g, period in enumerate(periods):
        teeth = np.abs(frequencies.fold(np.arange(1, int(reach * size / period) + 1) * period, size))
        for f, s in zip(freqs, strengths):
            scores[g] += s * np.exp(-0.5 * ((teeth - abs(f)) / sigma) ** 2).max()
    return scores


@pytest.mark.parametrize("rotation, skew", [(0.0, 0.0), (2.5, 0.0), (-1.0, 3.5)])
def test_signature_score_matches_its_reference(rotation, skew):
    rng = np.random.default_rng(4)
    size = 128
    maps = [rng.random((2 * size, 2 * size)) for _ in range(2)]
    m, n = np.meshgrid(np.arange(-3, 4), np.arange(0, 4))
    keep = (n > 0) | (m > 0)
    signatures = [lattice.Signature(m[keep], n[keep], w / w.sum())
                  for w in (rng.random(int(keep.sum())) for _ in range(2))]
    a = 20.0 * np.exp(np.linspace(-0.5, 1.5, 7))[None, :]   # some harmonics fold past Nyquist
    b = 30.0 * np.exp(np.linspace(-0.3, 0.3, 5))[:, None]
    fast = lattice.signature_score(maps, signatures, a, b, size, rotation, skew)
    assert fast.shape == (5, 7)
    np.testing.assert_allclose(fast, reference_signature_score(maps, signatures, a, b, size, rotation, skew),
                               rtol=1e-12)


def test_a_scan_of_angles_scores_exactly_as_one_call_per_angle():
    """The placement refinement scores one lattice at 31 angles in one call; it must pick the same
    angle as one signature_score per angle, so the numbers must be the same to the last bit (0 included)."""
    rng = np.random.default_rng(5)
    size = 128
    maps = [rng.random((2 * size, 2 * size)) for _ in range(2)]
    m, n = np.meshgrid(np.arange(-3, 4), np.arange(0, 4))
    keep = (n > 0) | (m > 0)
    signatures = [lattice.Signature(m[keep], n[keep], np.full(int(keep.sum()), 1.0 / int(keep.sum())))] * 2
    steps = np.arange(-0.3, 0.3 + 1e-9, 0.02)
    for warp, weft, moves in ((0.0, 0.0, (1, 1)), (1.7, -2.2, (1, 0)), (-4.1, 0.6, (0, 1))):
        placements = [placement_of(warp + moves[0] * d, weft + moves[1] * d) for d in steps] + [(0.0, 0.0)]
        for a, b in ((23.7, 31.2), (61.0, 17.5)):  # the second folds harmonics past Nyquist
            scan = lattice.scores_at_angles(maps, signatures, a, b, size, placements)
            one_by_one = [float(lattice.signature_score(maps, signatures, a, b, size, *p)) for p in placements]
            assert scan.tolist() == one_by_one


def test_comb_scores_match_their_reference():
    rng = np.random.default_rng(9)
    size = 256
    freqs, strengths = rng.uniform(-120, 120, 12), rng.uniform(1, 5, 12)
    periods = np.exp(np.linspace(np.log(6.0), np.log(90.0), 200))
    fast = sieve.comb_scores(freqs, strengths, periods, size, reach=2.5)
    np.testing.assert_allclose(fast, reference_comb_scores(freqs, strengths, periods, size, reach=2.5), rtol=1e-12)
    assert fast.max() > 0.5 * strengths.max()   # something lines up: the check is not all zeros


def reference_peak_coverage(spectra, a, b, rotation_deg, skew_deg):
    """One peak and one harmonic (m, n) at a time: the strength of the peaks (or their mirror images)
    within the tolerance of a turned harmonic folded by the sampling, over the strength of all."""
    size, reach = spectra.size, GATES.coverage_reach * spectra.size / 2
    peaks = [p for image in spectra.peaks for p in image[: GATES.coverage_peaks]]
    explained = 0.0
    for p in peaks:
        tolerance = GATES.coverage_tolerance[0] + GATES.coverage_tolerance[1] * np.hypot(p.fx, p.fy)
        hit = False
        for m in range(-int(reach / a) - 1, int(reach / a) + 2):
            for n in range(-int(reach / b) - 1, int(reach / b) + 2):
                fx, fy = frequencies.turned_frequencies(m * a, n * b, rotation_deg, skew_deg)
                if abs(fx) > reach or abs(fy) > reach:
                    continue
                fx, fy = frequencies.fold(fx, size), frequencies.fold(fy, size)
                hit |= min(np.hypot(fx - p.fx, fy - p.fy), np.hypot(fx + p.fx, fy + p.fy)) <= tolerance
        explained += p.strength * hit
    return explained / sum(p.strength for p in peaks)


@pytest.mark.parametrize("rotation, skew", [(0.0, 0.0), (2.5, 0.0), (-1.0, 3.5)])
def test_peak_coverage_matches_its_reference(rotation, skew):
    rng = np.random.default_rng(11)
    size = 512
    a, b = 37.3, 52.9
    # half the peaks on (turned, folded) harmonics, nudged within the tolerance; half anywhere
    m, n = rng.integers(-9, 10, 10), rng.integers(-7, 8, 10)
    fx, fy = frequencies.turned_frequencies(m * a, n * b, rotation, skew)
    fx, fy = frequencies.fold(fx, size) + rng.normal(0, 1, 10), frequencies.fold(fy, size) + rng.normal(0, 1, 10)
    on = [Peak(float(x), float(y), float(s)) for x, y, s in zip(fx, fy, rng.uniform(3, 8, 10))]
    off = [Peak(float(x), float(y), float(s)) for x, y, s in
           zip(rng.uniform(-250, 250, 10), rng.uniform(0, 250, 10), rng.uniform(3, 8, 10))]
    spectra = Spectra(size, [on[:5] + off[:5], on[5:] + off[5:]], [], [])
    fast = lattice.peak_coverage(spectra, a, b, rotation, skew)
    assert fast == pytest.approx(reference_peak_coverage(spectra, a, b, rotation, skew), abs=1e-12)
    assert 0.4 < fast < 1.0


@pytest.fixture(scope="module")
def turned_satin():
    params = typical("satin0").replace(tiles=(60.0, 30.0))
    pair = render_pair(params, CaptureRig(sample_rotation_deg=2.5), size=512, spp=4, seed=1)
    spectra = Spectra.of([pair.reflection.numpy(), pair.transmission.numpy()])
    return spectra, frequencies.lattice_of(params.tiles, DEFAULT_RIG)


def test_the_true_lattice_makes_the_photos_peaks_and_one_too_fine_does_not(turned_satin):
    spectra, (a, b) = turned_satin
    true = lattice.peak_coverage(spectra, a, b, 2.5)
    assert true > 0.95
    # three or one and a half times too fine on an axis: the harmonics between its own are missed
    for finer in ((a, 3 * b), (3 * a, b), (1.5 * a, b)):
        assert lattice.peak_coverage(spectra, *finer, 2.5) < true - 0.5
    # read unturned, the same lattice misses the higher harmonics
    assert lattice.peak_coverage(spectra, a, b) < true - 0.3
    # one-sided: a lattice twice too coarse has every harmonic of the true one
    assert lattice.peak_coverage(spectra, a / 2, b / 2, 2.5) == true


@pytest.mark.parametrize("combs_cover, reading_cover, joins", [(0.06, 0.26, True), (0.06, 0.05, False),
                                                                (0.8, 0.95, False)])
def test_a_single_peak_reading_joins_without_the_gain_only_where_the_combs_miss_the_peaks(
        monkeypatch, combs_cover, reading_cover, joins):
    """A reading from a single peak that scores above the combs, but under anchor_gain times them,
    joins where the combs make less than low_coverage of the photos' peak strength and it makes
    more; one above the gain always joins."""
    comb = lattice.Lattice(90.0, 50.0, 1.0)
    reading = lattice.Lattice(130.0, 130.0, 1.1)
    strong = lattice.Lattice(60.0, 60.0, 1.3)
    covers = {(comb.a, comb.b): combs_cover, (reading.a, reading.b): reading_cover, (strong.a, strong.b): 0.0}
    monkeypatch.setattr(candidates, "anchored", lambda *args, **kwargs: [reading, strong])
    monkeypatch.setattr(candidates, "_polished", lambda spectra, signatures, starts, *args: [
        next(lat for lat in (reading, strong) if (lat.a, lat.b) == start) for start in starts])
    monkeypatch.setattr(candidates, "peak_coverage", lambda spectra, a, b, *args: covers[a, b])
    found = candidates.with_anchored(None, [comb], [], (1.0, 500.0), (1.0, 500.0), 3, 0.0, 0.0)
    assert found == ([strong, reading, comb] if joins else [strong, comb])
