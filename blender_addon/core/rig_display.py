"""The rig's output transform on numpy images (no bpy, no torch): what the backend's renderer does
to its linear radiance, for renders made in Blender (scene/rig_scene.py, tools/validate_shader.py).

Per image, with the rig's settings (``CaptureRig``, spec section 1): in transmission, add
``glow_strength * exp(-d^2 / glow_sigma_px^2)`` where the pixel sees through the gaps; blur by the
camera's point spread (a Gaussian of ``camera_blur_px`` film pixels); clamp to ``clamp``; raise to
1 / gamma; multiply by the vignetting mask exp(-d^2 / vignette_sigma_px^2). Masks are normalised
to a maximum of 1, d in pixels of the ``film_size`` film.

:func:`gaussian_blur` is the numpy twin of ``backend.model.render.gaussian_blur`` (the add-on never
imports torch); a test keeps the two equal.
"""
from __future__ import annotations

import math

import numpy as np

from . import rig_settings


def falloff(size: int, sigma_px: float, film_size: int = 512) -> np.ndarray:
    """exp(-d^2 / sigma^2) at pixel centres, normalised to max 1; d in pixels of the rig's film."""
    centres = (np.arange(size, dtype=np.float64) + 0.5) * (film_size / size) - film_size / 2.0
    d2 = centres[:, None] ** 2 + centres[None, :] ** 2
    mask = np.exp(-d2 / (sigma_px * sigma_px))
    return mask / mask.max()


def gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur (mirrored borders) of an (H, W, C) image; sigma in pixels."""
    if sigma <= 1e-3:
        return image
    radius = max(1, min(int(math.ceil(3.0 * sigma)), image.shape[0] - 1, image.shape[1] - 1))
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (x / sigma) ** 2)
    kernel /= kernel.sum()
    out = np.pad(image, ((radius, radius), (radius, radius), (0, 0)), mode="reflect")
    out = sum(w * out[i:i + image.shape[0]] for i, w in enumerate(kernel))
    return sum(w * out[:, i:i + image.shape[1]] for i, w in enumerate(kernel))


def display(radiance: np.ndarray, rig: dict | None = None, coverage: np.ndarray | None = None,
            glow: bool = False) -> np.ndarray:
    """The rig's output transform of a linear (N, N, 3) image: (+ glow where the pixel sees no
    yarn, transmission only), the camera blur, clamp, 1 / gamma, vignette."""
    capture = rig_settings.capture_rig(rig)
    n = radiance.shape[0]
    rad = radiance[..., :3].astype(np.float64)
    if glow and coverage is not None and capture.glow_strength > 0:
        open_fraction = 1.0 - np.clip(coverage, 0.0, 1.0)
        rad = rad + (falloff(n, capture.glow_sigma_px, capture.film_size) * capture.glow_strength
                     * open_fraction)[..., None]
    rad = gaussian_blur(rad, capture.camera_blur_px * n / capture.film_size)
    out = np.clip(rad, 0.0, capture.clamp) ** (1.0 / capture.gamma)
    return out * falloff(n, capture.vignette_sigma_px, capture.film_size)[..., None]
