"""The yarn variation read from the texture power a regular weave leaves unexplained
(backend.fit.variation_estimate), and the noise-free cross-power it reads renders by."""
import itertools
import math

import numpy as np
import pytest

from backend.core.params import SPECS, FabricParams
from backend.core.rig import DEFAULT_RIG
from backend.core.variation import KINDS, amplitude_name, length_name
from backend.fit.pipeline import _objective
from backend.fit.settings import FitSettings
from backend.fit.variation_estimate import (
    MIN_GAIN_DB,
    READINGS,
    bounded_least_squares,
    estimate_variation,
    read_length,
    with_amplitudes,
    with_scaled_variation,
)
from backend.image.metrics import band_power, power_db, texture_gap_db
from backend.model.render import render_pair

TWILL = FabricParams.from_interchange(
    "twill1_R_0.72,0.55_S_1.3,1.6_T_2.4,2.9_N_0.0_UV_92.0,131.0_Kd_0.32,0.18,0.11,0.26,0.14,0.08"
    "_G_0.88,0.9_Rm_0.7,0.45_Tm_2.2,2.6_W_0.6,0.9_Ks_0.62,0.38,0.25,0.55,0.33,0.22_Psi_-30.0,-30.0")
SIZE = 128


def _texture(seed: int, noise: float) -> tuple[np.ndarray, np.ndarray]:
    """A 256-px grey image of smooth random texture, and the same with white noise of ``noise``."""
    rng = np.random.default_rng(seed)
    field = np.fft.ifft2(np.fft.fft2(rng.normal(size=(256, 256))) / (0.02 + np.hypot(
        *np.meshgrid(np.fft.fftfreq(256), np.fft.fftfreq(256))))).real
    clean = 0.5 + 0.05 * field / field.std()
    noisy = clean + noise * rng.normal(size=clean.shape)
    return np.repeat(clean[..., None], 3, axis=2), np.repeat(noisy[..., None], 3, axis=2)


def test_the_cross_power_of_two_noisy_copies_reads_the_power_without_the_noise():
    """White noise adds to every band's power; the cross-power of two copies with independent noise
    does not: within 0.5 dB where the noise adds 3 dB or more."""
    clean, noisy = _texture(1, 0.04)
    other = clean + 0.04 * np.random.default_rng(5).normal(size=clean.shape[:2])[..., None]
    truth, plain, cross = band_power(clean), band_power(noisy), band_power(noisy, other)
    assert (power_db(plain) - power_db(truth) > 3.0).any()          # the noise shows in the plain power
    assert np.abs(power_db(cross) - power_db(truth)).max() < 0.5


def test_the_texture_gap_is_zero_for_an_image_and_ten_db_for_a_tenth_of_its_power():
    clean, _ = _texture(2, 0.0)
    damped = 0.5 + (clean - 0.5) / np.sqrt(10.0)
    assert texture_gap_db(clean, clean) == 0.0
    assert texture_gap_db(clean, damped) == pytest.approx(10.0, abs=0.05)


def test_a_small_image_has_a_gap_over_the_bands_it_holds():
    """A 64-px image holds three of the four bands (the last is past its Nyquist corner): the gap is
    their mean, a number (metrics.json and the protocol refuse NaN)."""
    clean, _ = _texture(3, 0.0)
    small = clean[::4, ::4]
    assert np.isnan(band_power(small)[-1]) and np.isfinite(band_power(small)[:-1]).all()
    assert texture_gap_db(small, 0.5 + (small - 0.5) / np.sqrt(10.0)) == pytest.approx(10.0, abs=0.05)


