"""What a phone adds to the rig's radiance: the photo-like synthetic data of the fit benchmark.

A render of the model is a perfect photo: sharp, noiseless, exactly exposed, lit exactly as the rig
says, with perfectly regular yarns. A phone photo of a real sample is none of these. Given the
linear radiance of a render of the (possibly turned) sample without camera blur, at the phone's own
resolution (``k`` phone pixels per film pixel; every length below is in film pixels), one photo is

    warped   = radiance(p + d(p))                     mild non-uniform yarn spacing: a smooth
               d(p) = A (sin(2 pi p_x / L_x + phi_x), sin(2 pi p_y / L_y + phi_y)), so the yarns
               across x and down y are spaced 1 + 2 pi A / L_x,y cos(...) times their mean pitch
               (local scale changes of up to 1-3 %; each axis's displacement runs along that axis)
    lit      = warped * (1 + falloff(p))              low-frequency light falloff the rig does not
               model: a random tilt and bowl, at most a few tens of percent across the image
    blurred  = G_sigma * lit                          the camera's point spread (sigma film pixels)
    exposed  = blurred * exposure * exposure_i * wb   exposure (both photos, and a little per photo:
               phones meter each shot) and white balance (per channel)
    noisy    = exposed + k N(0, gain * exposed + read^2)   shot and read noise per phone pixel, so
               that a film pixel (the mean of k x k phone pixels) has variance gain * exposed + read^2
    photo    = display_transform(noisy)               the rig's clamp, 1/gamma and vignetting

and the file is ``photo`` JPEG-compressed at ``jpeg_quality`` at the phone's resolution and
area-resized to the film (:func:`phone_jpeg`; the caller writes it). The order is
the physical one: the optics act on the light before the sensor samples it, so a weave finer than
the blur reaches the photo as the soft texture a phone shows, not as the false lattice that point
samples of a sharp image would alias it into. Everything is drawn from a seeded generator
(:meth:`PhoneEffects.draw`), so a photo-like set is a function of its seed. The camera's gains
(exposure x white balance) scale what the photo shows; a fit cannot tell them from the albedos, so a
comparison with the truth under other lights applies them to the truth (:meth:`PhoneEffects.gains`).

:meth:`PhoneEffects.without` takes effects away (:data:`EFFECTS`) after the draw, so a set made
without some (``photolike --without``) differs from the full set in those alone: every other value
and the render are the same. What each effect costs a fit is then one bench away: ``bench fit`` on
both sets.
"""
from __future__ import annotations

import math
import random
from dataclasses import asdict, dataclass, replace

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from backend.core.rig import CaptureRig
from backend.model.camera import CameraSamples
from backend.model.imaging import display_transform, gaussian_blur_products

EFFECTS = ("warp", "falloff", "blur", "exposure", "noise", "jpeg")
"""What a phone adds, by the names :meth:`PhoneEffects.without` takes: the spacing warp, the light
falloff, the camera blur, exposure and white balance, sensor noise, JPEG compression."""


