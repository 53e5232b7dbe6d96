"""Novel-light error: the fitted and the true parameters rendered under lights the fit never saw.

The photo pair shows the fabric under two lights; draped cloth in a scene meets every other one. A
parameter the two photos cannot see (poorly constrained) may take any value without changing the
fit's images, but it shows under other lights; a wrong parameter shows under the photo's lights too.
So both parameter sets are rendered, without the sample's rotation and the camera's blur (the
material alone), under

- ``side``: the front light 8 units to the right of the camera instead of above the top edge;
- ``grazing``: the front light low beyond the top edge (elevation about 14 degrees);
- ``overhead``: the front light high above the camera, almost along the view;
- ``back_offset``: the back light moved off the axis (its out-of-focus glow, a pinhole trick tied to
  the rig's axis, is left out of both renders),

and compared image by image: 16 x 16 colour L1 and spectrum correlation (the project's metric
definitions, :mod:`backend.image.metrics`), averaged over the four. ``gains`` (the photo-like
benchmark's camera exposure and white balance, per photo) scale the truth as its photo was scaled: a
fit cannot tell them from the albedos, so the fair target is the fabric as photographed.
"""
from __future__ import annotations

import dataclasses

import torch

from backend.core.options import RenderOptions
from backend.core.params import FabricParams
from backend.core.rig import DEFAULT_RIG, CaptureRig
from backend.image.metrics import colour_l1, spectrum_corr
from backend.model.imaging import display_transform
from backend.model.render import Renderer

# name -> (photo: 0 reflection / 1 transmission, rig changes)
NOVEL_LIGHTS = {
    "side": (0, {"front_light": (8.0, 0.0, 8.0)}),
    "grazing": (0, {"front_light": (0.0, 12.0, 3.0)}),
    "overhead": (0, {"front_light": (1.0, 1.0, 14.0)}),
    "back_offset": (1, {"back_light": (3.0, 2.0, -9.0)}),
}


def novel_light_images(params: FabricParams, rig: CaptureRig = DEFAULT_RIG, size: int = 256, spp: int = 16,
                       gains: tuple[torch.Tensor, torch.Tensor] | None = None) -> dict[str, torch.Tensor]:
    """Display-space images (size, size, 3) of ``params`` under each novel light."""
    base = dataclasses.replace(rig, sample_rotation_deg=0.0, sample_skew_deg=0.0, camera_blur_px=0.0)
    out = {}
    for name, (photo, changes) in NOVEL_LIGHTS.items():
        renderer = Renderer(dataclasses.replace(base, **changes), size=size, spp=spp, seed=5,
                            options=RenderOptions(glow=False), cache_samples=0)
        with torch.no_grad():
            pair = renderer.render(params)
        radiance = pair.reflection_radiance if photo == 0 else pair.transmission_radiance
        if gains is not None:
            radiance = radiance * gains[photo].to(radiance)
        out[name] = display_transform(radiance, base.gamma, base.clamp, renderer.vignette)
    return out


def novel_light_error(fitted: FabricParams, truth: FabricParams, rig: CaptureRig = DEFAULT_RIG,
                      gains: tuple[torch.Tensor, torch.Tensor] | None = None, size: int = 256) -> dict[str, float]:
    """Mean colour L1 and spectrum correlation over the novel lights (and each light's figures)."""
    fit_images = novel_light_images(fitted, rig, size)
    true_images = novel_light_images(truth, rig, size, gains=gains)
    out = {}
    for name in NOVEL_LIGHTS:
        a, b = true_images[name].numpy(), fit_images[name].numpy()
        out[f"colour_l1_{name}"] = colour_l1(a, b)
        out[f"spectrum_corr_{name}"] = spectrum_corr(a, b)
    out["colour_l1"] = sum(out[f"colour_l1_{n}"] for n in NOVEL_LIGHTS) / len(NOVEL_LIGHTS)
    out["spectrum_corr"] = sum(out[f"spectrum_corr_{n}"] for n in NOVEL_LIGHTS) / len(NOVEL_LIGHTS)
    return out
