"""Weave geometry: segments against the spec's figures, tension, per-point layers vs the reference."""
import math
import random

import pytest
import torch
from oracles import reference

from backend.core.weave import (
    BACK,
    FRONT,
    MIRRORED_OF,
    PAPER_PRESETS,
    PRESETS,
    WARP,
    WEFT,
    Weave,
    WeaveError,
    face_twin,
    mirrored,
)
from backend.model.layers import GAP, WeaveLookup


def shapes(weave, yarn, layer):
    """{(width, length)} of the segments of every yarn of a direction in one layer."""
    width = weave.band(yarn)[0]
    count = weave.cols if yarn == WARP else weave.rows
    return {(width, seg.length) for i in range(count) for seg in weave.segments(yarn, i) if seg.layer == layer}


def test_tile_sizes_match_the_spec():
    sizes = {name: (w.tile_width, w.tile_height) for name, w in PRESETS.items()}
    assert sizes == {"plain": (2, 2), "twill0": (4, 8), "twill1": (8, 4), "satin0": (10, 5), "satin1": (5, 10),
                     "twill0m": (4, 8), "twill1m": (8, 4), "satin0m": (10, 5), "satin1m": (5, 10)}
    assert list(PRESETS)[:5] == list(PAPER_PRESETS)  # the shader's pattern index of the paper's five stays


@pytest.mark.parametrize("name", list(MIRRORED_OF))
def test_a_mirrored_preset_is_the_left_right_mirror_image_of_its_paper_preset(name):
    """At (X, Y) the mirrored weave has what its paper preset has at (tile_width - X, Y): the same yarn
    and tension, a warp's across-coordinate and a weft's along-coordinate negated."""
    base, mirror = PRESETS[MIRRORED_OF[name]], PRESETS[name]
    rng = random.Random(3)
    pts = [(rng.uniform(0, base.tile_width), rng.uniform(0, base.tile_height)) for _ in range(500)]
    X = torch.tensor([p[0] for p in pts], dtype=torch.float64)
    Y = torch.tensor([p[1] for p in pts], dtype=torch.float64)
    gap_scale = (0.8, 0.9)
    expected = WeaveLookup(base, dtype=torch.float64).layers(base.tile_width - X, Y, gap_scale)
    got = WeaveLookup(mirror, dtype=torch.float64).layers(X, Y, gap_scale)
    for want, have in zip(expected, got):
        assert torch.equal(want.yarn, have.yarn)
        yarn = want.yarn[want.yarn != GAP]
        sign = torch.where(yarn == WARP, 1.0, -1.0).to(torch.float64)
        assert torch.allclose(have.u[have.yarn != GAP], sign * want.u[want.yarn != GAP], atol=1e-9)
        assert torch.allclose(have.v[have.yarn != GAP], -sign * want.v[want.yarn != GAP], atol=1e-9)
        assert torch.allclose(have.mu, want.mu, atol=1e-9)
    # Mirrored twice is the preset itself; a plain weave has no other handedness.
    assert mirrored(mirror, base.name) == base
    assert "plain" not in MIRRORED_OF.values()


def test_a_face_twin_is_the_weave_turned_over_at_every_crossing():
    """Every crossing turned over (warp over weft <-> weft over warp), up to where the tile starts;
    the diagonal stays, so a twin is never a mirror image."""
    twins = {name: face_twin(w) for name, w in PRESETS.items()}
    assert twins == {"plain": None, "twill0": "twill1m", "twill1": "twill0m", "satin0": "satin1", "satin1": "satin0",
                     "twill0m": "twill1", "twill1m": "twill0", "satin0m": "satin1m", "satin1m": "satin0m"}
    for name, twin in twins.items():
        if twin is None:
            continue
        assert twins[twin] == name
        mine, theirs = PRESETS[name].matrix, PRESETS[twin].matrix
        rows, cols = len(mine), len(mine[0])
        assert any(all(mine[r][c] == 1 - theirs[(r + i) % rows][(c + j) % cols]
                       for r in range(rows) for c in range(cols)) for i in range(rows) for j in range(cols))
    assert face_twin(Weave("custom", ["0011", "0110", "1100", "1001"])) is None   # a 2/2 twill: none of the presets


def test_segment_figures_of_the_spec():
    plain = PRESETS["plain"]
    for yarn in (WARP, WEFT):
        for layer in (FRONT, BACK):
            assert shapes(plain, yarn, layer) == {(1, 1)}
    twill0 = PRESETS["twill0"]
    assert shapes(twill0, WARP, FRONT) == {(1, 6)}
    assert shapes(twill0, WEFT, FRONT) == {(2, 1)}
    assert shapes(twill0, WARP, BACK) == {(1, 2)}
    assert shapes(twill0, WEFT, BACK) == {(2, 3)}
    satin0 = PRESETS["satin0"]
    assert shapes(satin0, WEFT, FRONT) == {(1, 9)}
    assert shapes(satin0, WARP, FRONT) == {(1, 1)}
    assert shapes(satin0, WARP, BACK) == {(1, 4)}
    assert shapes(satin0, WEFT, BACK) == {(1, 1)}
    # twill1 is twill0 transposed (the published map's length-6 back segment is an error: the rule gives 3).
    twill1 = PRESETS["twill1"]
    assert shapes(twill1, WARP, BACK) == {(2, 3)}
    assert shapes(twill1, WEFT, FRONT) == {(1, 6)}


