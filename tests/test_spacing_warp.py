"""The photos' uneven yarn spacing: the warp's B-splines (backend/model/spacing_warp.py), renders that
show it, and its reading from the phase of the lattice harmonics (backend/texture/uneven_spacing.py)."""
import math

import numpy as np
import pytest
import torch

from backend.core.params import FabricParams
from backend.core.rig import DEFAULT_RIG
from backend.fit import optimise
from backend.fit.objective import Objective, Target
from backend.fit.optimise import Run
from backend.fit.settings import FitSettings
from backend.fit.warp import reread
from backend.image.spectrum import highpassed_luminance
from backend.model.render import Renderer, render_pair
from backend.model.spacing_warp import (
    GRID,
    SpacingWarp,
    affine_part,
    bspline_basis,
    control_abscissae,
    grid_centres,
    non_affine,
)
from backend.texture.lattice import Signature, turned_frequencies
from backend.texture.uneven_spacing import INTERVALS, WarpReading, read_warp

SIZE = 512
SIDE = INTERVALS + 3
LATTICE = (40.0, 55.0)      # cycles per image
TURN = 2.0                  # degrees
HARMONICS = Signature(m=np.array([1, 0, 1, 2]), n=np.array([0, 1, 1, 1]), weight=np.array([0.3, 0.3, 0.2, 0.2]))
PLAIN = FabricParams.from_interchange(
    "plain_R_0.3,0.3_S_1.0,1.0_T_1.5,1.5_N_0.0_UV_40.0,40.0_Kd_0.3,0.2,0.1,0.2,0.15,0.1"
    "_G_0.8,0.8_Rm_0.3,0.3_Tm_1.5,1.5_W_0.5,1.0_Ks_0.6,0.4,0.3,0.6,0.4,0.3_Psi_0.0,0.0")


def smooth_warp(x, y):
    """A warp that is not affine: displacements of up to about 0.9 px, periods of 200-300 px."""
    return (0.7 * np.sin(2 * math.pi * x / 260 + 0.4) + 0.2 * np.cos(2 * math.pi * y / 300),
            0.6 * np.sin(2 * math.pi * y / 210 + 1.1) - 0.2 * np.sin(2 * math.pi * x / 240))


def field(warp):
    """The warp's (dx, dy) on the comparison grid of the film (zeros for None)."""
    return (np.zeros((GRID, GRID)),) * 2 if warp is None else warp.sampled(SIZE)


def truth_of(warp_fn, scale=1.0):
    """``warp_fn``'s non-affine part on the comparison grid."""
    x, y = np.meshgrid(grid_centres(SIZE), grid_centres(SIZE), indexing="xy")
    return [scale * non_affine(d, SIZE) for d in warp_fn(x, y)]


def rms(dx, dy):
    return float(np.sqrt(np.mean(dx ** 2 + dy ** 2)))


def woven(warp=None, drift=0.0) -> np.ndarray:
    """A grey (SIZE, SIZE, 3) image of HARMONICS of the lattice LATTICE turned by TURN, its weave seen at
    p + warp(p), each harmonic's phase drifting by ``drift`` m radians across the image (the light's
    own drift, as a highlight's place on a yarn follows the half vector)."""
    centres = np.arange(SIZE) + 0.5
    y, x = np.meshgrid(centres, centres, indexing="ij")
    dx, dy = (0.0, 0.0) if warp is None else warp(x, y)
    image = np.full((SIZE, SIZE), 0.5)
    for m, n, w in zip(HARMONICS.m, HARMONICS.n, HARMONICS.weight):
        fx, fy = turned_frequencies(m * LATTICE[0], n * LATTICE[1], TURN)
        phase = 2 * math.pi * (fx * (x + dx) + fy * (y + dy)) / SIZE + drift * m * (x / SIZE) ** 2
        image += 0.25 * w * np.cos(phase + 0.7 * m + 0.3 * n)
    return np.repeat(image[..., None], 3, axis=-1)


def read(photo, render):
    reading = WarpReading(highpassed_luminance(photo, SIZE / 64), highpassed_luminance(render, SIZE / 64), HARMONICS)
    return read_warp([reading], *LATTICE, TURN, 0.0, SIZE)


