"""The camera's blur read from a photo's noise spectrum (backend.image.camera_blur)."""
import cv2
import numpy as np
import pytest

from backend.core.params import FabricParams
from backend.core.rig import CaptureRig
from backend.image.camera_blur import SOFT_PHOTO_PX, noise_blur_px, photo_blur_px
from backend.image.photos import load_pair
from backend.model.render import render_pair


def noise_image(seed=0, size=512):
    rng = np.random.default_rng(seed)
    return np.clip(0.5 + 0.05 * rng.standard_normal((size, size, 1)), 0, 1).repeat(3, axis=2)


@pytest.mark.parametrize("sigma", [0.8, 1.0, 1.5])
def test_blurred_noise_gives_its_sigma(sigma):
    blurred = cv2.GaussianBlur(noise_image(), (0, 0), sigma)  # mirrored borders, kernel to 4 sigma
    assert noise_blur_px(blurred) == pytest.approx(sigma, abs=0.1)


def test_white_noise_and_a_lattice_read_as_sharp():
    assert noise_blur_px(noise_image()) < 0.1
    # A strong yarn lattice on top of the noise does not count (ring medians skip its peaks).
    y, x = np.mgrid[0:512, 0:512]
    lattice = 0.2 * np.sin(2 * np.pi * (0.21 * x + 0.1 * y))[..., None] * np.ones(3)
    assert noise_blur_px(np.clip(noise_image(1) + lattice, 0, 1)) < 0.1


def test_renders_are_sharp_and_a_blurred_render_is_not():
    params = FabricParams(pattern="twill1", tiles=(92.0, 131.0))
    sharp = render_pair(params, size=256, spp=4, seed=2)
    soft = render_pair(params, CaptureRig(camera_blur_px=2.0), size=256, spp=4, seed=2)
    film = 512
    assert photo_blur_px(sharp.reflection.numpy(), sharp.transmission.numpy(), film) < SOFT_PHOTO_PX
    # 2 film pixels = 1 pixel of these 256-px images
    assert photo_blur_px(soft.reflection.numpy(), soft.transmission.numpy(), film) == pytest.approx(2.0, abs=0.3)


@pytest.mark.parametrize("name", ["satin1", "twill1", "twill2"])
def test_real_photos_read_soft(real_dir, name):
    """The phone photos: 0.49 .. 0.62 px a pair (each photo 0.46 .. 0.77), well above the threshold."""
    pair = load_pair(real_dir / f"{name}_R.png", real_dir / f"{name}_T.png")
    assert 0.4 < photo_blur_px(pair.reflection, pair.transmission, 512) < 0.7


def test_golden_renders_read_sharp(golden_dir, golden_cases):
    """The 17 golden renders: at most 0.12 px a pair (0.23 for one photo), under the threshold."""
    for case in golden_cases:
        pair = load_pair(golden_dir / f"{case['name']}_R.png", golden_dir / f"{case['name']}_T.png")
        assert photo_blur_px(pair.reflection, pair.transmission, 512) < 0.2, case["name"]
