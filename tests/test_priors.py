"""The fit's prior (backend.core.priors.prior_nll) against its formula and the dataset it stands for."""
import math
import random

import pytest
import torch

from backend.core import priors
from backend.core.priors import MULTIPLE_ROUGHNESS_RATIO, MULTIPLE_ROUGHNESS_SPREAD, prior_nll


def _nll(pattern, height, gap, roughness, multiple):
    return prior_nll(pattern, torch.tensor(height), torch.tensor(gap), torch.tensor(roughness),
                     torch.tensor(multiple))


def test_height_and_gap_terms_are_the_specs_gaussians():
    # twill: height (1, 0.5), gap (0.9, 0.05); the multiple-scattering ratio (1) is inside its range
    value = _nll("twill1", (1.5, 0.5), (0.95, 0.9), (0.6, 0.6), (0.6, 0.6))
    expected = (0.25 + 0.25) / 2 / (2 * 0.25) + (0.0025 + 0.0) / 2 / (2 * 0.0025)
    assert float(value) == pytest.approx(expected, rel=1e-5)


@pytest.mark.parametrize("ratio", [MULTIPLE_ROUGHNESS_RATIO[0] * 1.001, 0.8, 1.0, MULTIPLE_ROUGHNESS_RATIO[1] * 0.999])
def test_a_multiple_scattering_roughness_within_the_datasets_ratio_costs_nothing(ratio):
    at_centre = _nll("satin0", (0.1, 0.1), (0.9, 0.9), (0.5, 0.05), (0.5, 0.05))
    value = _nll("satin0", (0.1, 0.1), (0.9, 0.9), (0.5, 0.05), (0.5 * ratio, 0.05 * ratio))
    assert float(value) == pytest.approx(float(at_centre), abs=1e-7)


def test_outside_the_ratio_the_cost_grows_with_the_log_distance_and_pulls_back():
    spread = MULTIPLE_ROUGHNESS_SPREAD
    lo, hi = MULTIPLE_ROUGHNESS_RATIO
    base = float(_nll("twill1", (1.0, 1.0), (0.9, 0.9), (0.76, 0.5), (0.76, 0.5)))
    # warp alpha_m at the parameter's bound 0.01 under alpha 0.76 (the fit of dev real twill2)
    multiple = torch.tensor((0.01, 0.5), requires_grad=True)
    value = prior_nll("twill1", torch.tensor((1.0, 1.0)), torch.tensor((0.9, 0.9)), torch.tensor((0.76, 0.5)),
                      multiple)
    distance = math.log(lo) - math.log(0.01 / 0.76)
    assert float(value.detach()) - base == pytest.approx(distance ** 2 / 2 / (2 * spread ** 2), rel=1e-4)
    value.backward()
    assert multiple.grad[0] < 0 and multiple.grad[1] == 0  # descending raises the razor-thin lobe only
    above = float(_nll("twill1", (1.0, 1.0), (0.9, 0.9), (0.2, 0.5), (0.2 * hi * 2, 0.5)))
    further = float(_nll("twill1", (1.0, 1.0), (0.9, 0.9), (0.2, 0.5), (0.2 * hi * 4, 0.5)))
    assert base < above < further
    assert above - base == pytest.approx(math.log(2) ** 2 / 2 / (2 * spread ** 2), rel=1e-4)


@pytest.mark.parametrize("pattern", priors.PATTERNS)
def test_every_draw_of_the_dataset_prior_is_within_the_ratio(pattern):
    rng = random.Random(11)
    for _ in range(40):
        p = priors.sample(pattern, rng)
        ratios = [m / r for m, r in zip(p.roughness_multiple, p.roughness)]
        assert all(MULTIPLE_ROUGHNESS_RATIO[0] <= r <= MULTIPLE_ROUGHNESS_RATIO[1] for r in ratios), p
