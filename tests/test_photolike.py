"""The fit benchmark's photo-like data and its novel-light error: deterministic, truthful, and the
phone's effects do what they say."""
import dataclasses
import json
import random

import numpy as np
import pytest
import torch

from backend.bench import photolike
from backend.bench.novel_light import NOVEL_LIGHTS, novel_light_error
from backend.core.params import FabricParams
from backend.core.priors import typical
from backend.core.rig import CaptureRig
from backend.model.imaging import display_transform
from backend.model.phone import PhoneEffects
from backend.model.render import Renderer

SMALL = CaptureRig(film_size=96)  # every effect is in film pixels: a small film keeps the test fast


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
    assert abs(truth["rig"]["sample_rotation_deg"]) <= photolike.MAX_ROTATION_DEG
    assert truth["rig"]["camera_blur_px"] == pytest.approx(truth["phone"]["blur_px"], abs=1e-4)
    assert 0.5 <= truth["phone"]["blur_px"] <= 2.0 and 75 <= truth["phone"]["jpeg_quality"] <= 95
    json.dumps(first)  # the cases.json entry is plain JSON


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


def test_jpeg_at_the_phones_scale_is_a_deterministic_lossy_copy():
    from backend.image.png import jpeg_at_phone_scale
    rng = np.random.default_rng(3)
    image = np.clip(0.5 + 0.1 * rng.standard_normal((64, 64, 3)), 0, 1)
    phone = jpeg_at_phone_scale(image, 75)
    assert phone.shape == image.shape and np.array_equal(phone, jpeg_at_phone_scale(image, 75))
    assert 0.001 < np.abs(phone - image).mean() < 0.05          # compressed, not replaced
    assert np.abs(jpeg_at_phone_scale(image, 95) - image).mean() < np.abs(phone - image).mean()


def test_the_fit_benchmark_counts_pixels_per_yarn_and_scores_the_resolved_pairs_apart():
    from backend.bench.fit import RESOLVED_PX_PER_YARN, pixels_per_yarn, summarise
    from backend.core.rig import DEFAULT_RIG

    seen = DEFAULT_RIG.view_size / DEFAULT_RIG.plane_size      # of the plane's tiles, this share is in view
    plain = typical("plain").replace(tiles=(100.0, 100.0))       # 79.8 tiles of 2 yarns across 512 px
    assert pixels_per_yarn(plain, DEFAULT_RIG) == pytest.approx(512 / (2 * 100 * seen))
    satin = typical("satin1").replace(tiles=(175.0, 79.0))      # 5 yarns a tile: the finer axis counts
    assert pixels_per_yarn(satin, DEFAULT_RIG) == pytest.approx(512 / (5 * 175 * seen))

    def row(name, ppy, ok, tiles_error):
        return {"kind": "photolike", "name": name, "wall_s": 1.0, "pattern_ok": ok, "family_ok": ok,
                "roughness_mae": 0.1, "thickness_mae": 0.2, "tiles_error_pct": tiles_error,
                "rotation_error_deg": 0.0, "pixels_per_yarn": ppy,
                **{f"{m}_{t}": 0.0 for m in ("flip", "colour_l1", "spectrum_corr") for t in "RT"}}

    section = summarise([row("sharp", RESOLVED_PX_PER_YARN + 0.7, True, 0.5),
                         row("aliased", RESOLVED_PX_PER_YARN - 1.3, False, 120.0)])["photolike"]
    assert section["pattern_accuracy"] == 0.5 and section["tiles_error_pct_max"] == 120.0
    assert section["resolved"] == {"pairs": 1, "pattern_accuracy": 1.0, "family_accuracy": 1.0, "roughness_mae": 0.1,
                                   "thickness_mae": 0.2, "tiles_error_pct_max": 0.5, "tiles_error_pct_mean": 0.5}