def test_the_control_values_of_an_affine_warp_are_its_values_at_the_control_abscissae():
    at = control_abscissae(SIZE, INTERVALS)
    warp = SpacingWarp.from_grids(0.3 + 0.002 * at[None, :] - 0.001 * at[:, None], np.full((SIDE, SIDE), -0.25))
    x, y = torch.meshgrid(torch.linspace(0.0, SIZE, 37, dtype=torch.float64),
                          torch.linspace(0.0, SIZE, 41, dtype=torch.float64), indexing="xy")
    dx, dy = warp.displacement(x, y, SIZE)
    assert torch.allclose(dx, 0.3 + 0.002 * x - 0.001 * y, atol=1e-12)
    assert torch.allclose(dy, torch.full_like(dy, -0.25), atol=1e-12)


def test_the_displacement_is_the_sum_of_the_basis_functions_times_the_control_values():
    """The fast path (one flattened index per term) against the dense bases of each axis: at random
    points, on the film's edges and off the film (clamped onto it), of any shape."""
    rng = np.random.default_rng(3)
    warp = SpacingWarp.from_grids(rng.normal(size=(SIDE, SIDE)), rng.normal(size=(SIDE, SIDE)))
    x = np.concatenate((rng.uniform(0.0, SIZE, 500), [0.0, SIZE, -3.0, SIZE + 2.0, 0.0]))
    y = np.concatenate((rng.uniform(0.0, SIZE, 500), [SIZE, 0.0, 7.0, -1.0, SIZE - 1e-12]))
    bx, by = bspline_basis(x, SIZE, INTERVALS), bspline_basis(y, SIZE, INTERVALS)
    dx, dy = warp.displacement(torch.tensor(x).view(5, 101), torch.tensor(y).view(5, 101), SIZE)
    for fast, grid in ((dx, warp.dx), (dy, warp.dy)):
        assert fast.shape == (5, 101)
        assert np.allclose(fast.numpy().ravel(), ((by @ np.asarray(grid)) * bx).sum(1), rtol=0, atol=1e-12)


def test_the_basis_slopes_are_the_derivatives_of_the_basis():
    coords = np.linspace(1.0, SIZE - 1.0, 301)
    step = 1e-4
    numeric = (bspline_basis(coords + step, SIZE, INTERVALS) - bspline_basis(coords - step, SIZE, INTERVALS))
    numeric /= 2 * step
    assert np.allclose(bspline_basis(coords, SIZE, INTERVALS, derivative=True), numeric, atol=1e-6)


def test_a_warp_of_one_whole_tile_renders_the_same_fabric_and_half_a_tile_does_not():
    size = 64
    period = DEFAULT_RIG.film_size / (PLAIN.tiles[0] * DEFAULT_RIG.view_size / DEFAULT_RIG.plane_size)  # film px

    def render(shift):
        warp = None if shift is None else SpacingWarp.from_grids(np.full((SIDE, SIDE), shift), np.zeros((SIDE, SIDE)))
        with torch.no_grad():
            return Renderer(DEFAULT_RIG, size, 4, seed=2, warp=warp).render(PLAIN).reflection

    even = render(None)
    whole, half = render(period), render(period / 2)
    assert float((whole - even).abs().mean()) < 1e-3 * float(even.mean())
    assert float((half - even).abs().mean()) > 0.05 * float(even.mean())


def test_a_renderer_shows_a_new_warp_once_it_is_set():
    warp = SpacingWarp.from_grids(np.full((SIDE, SIDE), 3.0), np.zeros((SIDE, SIDE)))
    renderer = Renderer(DEFAULT_RIG, 64, 4, seed=2)
    with torch.no_grad():
        even = renderer.render(PLAIN).reflection
        renderer.set_warp(warp)
        moved = renderer.render(PLAIN).reflection
        fresh = Renderer(DEFAULT_RIG, 64, 4, seed=2, warp=warp).render(PLAIN).reflection
        renderer.set_warp(None)
        back = renderer.render(PLAIN).reflection
    assert renderer.warp is None
    assert torch.equal(moved, fresh) and torch.equal(back, even)
    assert not torch.equal(moved, even)


def test_the_warp_is_read_from_the_harmonics_phase():
    found = read(woven(smooth_warp), woven()).warp
    truth = truth_of(smooth_warp)
    assert rms(*truth) > 0.4
    assert rms(*(t - f for t, f in zip(truth, field(found)))) < 0.15 * rms(*truth)
    assert found.rms_px(SIZE) == pytest.approx(rms(*truth), rel=0.15)


