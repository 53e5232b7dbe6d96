"""Camera samples of the rig: where each pixel sample lands on the fabric, and the directions and
irradiance factors the BSDF needs there (spec section 1).

Pixel (row r, column c) of an N x N film covers x in [c, c + 1] * V / N and y in [-(r + 1), -r] * V / N
(row 0 is the largest y). Each pixel takes ``spp`` samples: the first k^2 (k = floor(sqrt(spp))) on a
stratified k x k jitter, any others uniform. With a fixed ``seed`` the pattern is identical on every
call (the optimiser's fixed jitter); the random numbers are a hash of (seed, pixel, sample), so the
pattern does not depend on chunking.

Per sample: world position (float64, for the tile lookup; moved by the photos' uneven yarn
spacing where the camera has one, :mod:`.spacing_warp`: only where the weave is looked up moves),
``wi`` (to the camera), and for each light ``wo``, the unit half vector ``h = normalize(wi + wo)``
((0, 0, 1) where it vanishes) and ``irradiance = intensity / distance^2``. Everything is computed
in float64 and stored in the render dtype. Pixel-unit quantities (vignetting, glow) are in pixels
of the rig's ``film_size`` film, so a smaller render is a downsample of the full one.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import torch

from ..core.rig import CaptureRig
from . import rng
from .frames import dot, normalize
from .spacing_warp import SpacingWarp


@dataclass
class LightSamples:
    wo: torch.Tensor          # (3, S) unit, to the light
    half: torch.Tensor        # (3, S) unit half vector of wi and wo
    irradiance: torch.Tensor  # (S,) intensity / distance^2


@dataclass
class SampleChunk:
    """Samples of film rows [row0, row1): S = (row1 - row0) * size * spp, pixel-major, sample-minor."""

    row0: int
    row1: int
    x: torch.Tensor           # (S,) float64 world x
    y: torch.Tensor           # (S,) float64 world y
    wi: torch.Tensor          # (3, S)
    front: LightSamples
    back: LightSamples

    @cached_property
    def wide(self) -> tuple[torch.Tensor, ...]:
        """The x and y of (wi, front wo, front half, back wo, back half) in float64 (2, S): every
        geometry state projects them on each layer's yarn frame in float64 (:mod:`.projections`), so
        they are converted once per chunk instead of once per layer and state."""
        return tuple(v[:2].to(torch.float64) for v in (self.wi, self.front.wo, self.front.half,
                                                      self.back.wo, self.back.half))


class CameraSamples:
    def __init__(self, rig: CaptureRig, size: int, spp: int, seed: int = 0, device="cpu", dtype=torch.float32,
                 warp: SpacingWarp | None = None):
        if size < 1 or spp < 1:
            raise ValueError(f"size and spp must be positive (got size {size}, spp {spp})")
        self.rig, self.size, self.spp, self.seed = rig, int(size), int(spp), int(seed)
        self.warp = warp
        self.device, self.dtype = torch.device(device), dtype

    def jitter(self, row0: int, row1: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(jx, jy) in [0, 1) of every sample of rows [row0, row1), float64, shape (rows, size, spp).

        Each film row draws from its own generator, seeded by a hash of (seed, row), so a chunk's
        pattern does not depend on how the film was split into chunks.
        """
        draws = []
        for row in range(row0, row1):
            # drawn on the CPU whatever the device (and the default device): the same jitter everywhere
            gen = torch.Generator(device="cpu").manual_seed(rng.hash32_int(self.seed * 1_000_003 + row))
            draws.append(torch.rand((2, self.size, self.spp), generator=gen, dtype=torch.float64, device="cpu"))
        u = torch.stack(draws, 1).to(self.device)  # (2, rows, size, spp)
        k = math.isqrt(self.spp)
        sample = torch.arange(self.spp, dtype=torch.int64, device=self.device)
        stratified = sample < k * k
        strata = torch.stack(((sample % k).double(), (sample // k).double()))[:, None, None, :]
        jitter = torch.where(stratified, (strata + u) / k, u)
        return jitter[0], jitter[1]

    def chunk(self, row0: int, row1: int) -> SampleChunk:
        jx, jy = self.jitter(row0, row1)
        d = self.device
        rows = torch.arange(row0, row1, device=d, dtype=torch.float64)[:, None, None]
        cols = torch.arange(self.size, device=d, dtype=torch.float64)[None, :, None]
        scale = self.rig.view_size / self.size
        chunk = self.at_points(((cols + jx) * scale).reshape(-1), (-(rows + jy) * scale).reshape(-1), row0, row1)
        if self.warp is not None:  # the weave is looked up where the photos' uneven spacing puts it
            film = self.rig.film_size / self.size  # film pixels per pixel
            px, py = ((cols + jx) * film).reshape(-1), ((rows + jy) * film).reshape(-1)
            dx, dy = self.warp.displacement(px, py, self.rig.film_size)
            world = self.rig.view_size / self.rig.film_size
            chunk.x, chunk.y = (px + dx) * world, -(py + dy) * world
        return chunk

    def at_points(self, x: torch.Tensor, y: torch.Tensor, row0: int = 0, row1: int = 0) -> SampleChunk:
        """Samples at given world positions on the fabric plane (float64 x, y of shape (S,))."""
        rig, d = self.rig, self.device
        x, y = x.to(device=d, dtype=torch.float64), y.to(device=d, dtype=torch.float64)
        p = torch.stack((x, y, torch.zeros_like(x)))
        cam = torch.tensor(rig.camera_position(), dtype=torch.float64, device=d)[:, None]
        wi = normalize(cam - p)
        lights = []
        for which in ("front", "back"):
            to_light = torch.tensor(rig.light_position(which), dtype=torch.float64, device=d)[:, None] - p
            dist2 = dot(to_light, to_light)
            wo = to_light * torch.rsqrt(dist2)
            half = wi + wo
            length2 = dot(half, half)
            half = torch.where(length2 > 1e-24, half * torch.rsqrt(length2.clamp_min(1e-300)),
                               torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64, device=d)[:, None])
            lights.append(LightSamples(wo.to(self.dtype), half.to(self.dtype),
                                       (rig.intensity(which) / dist2).to(self.dtype)))
        return SampleChunk(row0, row1, x, y, wi.to(self.dtype), *lights)

    def row_chunks(self, max_samples: int) -> list[tuple[int, int]]:
        """Row ranges holding at most ``max_samples`` samples each (at least one row)."""
        rows = max(1, max_samples // (self.size * self.spp))
        return [(r, min(r + rows, self.size)) for r in range(0, self.size, rows)]

    def pixel_falloff(self, sigma_px: float) -> torch.Tensor:
        """exp(-d^2 / sigma^2) at pixel centres, normalised to a maximum of 1, shape (size, size).

        d is measured in pixels of the rig's film (``film_size``), from the film centre.
        """
        n, film = self.size, self.rig.film_size
        centres = (torch.arange(n, dtype=torch.float64, device=self.device) + 0.5) * (film / n) - film / 2
        d2 = centres[:, None] ** 2 + centres[None, :] ** 2
        mask = torch.exp(-d2 / (sigma_px * sigma_px))
        return (mask / mask.max()).to(self.dtype)
