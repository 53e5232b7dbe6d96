"""The fit benchmark's photo-like data and its novel-light error: deterministic, truthful, and the
phone's effects do what they say."""
import dataclasses
import json
import random

import numpy as np
import pytest
import torch

from backend.core.params import SPECS, FabricParams
from backend.core.priors import typical
from backend.core.rig import DEFAULT_RIG, CaptureRig
from backend.model.imaging import display_transform
from backend.model.render import Renderer
from backend.texture.gates import GATES
from devtools import photo_like
from devtools.bench import photolike
from devtools.bench.novel_light import NOVEL_LIGHTS, novel_light_error
from devtools.phone import EFFECTS, PhoneEffects

SMALL = CaptureRig(film_size=64)  # every effect is in film pixels: a small film keeps the test fast


def test_every_other_run_of_five_items_is_mirrored():
    patterns = [photolike.item_pattern(k) for k in range(20)]
    assert patterns[:10] == ["plain", "twill0", "twill1", "satin0", "satin1",
                             "plain", "twill0m", "twill1m", "satin0m", "satin1m"]
    assert patterns[10:] == patterns[:10]


def test_a_photo_like_set_is_a_function_of_its_seed(tmp_path):
    first = [photolike.make_item(tmp_path / "a", seed=4, index=k, rig=SMALL) for k in (0, 3)]
    again = [photolike.make_item(tmp_path / "b", seed=4, index=k, rig=SMALL) for k in (0, 3)]
    other = photolike.make_item(tmp_path / "c", seed=5, index=0, rig=SMALL)
    assert first == again
    for name in ("plain_000_R.png", "plain_000_T.png", "satin0_003_T.png"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert (tmp_path / "c" / "plain_000_R.png").read_bytes() != (tmp_path / "a" / "plain_000_R.png").read_bytes()
    assert other["params"] != first[0]["params"]
    truth = first[1]
    assert FabricParams.from_interchange(truth["params"]).pattern == "satin0"
    assert abs(truth["rig"]["sample_rotation_deg"]) <= photo_like.MAX_ROTATION_DEG
    assert truth["rig"]["camera_blur_px"] == pytest.approx(truth["phone"]["blur_px"], abs=1e-4)
    assert 0.5 <= truth["phone"]["blur_px"] <= 2.0 and 75 <= truth["phone"]["jpeg_quality"] <= 95
    json.dumps(first)  # the cases.json entry is plain JSON


def test_a_moved_set_moves_only_the_reflection_photo(tmp_path):
    still = photolike.make_item(tmp_path / "a", seed=4, index=3, rig=SMALL)
    moved = photolike.make_item(tmp_path / "m", seed=4, index=3, rig=SMALL, moved=True)
    again = photolike.make_item(tmp_path / "n", seed=4, index=3, rig=SMALL, moved=True)
    assert "move" not in still and moved == again
    assert {k: v for k, v in moved.items() if k != "move"} == still     # the truth is the transmission's framing
    assert photo_like.MOVE_SCALE[0] <= moved["move"]["scale"] <= photo_like.MOVE_SCALE[1]
    assert abs(moved["move"]["turn_deg"]) <= photo_like.MAX_MOVE_TURN_DEG
    name = "satin0_003"
    assert (tmp_path / "m" / f"{name}_T.png").read_bytes() == (tmp_path / "a" / f"{name}_T.png").read_bytes()
    assert (tmp_path / "m" / f"{name}_R.png").read_bytes() != (tmp_path / "a" / f"{name}_R.png").read_bytes()
    # the fit benchmark carries the move to its rows (beside the registration the fit made)
    from devtools.bench.fit import pair_jobs
    for folder, case in (("a", still), ("m", moved)):
        (tmp_path / folder / "cases.json").write_text(json.dumps([case]))
    assert [job["move"] for job in pair_jobs([str(tmp_path / "a"), str(tmp_path / "m")], [], None)] == [
        None, moved["move"]]


def test_a_forward_set_scatters_forward_and_the_fit_benchmark_scores_it(tmp_path):
    """--forward: the yarns' forward scattering drawn from its declared prior into the truth, every other
    draw the plain set's (the photos differ in transmission only); the fit benchmark reads that truth
    (0 for a set without it) and means the error."""
    from devtools.bench.fit import _format_summary, forward_error, pair_jobs, summarise

    still = photolike.make_item(tmp_path / "a", seed=4, index=3, rig=SMALL)
    forward = photolike.make_item(tmp_path / "f", seed=4, index=3, rig=SMALL, forward=True)
    assert "forward_scattering" not in still
    assert {k: v for k, v in forward.items() if k != "forward_scattering"} == still
    lo, hi = SPECS["forward_scattering"].prior
    assert all(lo <= k <= hi for k in forward["forward_scattering"]) and forward["forward_scattering"] != [0.0, 0.0]
    name = forward["name"]
    assert (tmp_path / "f" / f"{name}_R.png").read_bytes() == (tmp_path / "a" / f"{name}_R.png").read_bytes()
    assert (tmp_path / "f" / f"{name}_T.png").read_bytes() != (tmp_path / "a" / f"{name}_T.png").read_bytes()
    for folder, case in (("a", still), ("f", forward)):
        (tmp_path / folder / "cases.json").write_text(json.dumps([case]))
    truths = [job["truth"] for job in pair_jobs([str(tmp_path / "a"), str(tmp_path / "f")], [], None)]
    assert [list(t.forward_scattering) for t in truths] == [[0.0, 0.0], forward["forward_scattering"]]
    assert forward_error(truths[0].replace(forward_scattering=(0.1, 0.3)), truths[0]) == pytest.approx(0.2)
    summary = summarise([_bench_row("a", forward_error=0.1), _bench_row("b", forward_error=0.3)])
    assert summary["photolike"]["forward_error"] == pytest.approx(0.2)
    assert "forward scattering error 0.2" in _format_summary(summary)


@pytest.mark.parametrize("index, pattern", [(1, "twill0"), (3, "twill1")])
def test_the_moved_reflection_shows_the_lattice_moved_as_drawn(index, pattern):
    # The registration's map of the moved pair is the drawn move after the unmoved pair's own (the two
    # photos weigh different parts of a non-uniformly spaced sample: 0.3-0.6 %, a tenth of a degree).
    from backend.image.registration import Registration, lattice_map

    def scale_and_turn(matrix):
        read = Registration(matrix, 0, 0.0, 0.0)
        return read.scale, read.turn_deg

    still = photo_like.photograph(pattern, photolike.item_rng(5, index), DEFAULT_RIG, 2)
    shot = photo_like.photograph(pattern, photolike.item_rng(5, index), DEFAULT_RIG, 2,
                                 move_rng=photolike.item_rng(5, index, "move"))
    assert np.array_equal(shot.transmission, still.transmission) and shot.params == still.params
    own_scale, own_turn = scale_and_turn(lattice_map(still.reflection, still.transmission, 1.0)[0])
    matrix, matches, _, _ = lattice_map(shot.reflection, shot.transmission, shot.move.scale)
    scale, turn = scale_and_turn(matrix)
    assert matches >= 12
    assert scale == pytest.approx(shot.move.scale * own_scale, abs=0.002)
    assert turn == pytest.approx(shot.move.turn_deg + own_turn, abs=0.2)


def test_a_set_without_a_phone_effect_differs_from_the_full_set_in_that_effect_alone(tmp_path):
    full = photolike.make_item(tmp_path / "full", seed=4, index=3, rig=SMALL)
    flat = photolike.make_item(tmp_path / "flat", seed=4, index=3, rig=SMALL, without=("warp", "falloff"))
    assert flat["without"] == ["warp", "falloff"] and "without" not in full
    assert flat["params"] == full["params"] and flat["rig"] == full["rig"]  # the same draws and render
    changed = {k for k in full["phone"] if flat["phone"][k] != full["phone"][k]}
    assert changed == {"warp_px", "falloff"}
    assert flat["phone"]["warp_px"] == 0.0 and tuple(flat["phone"]["falloff"]) == (0.0,) * 4
    assert full["phone"]["warp_px"] > 0.0
    name = "satin0_003_T.png"
    assert (tmp_path / "flat" / name).read_bytes() != (tmp_path / "full" / name).read_bytes()
    # every effect taken away: the truth's blur is none, and the case reads back as the phone it was
    bare = photolike.make_item(tmp_path / "bare", seed=4, index=3, rig=SMALL, without=EFFECTS)
    assert bare["rig"]["camera_blur_px"] == 0.0 and bare["phone"]["jpeg_quality"] is None
    phone = PhoneEffects(**bare["phone"])
    assert phone.gains(0).tolist() == [1.0, 1.0, 1.0] and phone.noise_gain == 0.0 == phone.read_noise
    with pytest.raises(ValueError, match="unknown phone effect lens"):
        phone.without("lens")


def test_the_photolike_command_takes_effects_away_by_name(tmp_path, capsys):
    from devtools.cli.main import main
    assert main(["photolike", "--out", str(tmp_path), "--count", "1", "--seed", "4", "--without", "noise",
                 "jpeg"]) == 0
    [case] = json.loads((tmp_path / "cases.json").read_text())
    assert case["without"] == ["noise", "jpeg"] and case["phone"]["noise_gain"] == 0.0
    with pytest.raises(SystemExit):
        main(["photolike", "--out", str(tmp_path / "x"), "--count", "1", "--without", "lens"])
    assert "invalid choice: 'lens'" in capsys.readouterr().err


def test_a_phone_without_effects_is_the_renderers_display_transform():
    rig = CaptureRig(film_size=64)
    pair = Renderer(rig, size=64, spp=2).render(typical("twill0").replace(tiles=(30.0, 30.0)))
    none = PhoneEffects(blur_px=0.0, exposure=1.0, photo_exposure=(1.0, 1.0), white_balance=(1.0, 1.0, 1.0),
                        falloff=(0.0, 0.0, 0.0, 0.0), warp_px=0.0, warp_period_px=(200.0, 200.0),
                        warp_phase=(0.0, 0.0), noise_gain=0.0, read_noise=0.0, jpeg_quality=95, seed=1)
    torch.testing.assert_close(none.apply(pair.reflection_radiance, 0, rig), pair.reflection.clamp(0, 1),
                               atol=2e-5, rtol=0)
    brighter = dataclasses.replace(none, exposure=1.2)
    expected = display_transform(pair.transmission_radiance * 1.2, rig.gamma, rig.clamp,
                                 Renderer(rig, size=64, spp=2).vignette).clamp(0, 1)
    torch.testing.assert_close(brighter.apply(pair.transmission_radiance, 1, rig), expected, atol=2e-5, rtol=0)
    noisy = dataclasses.replace(none, noise_gain=1e-3, read_noise=0.003)
    difference = noisy.apply(pair.reflection_radiance, 0, rig) - none.apply(pair.reflection_radiance, 0, rig)
    assert 0.002 < float(difference.std()) < 0.05 and abs(float(difference.mean())) < 0.005


def _stripe_phase(photo: np.ndarray, period: float) -> np.ndarray:
    """Per row, the phase (radians) of stripes of ``period`` pixels running down the image, against
    cos(2 pi x / period), along x: the photo demodulated at the stripes' frequency and averaged over
    four periods (which cancels the harmonics the display transform's gamma adds)."""
    x = np.arange(photo.shape[1]) + 0.5
    demodulated = photo * np.exp(-2j * np.pi * x / period)
    width = int(4 * period)
    averaged = np.stack([np.convolve(row, np.ones(width) / width, mode="same") for row in demodulated])
    return np.angle(averaged)


@pytest.mark.parametrize("axis", [0, 1])
def test_the_phones_warp_changes_the_yarn_spacing_along_each_axis(axis):
    # Stripes of an 8-pixel pitch across one axis: the warp moves each stripe along that axis by
    # A sin(2 pi p / L + phi) (p along the same axis), so their spacing varies by 2 pi A / L and they
    # stay straight (the same phase on every line across them).
    n, period, length, amplitude, phase = 512, 8.0, 200.0, 0.03 * 200.0 / (2 * np.pi), 0.7
    rig = CaptureRig(film_size=n)
    x = torch.arange(n, dtype=torch.float64) + 0.5
    stripes = (0.45 + 0.35 * torch.cos(2 * np.pi * x / period))[None, :].expand(n, n)
    radiance = (stripes if axis == 0 else stripes.T)[..., None].expand(n, n, 3).contiguous()
    phone = PhoneEffects(blur_px=0.0, exposure=1.0, photo_exposure=(1.0, 1.0), white_balance=(1.0, 1.0, 1.0),
                         falloff=(0.0, 0.0, 0.0, 0.0), warp_px=amplitude, warp_period_px=(length, length),
                         warp_phase=(phase, phase), noise_gain=0.0, read_noise=0.0, jpeg_quality=95, seed=1)
    photo = phone.apply(radiance, 0, rig)[..., 0].numpy()
    measured = _stripe_phase(photo if axis == 0 else photo.T, period)[:, 64:-64]
    inner = x.numpy()[64:-64]
    expected = 2 * np.pi / period * amplitude * np.sin(2 * np.pi * inner / length + phase)
    # radians (the 4-period average smooths the phase a little); its swing is 0.75
    assert np.abs(np.angle(np.exp(1j * (measured - expected)))).max() < 0.08
    # the displacement's sinusoid fitted to the phase: its slope, the scale change, peaks at 3 %
    basis = np.stack([np.sin(2 * np.pi * inner / length), np.cos(2 * np.pi * inner / length)], axis=1)
    profile = np.unwrap(measured.mean(axis=0))  # the phase along the axis, the same on every line
    coefficients = np.linalg.lstsq(basis, profile, rcond=None)[0]
    displacement = np.hypot(*coefficients) * period / (2 * np.pi)
    assert 2 * np.pi * displacement / length == pytest.approx(0.03, abs=0.003)
    # and the phone says so: the local frequency change is the phase's slope
    slope = np.gradient(profile, inner) * period / (2 * np.pi)
    said = np.array([phone.spacing_change(p, p)[axis] for p in inner])
    assert np.abs(np.convolve(slope - said, np.ones(16) / 16, mode="valid")).max() < 0.005


def test_phone_draws_stay_in_their_ranges():
    rng = random.Random(11)
    for _ in range(50):
        phone = PhoneEffects.draw(rng)
        assert 0.5 <= phone.blur_px <= 2.0
        assert 0.01 <= 2 * np.pi * phone.warp_px / min(phone.warp_period_px) <= 0.03 + 1e-9
        assert all(0.93 <= g <= 1.07 for g in phone.white_balance)


def test_novel_light_error_tells_a_wrong_parameter_and_applies_the_cameras_gains():
    truth = typical("twill1").replace(tiles=(40.0, 60.0))
    same = novel_light_error(truth, truth, size=64)
    assert set(NOVEL_LIGHTS) <= {k.removeprefix("colour_l1_") for k in same if k.startswith("colour_l1_")}
    assert same["colour_l1"] < 1e-6 and same["spectrum_corr"] > 0.999
    wrong = novel_light_error(truth.replace(diffuse_reflection=(0.5, 0.5, 0.5)), truth, size=64)
    assert wrong["colour_l1"] > 0.01
    gains = (torch.tensor([1.3, 1.3, 1.3]), torch.tensor([1.3, 1.3, 1.3]))
    assert novel_light_error(truth, truth, gains=gains, size=64)["colour_l1"] > 0.01  # the photo was brighter


def test_the_phones_jpeg_is_a_deterministic_lossy_copy_at_the_film_size():
    from devtools.phone import phone_jpeg
    rng = np.random.default_rng(3)
    image = np.clip(0.5 + 0.1 * rng.standard_normal((128, 128, 3)), 0, 1)
    phone = phone_jpeg(image, 75, 32)
    assert phone.shape == (32, 32, 3) and np.array_equal(phone, phone_jpeg(image, 75, 32))
    area = image.reshape(32, 4, 32, 4, 3).mean(axis=(1, 3))
    assert 0.0005 < np.abs(phone - area).mean() < 0.05          # compressed, then resized by area
    assert np.abs(phone_jpeg(image, 95, 32) - area).mean() < np.abs(phone - area).mean()
    np.testing.assert_allclose(phone_jpeg(image, None, 32), area, atol=1e-9)  # no JPEG: the resize alone


def test_framing_resolves_the_weave_and_leaves_a_coarse_one_alone():
    from backend.texture.frequencies import yarns_in_view
    rig = CaptureRig()
    dense = typical("twill0")                                   # about 1 px per yarn at 512 px
    assert rig.film_size / yarns_in_view("twill0", dense.tiles, rig) < 2
    framed = photo_like.framed(dense, 3.0, rig)
    assert rig.film_size / yarns_in_view("twill0", framed.tiles, rig) == pytest.approx(3.0)
    assert framed.tiles[0] / framed.tiles[1] == pytest.approx(dense.tiles[0] / dense.tiles[1])  # same weave, closer
    coarse = dense.replace(tiles=(20.0, 20.0))
    assert photo_like.framed(coarse, 3.0, rig) == coarse


def _high_frequency_std(image: torch.Tensor) -> float:
    luma = image.mean(-1)
    return float((luma - torch.nn.functional.avg_pool2d(luma[None, None], 5, 1, 2, count_include_pad=False)[0, 0])
                 .std())


def test_the_optics_act_before_the_sensor_samples():
    """A weave finer than the camera's blur reaches the photo soft, not as an aliased lattice: the phone
    blurs the light at its own resolution before the film's pixels average it."""
    rig = CaptureRig(film_size=64)
    dense = typical("plain").replace(tiles=(48.0, 48.0))        # about 0.8 film px per yarn
    blur_only = PhoneEffects(blur_px=1.5, exposure=1.0, photo_exposure=(1.0, 1.0), white_balance=(1.0, 1.0, 1.0),
                             falloff=(0.0, 0.0, 0.0, 0.0), warp_px=0.0, warp_period_px=(200.0, 200.0),
                             warp_phase=(0.0, 0.0), noise_gain=0.0, read_noise=0.0, jpeg_quality=95, seed=1)
    sampled_first = blur_only.apply(Renderer(rig, size=64, spp=1).render(dense).reflection_radiance, 0, rig)
    fine = blur_only.apply(Renderer(rig, size=256, spp=1).render(dense).reflection_radiance, 0, rig)
    optics_first = torch.nn.functional.avg_pool2d(fine.permute(2, 0, 1)[None], 4)[0].permute(1, 2, 0)
    assert _high_frequency_std(optics_first) < 0.3 * _high_frequency_std(sampled_first)


def test_sensor_noise_is_per_phone_pixel_and_averages_to_the_drawn_level():
    rig = CaptureRig(film_size=32)
    flat = torch.full((128, 128, 3), 0.2)
    noisy = PhoneEffects(blur_px=0.0, exposure=1.0, photo_exposure=(1.0, 1.0), white_balance=(1.0, 1.0, 1.0),
                         falloff=(0.0, 0.0, 0.0, 0.0), warp_px=0.0, warp_period_px=(200.0, 200.0),
                         warp_phase=(0.0, 0.0), noise_gain=0.0, read_noise=0.01, jpeg_quality=95, seed=2)
    rig_linear = dataclasses.replace(rig, gamma=1.0, vignette_sigma_px=1e9)
    photo = noisy.apply(flat, 0, rig_linear)
    film = photo.reshape(32, 4, 32, 4, 3).mean(dim=(1, 3))
    assert float(film.std()) == pytest.approx(0.01, rel=0.15)
    assert float(photo.std()) == pytest.approx(0.04, rel=0.15)


def _bench_row(name: str, ppy: float = 3.0, ok: bool = True, tiles_error: float = 0.1, **extra) -> dict:
    """A photo-like row of ``bench fit`` with the keys its summary reads."""
    return {"kind": "photolike", "name": name, "wall_s": 1.0, "pattern_ok": ok, "family_ok": ok,
            "roughness_mae": 0.1, "thickness_mae": 0.2, "tiles_error_pct": tiles_error,
            "rotation_error_deg": 0.0, "pixels_per_yarn": ppy,
            **{f"{m}_{t}": 0.0 for m in ("flip", "colour_l1", "spectrum_corr") for t in "RT"}, **extra}


def test_the_fit_benchmark_counts_pixels_per_yarn_and_scores_the_resolved_pairs_apart():
    from backend.core.rig import DEFAULT_RIG
    from devtools.bench.fit import RESOLVED_PX_PER_YARN, pixels_per_yarn, summarise

    seen = DEFAULT_RIG.view_size / DEFAULT_RIG.plane_size      # of the plane's tiles, this share is in view
    plain = typical("plain").replace(tiles=(100.0, 100.0))       # 79.8 tiles of 2 yarns across 512 px
    assert pixels_per_yarn(plain, DEFAULT_RIG) == pytest.approx(512 / (2 * 100 * seen))
    satin = typical("satin1").replace(tiles=(175.0, 79.0))      # 5 yarns a tile: the finer axis counts
    assert pixels_per_yarn(satin, DEFAULT_RIG) == pytest.approx(512 / (5 * 175 * seen))

    section = summarise([_bench_row("sharp", RESOLVED_PX_PER_YARN + 0.7, True, 0.5),
                         _bench_row("aliased", RESOLVED_PX_PER_YARN - 1.3, False, 120.0)])["photolike"]
    assert "blur_error_px_mean" not in section  # golden-like rows have no phone
    assert section["pattern_accuracy"] == 0.5 and section["tiles_error_pct_max"] == 120.0
    assert section["resolved"] == {"pairs": 1, "pattern_accuracy": 1.0, "family_accuracy": 1.0, "roughness_mae": 0.1,
                                   "thickness_mae": 0.2, "tiles_error_pct_max": 0.5, "tiles_error_pct_mean": 0.5}


def test_the_fit_benchmark_reports_the_camera_blur_against_the_phones():
    from devtools.bench.fit import blur_errors, summarise
    from devtools.phone import PhoneEffects

    phone = PhoneEffects.draw(random.Random(3))
    assert blur_errors(phone.blur_px + 0.27, phone) == {"phone_blur_px": round(phone.blur_px, 3),
                                                        "blur_error_px": pytest.approx(0.27, abs=1e-3)}
    section = summarise([_bench_row("over", phone_blur_px=1.0, blur_error_px=0.3),
                         _bench_row("under", phone_blur_px=1.0, blur_error_px=-0.1)])["photolike"]
    assert section["blur_error_px_mean"] == pytest.approx(0.1)
    assert section["blur_error_px_mean_abs"] == pytest.approx(0.2)


def test_the_fit_benchmark_means_the_texture_gap_and_the_variation_error_with_their_targets():
    from devtools.bench.fit import TARGETS, _format_summary, summarise

    rows = [_bench_row("even", texture_gap_db_R=2.0, texture_gap_db_T=4.0, variation_rms_error=-0.5),
            _bench_row("uneven", texture_gap_db_R=6.0, texture_gap_db_T=1.0, variation_rms_error=0.1),
            _bench_row("regular", texture_gap_db_R=1.0, texture_gap_db_T=1.0, variation_rms_error=None)]
    summary = summarise(rows)
    section = summary["photolike"]
    assert section["texture_gap_db_R"] == pytest.approx(3.0) and section["texture_gap_db_T"] == pytest.approx(2.0)
    assert section["variation_rms_abs_error"] == pytest.approx(0.3)  # the truths without variation left out
    text = _format_summary(summary)
    assert "texture gap 3.0/2.0 dB" in text and "variation amplitude error (mean size, relative) 0.3" in text
    assert TARGETS["real"]["texture_gap_db_max"] == 3.0 and TARGETS["photolike"]["variation_rms_abs_error_max"] == 0.25


@pytest.mark.slow
def test_the_placement_benchmark_reports_the_fits_placement_and_lattice_against_the_truth(tmp_path, capsys):
    from devtools.bench.placement import summary
    from devtools.cli.main import main

    # A satin whose photos show a few low oblique peaks at 2-3 px per yarn (tests/test_fit.py's lone
    # harmonic case), turned 0.15 degrees.
    case = photolike.make_item(tmp_path, seed=31, index=14)
    (tmp_path / "cases.json").write_text(json.dumps([case]))
    assert main(["bench", "placement", "--synthetic", str(tmp_path), "--json", "--no-record"]) == 0
    row, total = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert total["gates"]["rival_turn_gain"] == GATES.rival_turn_gain  # the summary names the gates it ran with
    assert row["name"] == case["name"] and row["true_rotation_deg"] == pytest.approx(0.15, abs=0.01)
    assert row["rotation_error_deg"] == pytest.approx(abs(row["rotation_deg"] - row["true_rotation_deg"]), abs=1e-3)
    assert row["rotation_error_deg"] < 0.25 and row["tiles_error_pct"] < 1.0
    assert any(pattern == "satin1" for pattern, _ in row["candidates"])
    assert total["pairs"] == 1 and total["tiles_error_over_1_pct"] == 0 and total["rotation_error_over_0.5_deg"] == 0

    # A pair without a candidate of its own pattern counts as off by more than the target.
    rows = [{"rotation_error_deg": 0.7, "tiles_error_pct": None, "seconds": 1.0},
            {"rotation_error_deg": 0.1, "tiles_error_pct": 0.4, "seconds": 2.0}]
    assert summary(rows) == {"summary": "placement", "pairs": 2, "rotation_error_mean_deg": 0.4,
                             "rotation_error_median_deg": 0.4, "rotation_error_over_0.5_deg": 1,
                             "tiles_error_mean_pct": 0.4, "tiles_error_median_pct": 0.4,
                             "tiles_error_over_1_pct": 1, "seconds": 3.0}

    # Without the truth there is nothing to score: a clear error, exit status 2.
    assert main(["bench", "placement"]) == 2
    assert "bench placement: give --synthetic DIR" in capsys.readouterr().err
    assert main(["bench", "placement", "--synthetic", str(tmp_path / "missing")]) == 2
    assert f"{tmp_path / 'missing'}: file not found" in capsys.readouterr().err