def test_bounded_least_squares_is_the_best_point_of_the_box():
    """Against a dense grid of the box: no grid point has a lower residual, and bounds hold."""
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(8, 3)), rng.normal(size=8) * 3
    upper = np.array([0.5, 2.0, 1.0])
    x = bounded_least_squares(a, b, upper)
    assert (x >= 0).all() and (x <= upper).all()
    cost = np.sum((a @ x - b) ** 2)
    grid = itertools.product(*(np.linspace(0, u, 21) for u in upper))
    assert all(np.sum((a @ np.array(g) - b) ** 2) >= cost - 1e-9 for g in grid)
    free = np.linalg.lstsq(a, b, rcond=None)[0]
    if (free >= 0).all() and (free <= upper).all():  # inside the box: the free solution
        assert x == pytest.approx(free)


@pytest.fixture(scope="module")
def objective_for():
    def make(params: FabricParams):
        photos = render_pair(params, size=SIZE, spp=16, seed=3)
        settings = FitSettings(pattern=params.pattern, size=SIZE, spp=4, compile=False)
        return _objective(photos.reflection.numpy(), photos.transmission.numpy(), DEFAULT_RIG, settings)
    return make


def test_photos_of_a_varied_fabric_read_their_variation_and_the_gap_closes(objective_for):
    """Photos of TWILL with thickness and brightness variation at the reading's lengths, read at the
    regular TWILL: the variation is kept, the gap closes to a third or less, and the power read (the
    sum of the squared amplitudes) is the power shown within a factor of 1.5. Which kind holds it is
    not told apart reliably: the kinds' band profiles are alike (the note of issue 88 says so)."""
    shown = {"thickness": 0.2, "brightness": 0.15}
    objective = objective_for(with_amplitudes(TWILL, shown, {k: read_length(k) for k in shown}))
    varied, reading = estimate_variation(TWILL, objective, blur=0.0)
    assert reading.kept and reading.gap_after_db < reading.gap_before_db / 3
    read = sum(a * a for a in reading.amplitudes.values())
    assert 1 / 1.5 < read / sum(a * a for a in shown.values()) < 1.5
    assert all(getattr(varied, amplitude_name(k)) == (a, a) for k, a in reading.amplitudes.items())
    assert all(getattr(varied, length_name(k)) == (read_length(k),) * 2 for k, a in reading.amplitudes.items() if a)
    assert reading.lengths == {k: read_length(k) for k, a in reading.amplitudes.items() if a}


def test_the_reading_lengths_are_the_centres_of_their_priors():
    assert read_length("width") == pytest.approx(math.sqrt(SPECS["width_variation_length"].prior[0]
                                                           * SPECS["width_variation_length"].prior[1]))
    assert all(SPECS[length_name(k)].prior[0] < read_length(k) < SPECS[length_name(k)].prior[1] for k in KINDS)


@pytest.mark.parametrize("length", [1.0, 8.0])
def test_a_variation_at_either_end_of_its_prior_is_read_within_half_again(objective_for, length):
    """Photos whose variation drifts over 1 or 8 yarns (the ends of the lengths' prior), read at the
    centre: the power read is still the power shown within a factor of 1.5, and the gap more than
    halves (a reading at one end misreads the other: the reason for the centre)."""
    shown = {"thickness": 0.2, "brightness": 0.15}
    objective = objective_for(with_amplitudes(TWILL, shown, {k: length for k in shown}))
    _, reading = estimate_variation(TWILL, objective, blur=0.0)
    assert reading.kept and reading.gap_after_db < reading.gap_before_db / 2
    assert 1 / 1.5 < sum(a * a for a in reading.amplitudes.values()) / sum(a * a for a in shown.values()) < 1.5


def test_photos_of_a_regular_fabric_keep_it_regular(objective_for):
    """Photos of the regular TWILL: nothing to explain, so no variation is kept (the gap at the
    truth is already within MIN_GAIN_DB of what any variation gives), and the parameters come back
    regular whatever was read."""
    objective = objective_for(TWILL)
    varied, reading = estimate_variation(with_amplitudes(TWILL, {"width": 0.2}), objective, blur=0.0)
    assert not reading.kept or reading.gap_before_db - reading.gap_after_db >= MIN_GAIN_DB
    if not reading.kept:
        assert all(getattr(varied, amplitude_name(k)) == (0.0, 0.0) for k in KINDS)