def test_only_what_the_render_does_not_show_is_read():
    # The photo's harmonics drift with the light by up to a third of a cycle; a render that drifts alike
    # leaves only the warp, and a photo with no warp beside it reads none.
    found = read(woven(smooth_warp, drift=2.0), woven(drift=2.0)).warp
    assert rms(*(a - b for a, b in zip(field(found), field(read(woven(smooth_warp), woven()).warp)))) < 0.05
    assert read(woven(drift=2.0), woven(drift=2.0)) is None
    assert read(woven(drift=2.0), woven()) is not None   # the drift alone would read as a warp


def other_warp(x, y):
    """A warp of another shape than :func:`smooth_warp` (about as strong)."""
    return 0.7 * np.cos(2 * math.pi * y / 230 + 0.2), 0.6 * np.cos(2 * math.pi * x / 280 + 2.0)


def test_a_warp_both_photos_show_alike_is_the_samples_and_one_only_is_not():
    def reading(warp_fn):
        return WarpReading(highpassed_luminance(woven(warp_fn), SIZE / 64), highpassed_luminance(woven(), SIZE / 64),
                           HARMONICS)

    alike = [reading(smooth_warp), reading(smooth_warp)]
    assert read_warp(alike, *LATTICE, TURN, 0.0, SIZE, agreeing=True) is not None
    unlike = [reading(smooth_warp), reading(other_warp)]
    assert read_warp(unlike, *LATTICE, TURN, 0.0, SIZE) is not None  # read from both at once: a compromise
    assert read_warp(unlike, *LATTICE, TURN, 0.0, SIZE, agreeing=True) is None
    blank = WarpReading(np.zeros((SIZE, SIZE)), np.zeros((SIZE, SIZE)), HARMONICS)  # shows no harmonic
    assert read_warp([reading(smooth_warp), blank], *LATTICE, TURN, 0.0, SIZE) is not None
    assert read_warp([reading(smooth_warp), blank], *LATTICE, TURN, 0.0, SIZE, agreeing=True) is None


def test_the_lattice_stretched_over_the_photo_is_read_as_the_tiles_and_not_as_the_warp():
    # the weave 0.8 % denser across the image than the render's (d = 0.008 (x - N / 2)) on top of
    # smooth_warp, whose own affine part (least squares over the film) is the lattice's too: the
    # yarn frequencies u (turned 2 degrees from the x axis) and v shown as (I + J)^T u and (I + J)^T v
    def stretched(x, y):
        dx, dy = smooth_warp(x, y)
        return dx + 0.008 * (x - SIZE / 2), dy

    x, y = np.meshgrid(grid_centres(SIZE), grid_centres(SIZE), indexing="xy")
    shown = np.eye(2) + np.array([affine_part(d, SIZE)[1:] for d in stretched(x, y)]).T
    u, v = (np.array(turned_frequencies(*f, TURN)) for f in ((1.0, 0.0), (0.0, 1.0)))
    expected = (float(np.linalg.norm(shown @ u)) - 1, float(np.linalg.norm(shown @ v)) - 1)
    assert expected[0] == pytest.approx(0.0067, abs=1e-4)   # smooth_warp's own: -0.0013
    found = read(woven(stretched), woven())
    assert found.stretch == pytest.approx(expected, abs=2e-4)
    assert rms(*(a - b for a, b in zip(field(found.warp), field(read(woven(smooth_warp), woven()).warp)))) < 0.05
    even = read(woven(lambda x, y: (0.008 * (x - SIZE / 2), 0.0 * y)), woven())   # the stretch alone
    assert even.warp is None and even.stretch[0] == pytest.approx(0.008 * math.cos(math.radians(TURN)) ** 2, abs=2e-4)
    # a stretch beyond what the mean spacing can miss is not the lattice's
    assert read(woven(lambda x, y: (0.05 * (x - SIZE / 2), 0.0 * y)), woven()) is None


def test_an_even_lattice_and_a_blank_photo_read_no_warp():
    assert read(woven(), woven()) is None
    blank = np.full((SIZE, SIZE, 3), 0.5)
    assert read(blank, blank) is None


def grids_of(warp_fn):
    """Control displacements fitted (least squares) to ``warp_fn``'s non-affine part over the film."""
    pinv = np.linalg.pinv(bspline_basis(grid_centres(SIZE), SIZE, INTERVALS))
    return [pinv @ d @ pinv.T for d in truth_of(warp_fn)]


