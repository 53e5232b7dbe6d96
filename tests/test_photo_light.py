"""The photos' light falloff (backend/model/photo_light.py): the solve, its use in the fit's loss and
in what a fit writes."""
import json

import pytest
import torch

from backend.core import priors
from backend.core.rig import DEFAULT_RIG
from backend.fit.objective import Objective, Target
from backend.model.param_tensors import ParamTensors
from backend.model.photo_light import LIMIT, PhotoLight, basis, linear_photo, solve
from backend.model.render import Renderer
from backend.texture.features import luminance

TWILL = priors.typical("twill0")
LIT = PhotoLight((0.12, -0.08, 0.1), (-0.05, 0.03, -0.15))


@pytest.fixture(scope="module")
def renderer():
    return Renderer(DEFAULT_RIG, 128, 4, seed=5)


@pytest.fixture(scope="module")
def radiance(renderer):
    with torch.no_grad():
        return renderer.blurred(TWILL)


def _solved(renderer, radiance, photos):
    out = []
    for rad, photo in zip(radiance, photos):
        linear, ok = linear_photo(photo, DEFAULT_RIG.gamma, renderer.vignette)
        out.append(solve(luminance(rad), (rad < DEFAULT_RIG.clamp).all(dim=-1), luminance(linear), ok))
    return out


def test_the_basis_has_zero_mean_so_the_level_stays_with_the_albedos():
    assert basis(64, torch.float64).mean(dim=(1, 2)).abs().max() < 1e-12
    gain = LIT.gain(0, 64, torch.float64)
    assert torch.log(gain).mean().abs() < 1e-12


def test_the_solve_recovers_a_known_falloff(renderer, radiance):
    photos = renderer.display(*radiance, LIT)
    solved = _solved(renderer, radiance, (photos.reflection, photos.transmission))
    assert solved[0] == pytest.approx(LIT.reflection, abs=2e-3)
    assert solved[1] == pytest.approx(LIT.transmission, abs=2e-3)
    flat = renderer.display(*radiance)
    assert _solved(renderer, radiance, (flat.reflection, flat.transmission))[0] == pytest.approx((0, 0, 0), abs=1e-6)


def test_clipped_blocks_are_left_out_and_the_gain_is_bounded(renderer, radiance):
    r, t = radiance
    bright = r.clone()
    bright[:40, :40] *= 50  # a clipped highlight in a corner: its blocks say nothing about the falloff
    photos = renderer.display(bright, t, LIT)
    solved = _solved(renderer, (r, t), (photos.reflection, photos.transmission))
    assert solved[0] == pytest.approx(LIT.reflection, abs=2e-3)
    steep = renderer.display(r, t, PhotoLight((3.0, 0.0, 0.0)))
    assert _solved(renderer, radiance, (steep.reflection, steep.transmission))[0][0] == pytest.approx(LIMIT)


def test_a_photo_falloff_leaves_the_loss_at_the_truth_where_it_was(renderer, radiance):
    """The loss of the true parameters against photos under an uneven light equals their loss
    against evenly lit photos; without the solve, the uneven light costs the truth."""
    with torch.no_grad():
        even, uneven = renderer.display(*radiance), renderer.display(*radiance, LIT)

    def loss(photos, fit_light):
        target = Target(photos.reflection, photos.transmission)
        objective = Objective(target, Renderer(DEFAULT_RIG, 128, 4, seed=5), DEFAULT_RIG, fit_light=fit_light)
        with torch.no_grad():
            return float(objective(ParamTensors.from_params(TWILL)))

    assert loss(uneven, True) == pytest.approx(loss(even, True), abs=2e-3)
    assert loss(uneven, False) > loss(even, False) + 0.02


def test_round_trip_and_flat_identity(radiance):
    assert PhotoLight.from_dict(json.loads(json.dumps(LIT.to_dict()))) == LIT
    assert PhotoLight.from_dict(None).flat
    r, t = radiance
    same = PhotoLight().apply(r, t)
    assert same[0] is r and same[1] is t