def test_the_estimate_reports_each_reading(objective_for):
    seen = []
    estimate_variation(TWILL, objective_for(TWILL), blur=0.0, progress=seen.append)
    assert seen == list(range(1, READINGS + 1)) and READINGS == len(KINDS) + 2


@pytest.mark.parametrize("darker", [False, True])
def test_a_variation_that_costs_the_fabric_its_colour_is_dropped(monkeypatch, darker):
    """The fit's variation stage with a reading that (darker) halves every albedo: after settling its
    colour terms stay far above the regular weave's, so the fit keeps the regular weave and says why;
    a reading that leaves the colour alone is kept."""
    import backend.fit.pipeline as pipeline
    from backend.fit.variation_estimate import VariationEstimate

    def reading(params, objective, blur, seed, progress):
        varied = with_amplitudes(params, {"brightness": 0.05})
        if darker:
            varied = varied.replace(specular_albedo=tuple(tuple(c / 2 for c in y) for y in params.specular_albedo),
                                    diffuse_reflection=tuple(c / 2 for c in params.diffuse_reflection),
                                    diffuse_transmission=tuple(c / 2 for c in params.diffuse_transmission))
        return varied, VariationEstimate({k: 0.05 * (k == "brightness") for k in KINDS}, 10.0, 5.0, True)

    monkeypatch.setattr(pipeline, "estimate_variation", reading)
    photos = render_pair(TWILL, size=64, spp=8, seed=3)
    settings = FitSettings(pattern="twill1", iterations=2, trial_iterations=1, size=64, spp=4, search_every=0,
                           compile=False, camera_blur=0.0, sample_rotation=0.0, settle_steps=2)
    result = pipeline.fit(photos.reflection.numpy(), photos.transmission.numpy(), settings=settings)
    assert result.variation["kept"] is not darker
    assert result.variation["dropped"] == ("colour" if darker else None)
    assert (max(result.variation["colour_shift"]) > pipeline.MEAN_COLOUR_SLACK) is darker
    assert result.params.brightness_variation == pytest.approx((0.0, 0.0) if darker else (0.05, 0.05))
    # darker: the halved albedos are no part of the amplitudes, so a part of them moves the colour too
    settled = result.variation["settled"]
    assert [s["scale"] for s in settled] == pytest.approx(
        [1.0, pipeline.retreat_scale(max(settled[0]["colour_shift"]))] if darker else [1.0], abs=1e-4)
    assert result.variation["scale"] == (0.0 if darker else 1.0)


def test_a_variation_that_moves_the_colour_in_full_is_kept_at_the_part_that_does_not(monkeypatch):
    """A reading whose overall colour shift grows with the square of its amplitude (as a convex
    transmission's does) and is four times the slack in full: the fit settles once more at
    retreat_scale's part of it, which moves the colour by RETREAT_TARGET of the slack, and keeps that
    part, saying so; the regular weave's colour is read once."""
    import backend.fit.pipeline as pipeline
    from backend.fit.objective import Objective
    from backend.fit.variation_estimate import VariationEstimate

    amplitude, read = 0.2, []
    full_shift = 4 * pipeline.MEAN_COLOUR_SLACK

    def reading(params, objective, blur, seed, progress):
        return (with_amplitudes(params, {"thickness": amplitude}),
                VariationEstimate({k: amplitude * (k == "thickness") for k in KINDS}, 10.0, 5.0, True))

    def mean_colour_errors(self, params, blur):
        a = params.thickness_variation[0]
        read.append(a)
        return (0.01, 0.01 + full_shift * (a / amplitude) ** 2)

    monkeypatch.setattr(pipeline, "estimate_variation", reading)
    monkeypatch.setattr(Objective, "mean_colour_errors", mean_colour_errors)
    photos = render_pair(TWILL, size=64, spp=8, seed=3)
    settings = FitSettings(pattern="twill1", iterations=2, trial_iterations=1, size=64, spp=4, search_every=0,
                           compile=False, camera_blur=0.0, sample_rotation=0.0, settle_steps=2)
    result = pipeline.fit(photos.reflection.numpy(), photos.transmission.numpy(), settings=settings)
    scale = pipeline.retreat_scale(full_shift)
    assert scale == pytest.approx(math.sqrt(pipeline.RETREAT_TARGET / 4))
    assert result.variation["kept"] and result.variation["dropped"] is None
    assert result.variation["scale"] == pytest.approx(scale, abs=1e-4)
    assert [s["scale"] for s in result.variation["settled"]] == pytest.approx([1.0, scale], abs=1e-4)
    assert max(result.variation["colour_shift"]) == pytest.approx(pipeline.RETREAT_TARGET
                                                                  * pipeline.MEAN_COLOUR_SLACK, abs=1e-5)
    assert result.params.thickness_variation == pytest.approx((amplitude * scale, amplitude * scale))
    assert read.count(0.0) == 1  # the regular weave's, once; then each settled one's
    assert len(read) == 3