def test_satin0_back_layer_is_a_gap_between_warps():
    lookup = WeaveLookup(PRESETS["satin0"])
    # x in [0, 1) of each pitch of 2 holds no warp: only the weft, which is then the front layer.
    X = torch.tensor([0.5, 2.5, 4.5, 6.5, 8.5], dtype=torch.float64)
    front, back = lookup.layers(X, torch.full_like(X, 2.5), (1.0, 1.0))
    assert (back.yarn == GAP).all()
    assert (front.yarn == WEFT).all()


def test_tension_is_zero_at_longest_and_one_at_shorter_segments():
    twill0 = PRESETS["twill0"]
    warp = twill0.segments(WARP, 0)
    assert {(s.length, s.tension) for s in warp} == {(6.0, 0.0), (2.0, 1.0)}
    plain = PRESETS["plain"]
    assert all(s.tension == 0.0 for i in range(2) for s in plain.segments(WARP, i))


def test_tension_is_linear_between_segment_centres():
    weave = PRESETS["twill0"]
    lookup = WeaveLookup(weave, dtype=torch.float64)
    # Warp 0: back segment [0, 2) (centre 1, mu 1), front [2, 8) (centre 5, mu 0); along-coordinate = Y.
    Y = torch.tensor([1.0, 2.0, 3.0, 5.0, 7.0], dtype=torch.float64)
    warp = lookup._yarn(WARP, torch.zeros(5, dtype=torch.long), torch.floor(Y / 2).long(),
                        torch.ones(5, dtype=torch.bool), Y, torch.zeros_like(Y), weave.tile_height)
    assert warp["mu"].tolist() == pytest.approx([1.0, 0.75, 0.5, 0.0, 0.5])


@pytest.mark.parametrize("name", list(PRESETS))
def test_layer_lookup_matches_the_reference_walk(name):
    weave = PRESETS[name]
    lookup = WeaveLookup(weave, dtype=torch.float64)
    rng = random.Random(1)
    gap_scale = (0.8, 0.9)
    pts = [(rng.uniform(0, weave.tile_width), rng.uniform(0, weave.tile_height)) for _ in range(400)]
    X = torch.tensor([p[0] for p in pts], dtype=torch.float64)
    Y = torch.tensor([p[1] for p in pts], dtype=torch.float64)
    front, back = lookup.layers(X, Y, gap_scale)
    for k, (x, y) in enumerate(pts):
        ref_front, ref_back = reference.point_layers(weave, x, y, gap_scale)
        for fast, ref in ((front, ref_front), (back, ref_back)):
            assert int(fast.yarn[k]) == ref.yarn, (x, y)
            if ref.yarn != GAP:
                assert float(fast.u[k]) == pytest.approx(ref.u, abs=1e-9)
                assert float(fast.v[k]) == pytest.approx(ref.v, abs=1e-9)
                assert float(fast.mu[k]) == pytest.approx(ref.mu, abs=1e-9)


def test_custom_matrix_and_band_layout():
    basket = Weave("basket", ["1100", "1100", "0011", "0011"])
    assert (basket.rows, basket.cols) == (4, 4)
    # A warp of the basket weave floats over two wefts then under two.
    assert sorted((s.length, s.layer) for s in basket.segments(WARP, 0)) == [(2.0, FRONT), (2.0, BACK)]
    spaced = Weave("spaced", ((0, 1), (1, 0)), warp_width=0.6, warp_pitch=1.0, warp_offset=0.2)
    # Open stretches along the weft split its back segments and belong to the front layer.
    weft = spaced.segments(WEFT, 0)
    assert sorted((round(s.length, 9), s.layer) for s in weft) == [(0.6, BACK), (1.4, FRONT)]


def test_a_yarn_that_never_goes_under_is_one_segment():
    weave = Weave("custom", ["11", "10"])
    assert [(s.length, s.layer) for s in weave.segments(WARP, 0)] == [(2.0, FRONT)]
    lookup = WeaveLookup(weave)
    front, _ = lookup.layers(torch.tensor([0.5]), torch.tensor([1.5]), (1.0, 1.0))
    assert torch.isfinite(front.u).all() and torch.isfinite(front.mu).all()


@pytest.mark.parametrize("kwargs,needle", [
    (dict(matrix=((0, 2), (1, 0))), "only 0 and 1"),
    (dict(matrix=((0, 1), (1,))), "same non-zero length"),
    (dict(matrix=((0, 1), (1, 0)), warp_width=2.0), "width <= pitch"),
    (dict(matrix=((0, 1), (1, 0)), weft_offset=0.5), "offset"),
    (dict(matrix=((0, 1), (1, 0)), umax_deg=(95.0, 10.0)), "umax_deg"),
])
def test_malformed_weaves_are_refused(kwargs, needle):
    with pytest.raises(WeaveError, match=needle):
        Weave("bad", **kwargs)


def test_flat_segments_use_the_vertical_frame():
    # A segment shorter than width * sin(umax) cannot bend: n = o = z.
    weave = Weave("short", ((0, 1), (1, 0)), weft_width=0.1, weft_pitch=0.1, umax_deg=(80.0, 10.0))
    # Row 1, column 0: the warp lies on top there (P[1][0] = 1); its segments are 0.1 long.
    front, _ = WeaveLookup(weave).layers(torch.tensor([0.5]), torch.tensor([0.15]), (1.0, 1.0))
    assert int(front.yarn[0]) == WARP and bool(front.flat[0])
    assert math.isclose(weave.warp_width * math.sin(math.radians(80.0)), 0.9848, rel_tol=1e-3)