@dataclass(frozen=True)
class PhoneEffects:
    blur_px: float                                  # Gaussian point spread, film pixels
    exposure: float                                 # linear gain of both photos
    photo_exposure: tuple[float, float]             # extra gain of the reflection and transmission photo
    white_balance: tuple[float, float, float]       # per-channel gain
    falloff: tuple[float, float, float, float]      # tilt x, tilt y, bowl, bowl centre offset (fraction)
    warp_px: float                                  # amplitude A of the spacing warp, film pixels
    warp_period_px: tuple[float, float]             # L_x, L_y, film pixels
    warp_phase: tuple[float, float]
    noise_gain: float                               # shot-noise variance per unit of linear signal
    read_noise: float                               # standard deviation, linear
    jpeg_quality: int | None                        # None: no compression
    seed: int                                       # of the noise

    @classmethod
    def draw(cls, rng: random.Random) -> "PhoneEffects":
        """One phone and one pair of shots, drawn from the ranges of the fit issue."""
        periods = (rng.uniform(150.0, 400.0), rng.uniform(150.0, 400.0))
        scale_change = rng.uniform(0.01, 0.03)          # 2 pi A / L
        return cls(blur_px=rng.uniform(0.5, 2.0), exposure=rng.uniform(0.85, 1.15),
                   photo_exposure=(rng.uniform(0.95, 1.05), rng.uniform(0.95, 1.05)),
                   white_balance=tuple(rng.uniform(0.93, 1.07) for _ in range(3)),
                   falloff=(rng.uniform(-0.15, 0.15), rng.uniform(-0.15, 0.15), rng.uniform(-0.2, 0.1),
                            rng.uniform(-0.2, 0.2)),
                   warp_px=scale_change * min(periods) / (2 * math.pi), warp_period_px=periods,
                   warp_phase=(rng.uniform(0, 2 * math.pi), rng.uniform(0, 2 * math.pi)),
                   noise_gain=rng.uniform(1e-4, 1e-3), read_noise=rng.uniform(0.001, 0.004),
                   jpeg_quality=rng.randrange(75, 96), seed=rng.randrange(1 << 30))

    def to_dict(self) -> dict:
        return asdict(self)

    def without(self, *effects: str) -> "PhoneEffects":
        """The same phone with ``effects`` (names in :data:`EFFECTS`) taken away: no spacing warp, an
        even light, a sharp lens, exposure and white balance of 1, a noiseless sensor, no JPEG."""
        unknown = sorted(set(effects) - set(EFFECTS))
        if unknown:
            raise ValueError(f"unknown phone effect {', '.join(unknown)} (known: {', '.join(EFFECTS)})")
        none = {"warp": {"warp_px": 0.0}, "falloff": {"falloff": (0.0, 0.0, 0.0, 0.0)}, "blur": {"blur_px": 0.0},
                "exposure": {"exposure": 1.0, "photo_exposure": (1.0, 1.0), "white_balance": (1.0, 1.0, 1.0)},
                "noise": {"noise_gain": 0.0, "read_noise": 0.0}, "jpeg": {"jpeg_quality": None}}
        return replace(self, **{k: v for effect in effects for k, v in none[effect].items()})

    def gains(self, photo: int) -> torch.Tensor:
        """(3,) linear gain of photo 0 (reflection) or 1 (transmission): exposure x white balance."""
        return torch.tensor(self.white_balance) * self.exposure * self.photo_exposure[photo]

    def apply(self, radiance: torch.Tensor, photo: int, rig: CaptureRig) -> torch.Tensor:
        """The display-space photo (N, N, 3) in [0, 1] of a render's sharp linear ``radiance`` (N x N
        phone pixels, N a multiple of the film's size, or the film's size itself)."""
        n = radiance.shape[0]
        film = rig.film_size / n  # film pixels per image pixel
        image = self._warped(radiance, film)
        image = image * self._falloff(n).to(image)[..., None]
        image = gaussian_blur_products(image, self.blur_px / film)  # bit-identical sets across versions
        image = image * self.gains(photo).to(image)
        generator = torch.Generator().manual_seed(self.seed * 2 + photo)
        std = torch.sqrt(self.noise_gain * image.clamp_min(0) + self.read_noise ** 2) / film
        image = image + std * torch.randn(image.shape, generator=generator, dtype=image.dtype)
        vignette = CameraSamples(rig, n, 1, dtype=image.dtype).pixel_falloff(rig.vignette_sigma_px)
        return display_transform(image.clamp_min(0), rig.gamma, rig.clamp, vignette).clamp(0, 1)

    def displacement(self, x_px, y_px):
        """d(p) = A (sin(2 pi x / L_x + phi_x), sin(2 pi y / L_y + phi_y)) (film pixels) at film pixel
        coordinates (x across, y down; numbers or arrays): the photo shows the sample's radiance at p + d(p)."""
        (lx, ly), (px, py) = self.warp_period_px, self.warp_phase
        return (self.warp_px * np.sin(2 * math.pi * np.asarray(x_px) / lx + px),
                self.warp_px * np.sin(2 * math.pi * np.asarray(y_px) / ly + py))

    def spacing_change(self, x_px: float, y_px: float) -> tuple[float, float]:
        """The warp's relative change of the yarn frequency at film pixel (x, y), across x and down y:
        d'(p) = 2 pi A / L cos(2 pi p / L + phi) (the photo shows the radiance at p + d(p), so its
        yarns are 1 + d'(p) times as dense there as the sample's own)."""
        (lx, ly), (px, py) = self.warp_period_px, self.warp_phase
        return (2 * math.pi * self.warp_px / lx * math.cos(2 * math.pi * x_px / lx + px),
                2 * math.pi * self.warp_px / ly * math.cos(2 * math.pi * y_px / ly + py))

    def _warped(self, image: torch.Tensor, film: float) -> torch.Tensor:
        n = image.shape[0]
        centres = torch.arange(n, dtype=torch.float64) + 0.5
        rows, cols = torch.meshgrid(centres, centres, indexing="ij")
        amplitude = self.warp_px / film
        (lx, ly), (px, py) = (p / film for p in self.warp_period_px), self.warp_phase
        x = cols + amplitude * torch.sin(2 * math.pi * cols / lx + px)
        y = rows + amplitude * torch.sin(2 * math.pi * rows / ly + py)
        grid = torch.stack((x / n * 2 - 1, y / n * 2 - 1), dim=-1)[None].to(image.dtype)
        warped = F.grid_sample(image.permute(2, 0, 1)[None], grid, mode="bilinear", padding_mode="reflection",
                               align_corners=False)
        return warped[0].permute(1, 2, 0)

    def _falloff(self, n: int) -> torch.Tensor:
        tilt_x, tilt_y, bowl, offset = self.falloff
        coords = (torch.arange(n, dtype=torch.float64) + 0.5) / n * 2 - 1   # -1 .. 1 across the image
        y, x = torch.meshgrid(coords, coords, indexing="ij")
        r2 = (x - offset) ** 2 + (y + offset) ** 2
        return (1 + tilt_x * x + tilt_y * y + bowl * r2 / 2).clamp_min(0.2)


def phone_jpeg(image, quality: int | None, size: int) -> np.ndarray:
    """``image`` (RGB in [0, 1] at the phone's resolution) as its JPEG of quality ``quality`` looks
    after the resize to ``size`` x ``size``: compressed and decoded at the phone's resolution, then
    area-downsampled (quality None: only the resize). A phone compresses at its own resolution and
    the photo is resized afterwards, so its 8-pixel blocks are a fraction of a working pixel, not a
    grid at size / 8 cycles."""
    array = image.detach().cpu().numpy() if hasattr(image, "detach") else image
    rgb = np.clip(np.asarray(array, dtype=np.float64), 0.0, 1.0)
    if quality is None:
        return cv2.resize(rgb, (size, size), interpolation=cv2.INTER_AREA)
    data = np.round(rgb * 255).astype(np.uint8)[..., ::-1]
    ok, encoded = cv2.imencode(".jpg", np.ascontiguousarray(data), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise OSError("JPEG encoding failed")
    decoded = cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1].astype(np.float32) / 255
    return cv2.resize(decoded, (size, size), interpolation=cv2.INTER_AREA).astype(np.float64)