@pytest.fixture(scope="module")
def warped_photos():
    """The plain fabric's pair rendered with the yarns spaced by :func:`smooth_warp` (2.5 x as strong)."""
    true = SpacingWarp.from_grids(*(2.5 * c for c in grids_of(smooth_warp)))
    pair = render_pair(PLAIN, size=SIZE, spp=4, seed=3, warp=true)
    return true, pair.reflection.numpy(), pair.transmission.numpy()


def plain_run(photos, size, params=PLAIN):
    objective = Objective(Target.from_arrays(*photos, size=size), Renderer(DEFAULT_RIG, size, 4, compile=False),
                          DEFAULT_RIG)
    run = Run(params, objective, FitSettings(compile=False), 10, 0.0)
    run.step()
    return run


def test_the_fit_reads_the_warp_its_renders_lack(warped_photos):
    true, *photos = warped_photos
    run = plain_run(photos, SIZE)
    found, tiles = reread(run.objective, PLAIN, 0.0)
    assert rms(*(a - b for a, b in zip(field(found), field(true)))) < 0.25 * true.rms_px(SIZE)
    assert tiles == PLAIN.tiles  # the photos' lattice is the render's: no stretch


def test_the_fit_reads_tiles_its_renders_space_otherwise(warped_photos):
    # a run whose tiles are 1.2 % off the photos' (as the placement's mean spacing can be): the photos
    # against its render read them back within 0.2 %
    true, *photos = warped_photos
    off = PLAIN.replace(tiles=tuple(1.012 * t for t in PLAIN.tiles))
    objective = Objective(Target.from_arrays(*photos, size=SIZE), Renderer(DEFAULT_RIG, SIZE, 4, compile=False),
                          DEFAULT_RIG)
    found, tiles = reread(objective, off, 0.0)
    assert tiles == pytest.approx(PLAIN.tiles, rel=2e-3)
    assert rms(*(a - b for a, b in zip(field(found), field(true)))) < 0.25 * true.rms_px(SIZE)


def test_a_run_keeps_a_warp_only_where_its_trial_lowers_the_loss(warped_photos, monkeypatch):
    true, *photos = warped_photos
    monkeypatch.setattr(optimise, "reread", lambda *args: (true, PLAIN.tiles))
    even_pair = render_pair(PLAIN, size=SIZE, spp=4, seed=3)
    for shown, pair in ((False, (even_pair.reflection.numpy(), even_pair.transmission.numpy())), (True, photos)):
        run = plain_run(pair, 256)
        before = run.best_loss, run.best, run.optimiser.state_dict()["state"][0]["exp_avg"].clone()
        run.update_warp()
        assert run.objective.renderer.warp is true  # on trial
        for _ in range(run.settings.warp_trial_steps):
            run.step()
        if shown:  # the photos show it: kept, and the best loss is the loss under it
            assert run.objective.renderer.warp is true
            assert run.best_loss < 0.5 * before[0]
        else:      # evenly spaced photos: it made the renders worse, and the run is back where it was
            assert run.objective.renderer.warp is None
            assert (run.best_loss, run.best) == before[:2]
            assert torch.equal(run.optimiser.state_dict()["state"][0]["exp_avg"], before[2])


def test_a_run_takes_the_stretched_tiles_only_where_they_lower_the_loss_at_once(warped_photos, monkeypatch):
    true, *photos = warped_photos
    off = PLAIN.replace(tiles=tuple(1.012 * t for t in PLAIN.tiles))
    run = plain_run(photos, 256, off)
    run.update_warp()   # read: the photos' tiles, and the loss is lower there
    assert run.fabric.scalar("tiles") == pytest.approx(PLAIN.tiles, rel=2e-3)
    assert run.objective.renderer.warp is not None
    # a stretch read wrong (the run is at the photos' tiles): the warp goes on trial, the tiles stay
    monkeypatch.setattr(optimise, "reread", lambda *args: (true, tuple(1.01 * t for t in PLAIN.tiles)))
    run = plain_run(photos, 256)
    run.update_warp()
    assert run.objective.renderer.warp is true
    assert run.fabric.scalar("tiles") == pytest.approx(PLAIN.tiles, rel=1e-6)