def test_a_scaled_variation_scales_every_amplitude_and_keeps_its_lengths():
    varied = with_amplitudes(TWILL, {"thickness": 0.2, "slub": 0.1}, {"thickness": 3.0, "slub": 5.0})
    half = with_scaled_variation(varied, 0.5)
    assert half.thickness_variation == pytest.approx((0.1, 0.1))
    assert half.slub_variation == pytest.approx((0.05, 0.05))
    assert half.width_variation == (0.0, 0.0)
    assert (half.thickness_variation_length, half.slub_variation_length) == ((3.0, 3.0), (5.0, 5.0))
    assert with_scaled_variation(varied, 1.0) is varied


def test_a_true_variation_whose_pattern_lies_elsewhere_is_kept(monkeypatch):
    """Photos of TWILL whose yarns' brightness varies (drifting over 3 yarns), and a reading of that
    amplitude at the default length: a random pattern that never lies where the photos' does. After
    settling, its 16 x 16 colour term is more than 10 % above the regular weave's (in blocks of a
    yarn or two two independent patterns differ more than either from their mean), but the fabric's
    overall colour stays within MEAN_COLOUR_SLACK of the regular weave's, so the fit keeps it."""
    import torch

    import backend.fit.pipeline as pipeline
    from backend.fit.variation_estimate import VariationEstimate
    from backend.model.param_tensors import ParamTensors

    amplitude, regular_colour = 0.25, []

    def reading(params, objective, blur, seed, progress):
        with torch.no_grad():
            terms = objective.terms(ParamTensors.from_params(params), blur)
        regular_colour.append(float(terms["colour_R"] + terms["colour_T"]))
        return (with_amplitudes(params, {"brightness": amplitude}),
                VariationEstimate({k: amplitude * (k == "brightness") for k in KINDS}, 10.0, 5.0, True))

    monkeypatch.setattr(pipeline, "estimate_variation", reading)
    shown = TWILL.replace(brightness_variation=(amplitude, amplitude), brightness_variation_length=(3.0, 3.0))
    photos = render_pair(shown, size=64, spp=8, seed=3)
    settings = FitSettings(pattern="twill1", iterations=2, trial_iterations=1, size=64, spp=4, search_every=0,
                           compile=False, camera_blur=0.0, sample_rotation=0.0, settle_steps=2)
    result = pipeline.fit(photos.reflection.numpy(), photos.transmission.numpy(), settings=settings)
    assert result.terms["colour_R"] + result.terms["colour_T"] > 1.1 * regular_colour[0]
    assert result.variation["kept"] and result.variation["dropped"] is None
    assert max(result.variation["colour_shift"]) <= pipeline.MEAN_COLOUR_SLACK
    assert result.params.brightness_variation == pytest.approx((amplitude, amplitude))
