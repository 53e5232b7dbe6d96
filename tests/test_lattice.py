"""The lattice search's scores (backend.texture.lattice) against slow references written from their
definitions: the fast paths evaluate every harmonic, tooth and lattice at once."""
import numpy as np
import pytest

from backend.core.rig import placement_of
from backend.texture import lattice


def reference_signature_score(maps, signatures, a, b, size, rotation_deg, skew_deg):
    """One harmonic at a time: the signature-weighted peakness at each turned, folded harmonic
    (m a, n b), halved where the pixel grid folds it."""
    total = np.zeros(np.broadcast(a, b).shape)
    for q, sig in zip(maps, signatures):
        weights = np.sqrt(sig.weight) / np.sqrt(sig.weight).sum()
        for m, n, weight in zip(sig.m, sig.n, weights):
            fx, fy = lattice.turned_frequencies(m * a, n * b, rotation_deg, skew_deg)
            folded = (np.abs(fx) > size / 2) | (np.abs(fy) > size / 2)
            fx, fy = np.broadcast_arrays(lattice.fold(fx, size), lattice.fold(fy, size))
            looked_up = lattice._lookup(q, fx.ravel(), fy.ravel(), size).reshape(fx.shape)
            total = total + weight * np.where(folded, 0.5, 1.0) * looked_up
    return total


def reference_comb_scores(freqs, strengths, periods, size, sigma=0.35, reach=1.6):
    """Each peak's strength times its best Gaussian hit over every tooth m * spacing within reach."""
    scores = np.zeros(len(periods))
    for g, period in enumerate(periods):
        teeth = np.abs(lattice.fold(np.arange(1, int(reach * size / period) + 1) * period, size))
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
    fast = lattice.comb_scores(freqs, strengths, periods, size, reach=2.5)
    np.testing.assert_allclose(fast, reference_comb_scores(freqs, strengths, periods, size, reach=2.5), rtol=1e-12)
    assert fast.max() > 0.5 * strengths.max()   # something lines up: the check is not all zeros
