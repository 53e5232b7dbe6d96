"""The fitting objective: photos as a target, and the loss of a parameter set against them.

    loss = sum over R, T of [ w_c L1(colour16) + w_h L1(log harmonic magnitudes)
                              + w_a aligned complex harmonics + w_q L1(quantiles) ]
           + w_p * prior(height_scale, gap_scale, roughness_multiple / roughness)

of a render made as the photos show the fabric: with the camera blur, and under each photo's light
falloff, solved in closed form for that render (:mod:`backend.model.photo_light`; ``fit_light``)

(see :mod:`backend.texture.features`; the prior is the spec's Gaussian NLL, and a half-Gaussian
keeping each yarn's multiple-scattering roughness within the dataset's 0.5-1.5 times its
single-scattering roughness: :func:`backend.core.priors.prior_nll`), plus, when the user supplies
VGG-19 weights, the paper's Gram loss (:mod:`backend.fit.gram`).
Photos are compared at a working size (256 by default) after an area downsample in linear light,
which is exactly what the renderer's box filter does, so a 256-pixel render with 16 samples per
pixel sees the same thing as the photo; 16 samples keep sharp highlights unbiased where 4 do not.
The harmonics are read at the lattice of the candidate tiles for both images.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ..core.params import FabricParams
from ..core.priors import prior_nll
from ..core.rig import CaptureRig
from ..image.metrics import spectrum_corr
from ..model.imaging import downsample_linear
from ..model.param_tensors import ParamTensors
from ..model.photo_light import PhotoLight, block_means, linear_photo, solve_blocks
from ..model.render import RenderedPair, Renderer
from ..texture.features import Descriptor, LatticeProbe, LossWeights, describe, descriptor_terms, luminance
from ..texture.frequencies import lattice_of
from .gram import gram_loss


@dataclass
class Target:
    """The photo pair at the working size (display space, (size, size, 3) tensors)."""

    reflection: torch.Tensor
    transmission: torch.Tensor

    @classmethod
    def from_arrays(cls, reflection: np.ndarray, transmission: np.ndarray, size: int, device="cpu") -> "Target":
        def prep(a):
            return downsample_linear(torch.tensor(np.asarray(a), dtype=torch.float32, device=device), size)

        return cls(prep(reflection), prep(transmission))

    @property
    def size(self) -> int:
        return self.reflection.shape[0]


class Objective:
    """Loss of parameter sets against a target, for one rig, renderer and lattice."""

    def __init__(self, target: Target, renderer: Renderer, rig: CaptureRig, weights: LossWeights = LossWeights(),
                 prior_weight: float = 0.002, gram=None, gram_weight: float = 1.0, fit_light: bool = True):
        self.target, self.renderer, self.rig = target, renderer, rig
        self.weights, self.prior_weight = weights, prior_weight
        self.fit_light = fit_light
        self._photo_luminance = None
        self._probe_key = None
        self.gram, self.gram_weight = gram, gram_weight
        if gram is not None:
            with torch.no_grad():
                self._photo_grams = (gram(target.reflection), gram(target.transmission))

    def _probes(self, tiles) -> tuple[LatticeProbe, tuple[Descriptor, Descriptor]]:
        key = tuple(round(t, 6) for t in tiles)
        if key != self._probe_key:
            a, b = lattice_of(tiles, self.rig)
            self._probe = LatticeProbe(self.target.size, a, b, device=self.target.reflection.device,
                                       rotation_deg=self.rig.sample_rotation_deg,
                                       skew_deg=self.rig.sample_skew_deg)
            self._photo = (describe(self.target.reflection, self._probe, self.rig.gamma),
                           describe(self.target.transmission, self._probe, self.rig.gamma))
            self._probe_key = key
        return self._probe, self._photo

    def _photo_linear(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per photo, its linear luminance at the renderer's size and where it is not clipped."""
        if self._photo_luminance is None:
            size = self.renderer.size
            linear = [linear_photo(downsample_linear(photo, size, self.rig.gamma), self.rig.gamma,
                                   self.renderer.vignette)
                      for photo in (self.target.reflection, self.target.transmission)]
            self._photo_luminance = [(luminance(radiance), unclipped) for radiance, unclipped in linear]
        return self._photo_luminance

    def light(self, reflection: torch.Tensor, transmission: torch.Tensor) -> PhotoLight:
        """The photos' light falloff (:mod:`backend.model.photo_light`) for a render's blurred linear
        radiance; none when the objective fits without one."""
        if not self.fit_light:
            return PhotoLight()
        renders = (reflection.detach(), transmission.detach())
        means = torch.stack([block_means(luminance(render), (render < self.rig.clamp).all(dim=-1), photo, photo_ok)
                             for render, (photo, photo_ok) in zip(renders, self._photo_linear())])
        return PhotoLight(*(solve_blocks(m) for m in means.cpu()))  # one copy from the device per render

    def rendered(self, fabric: ParamTensors | FabricParams, camera_blur_px: float | torch.Tensor | None = None
                 ) -> tuple[RenderedPair, PhotoLight]:
        """``fabric`` rendered as the photos show it: with the camera blur ``camera_blur_px`` (film
        pixels, a float or a 0-d tensor to differentiate; None: the rig's) and under the photos' light
        falloff solved for that render."""
        radiance = self.renderer.blurred(fabric, camera_blur_px=camera_blur_px)
        light = self.light(*radiance)
        return self.renderer.display(*radiance, light), light

    def terms(self, fabric: ParamTensors, camera_blur_px: float | torch.Tensor | None = None
              ) -> dict[str, torch.Tensor]:
        """Weighted loss terms (and their sum under 'loss') of ``fabric`` rendered as the photos
        show it (:meth:`rendered`)."""
        probe, (photo_r, photo_t) = self._probes(fabric.scalar("tiles"))
        pair, _ = self.rendered(fabric, camera_blur_px)
        size = self.target.size
        out: dict[str, torch.Tensor] = {}
        for tag, image, photo in (("R", pair.reflection, photo_r), ("T", pair.transmission, photo_t)):
            render = describe(downsample_linear(image, size, self.rig.gamma), probe, self.rig.gamma)
            for name, value in descriptor_terms(render, photo).items():
                out[f"{name}_{tag}"] = getattr(self.weights, name) * value
            if self.gram is not None:
                photo_grams = self._photo_grams[0 if tag == "R" else 1]
                working = downsample_linear(image, size, self.rig.gamma)
                out[f"gram_{tag}"] = self.gram_weight * gram_loss(self.gram(working), photo_grams)
        out["prior"] = self.prior_weight * prior_nll(fabric.pattern, fabric.height_scale, fabric.gap_scale,
                                                        fabric.roughness, fabric.roughness_multiple)
        out["loss"] = sum(out.values())
        return out

    def __call__(self, fabric: ParamTensors, camera_blur_px: float | None = None) -> torch.Tensor:
        return self.terms(fabric, camera_blur_px)["loss"]

    def value(self, params: FabricParams | ParamTensors, camera_blur_px: float | None = None) -> float:
        """The loss as a number (no gradients)."""
        if isinstance(params, FabricParams):
            params = ParamTensors.from_params(params, self.renderer.device)
        with torch.no_grad():
            return float(self(params, camera_blur_px))

    def values(self, params: Sequence[FabricParams], camera_blurs_px: Sequence[float]) -> list[float]:
        """The loss of each parameter set at its camera blur, as numbers (:meth:`value`)."""
        return [self.value(p, blur) for p, blur in zip(params, camera_blurs_px, strict=True)]

    def colour_ratios(self, params: FabricParams, camera_blur_px: float) -> tuple[list[float], list[float]]:
        """Per photo (R, T) and channel, the photo's mean linear colour over a render's of ``params``
        (blurred, without the light falloff), within [0.05, 20]: the albedo scales that match the
        render's colour to the photos' (:func:`backend.fit.search.colour_matched`)."""
        with torch.no_grad():
            pair = self.renderer.render(params, camera_blur_px=camera_blur_px)
        gamma = self.rig.gamma

        def ratio(render, photo):
            r, p = _linear_mean(render, gamma), _linear_mean(photo, gamma)
            return (p / r.clamp_min(1e-4)).clamp(0.05, 20.0).tolist()

        return ratio(pair.reflection, self.target.reflection), ratio(pair.transmission, self.target.transmission)

    def mean_colour_errors(self, params: FabricParams, camera_blur_px: float) -> tuple[float, float]:
        """Per photo (R, T), the L1 (mean over the channels) between the photo's overall colour and a
        render's of ``params`` as the photos show it (:meth:`rendered`): the area mean of each whole
        image in linear light, in display space. Unlike the 16 x 16 colour term it does not see where
        a random yarn pattern lies, only what it does to the fabric's colour."""
        with torch.no_grad():
            pair, _ = self.rendered(params, camera_blur_px)
        gamma = self.rig.gamma

        def overall(image):
            return _linear_mean(image, gamma).pow(1 / gamma)

        return tuple(float((overall(render) - overall(photo)).abs().mean())
                     for render, photo in ((pair.reflection, self.target.reflection),
                                           (pair.transmission, self.target.transmission)))

    def spectrum_similarity(self, params: FabricParams, camera_blur_px: float) -> float:
        """Mean over R and T of the log-power-spectrum correlation between a render of ``params``
        (blurred, without the light falloff) and the photo (:func:`backend.image.metrics.spectrum_corr`)."""
        with torch.no_grad():
            pair = self.renderer.render(params, camera_blur_px=camera_blur_px)
        return 0.5 * sum(spectrum_corr(photo.cpu().numpy(), render.cpu().numpy())
                         for photo, render in ((self.target.reflection, pair.reflection),
                                               (self.target.transmission, pair.transmission)))


def _linear_mean(image: torch.Tensor, gamma: float) -> torch.Tensor:
    """The mean linear colour (3,) of a display-space image (size, size, 3)."""
    return image.clamp_min(0).pow(gamma).mean(dim=(0, 1))
