"""The photos' light falloff: the smooth unevenness of a real capture's light that the rig's point
lamps do not model.

A phone photo of the rig is never lit exactly as the rig says: the lamps are not ideal points, the
holder and the diffuser shade, the phone's own lens shading is not the rig's vignetting. What that
leaves is a smooth gain across each photo (a render of the best fit and a real photo differ by a
tilt in log brightness across the reflection photo). Each photo gets a gain on its linear radiance,
after the camera blur and before the display transform:

    L'(x, y) = L(x, y) exp(c_x x + c_y y + c_r (x^2 + y^2 - mean(x^2 + y^2)))

with x to the right and y down the image, both in [-1, 1] across it. The basis has zero mean over
the image, so the overall level stays with the albedos; only the shape is the light's.

A fit does not optimise c: :func:`solve` computes it for every render it compares with a photo,
as the least-squares fit (with a constant) of log(photo / render) over BLOCKS x BLOCKS block means
of the luminance in linear light, leaving out blocks where either image is clipped or black, and
clamped to |c| <= LIMIT. Solved in closed form, the nuisance costs nothing per step, and a tilt the
rig cannot make no longer pushes roughness or the albedos to imitate it. The gain is at most second
order across the whole image, so it cannot make or remove a highlight, which is where roughness is
read. Gradients do not flow through the solve (the coefficients are the minimiser of the colour
term, so its derivative with respect to them is near zero there).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import torch
import torch.nn.functional as F

BLOCKS = 16
LIMIT = 0.5           # |c|: a gain of exp(0.5) = 1.65 at an edge, beyond any lamp falloff of the rig
CLIPPED = 0.98        # display values at or above this fraction of the vignetted maximum count as clipped
DARK = 1e-5           # linear block means below this are not compared (log of nothing)
NO_LIGHT = (0.0, 0.0, 0.0)


@functools.lru_cache(maxsize=8)
def basis(size: int, dtype=torch.float32, device="cpu") -> torch.Tensor:
    """(3, size, size): x, y and the centred x^2 + y^2 at the pixel centres, x and y in [-1, 1].
    Cached (every loss evaluation applies and solves a light at the same sizes): read it, never
    write to it."""
    coords = (torch.arange(size, dtype=torch.float64, device=device) + 0.5) / size * 2 - 1
    y, x = torch.meshgrid(coords, coords, indexing="ij")
    r2 = x * x + y * y
    return torch.stack((x, y, r2 - r2.mean())).to(dtype)


@dataclass(frozen=True)
class PhotoLight:
    """The falloff coefficients (c_x, c_y, c_r) of the reflection and the transmission photo."""

    reflection: tuple[float, float, float] = NO_LIGHT
    transmission: tuple[float, float, float] = NO_LIGHT

    def gain(self, photo: int, size: int, dtype=torch.float32, device="cpu") -> torch.Tensor:
        """(size, size) linear gain of photo 0 (reflection) or 1 (transmission)."""
        c = torch.tensor(self.reflection if photo == 0 else self.transmission, dtype=dtype, device=device)
        return _gain(c, size)

    def apply(self, reflection: torch.Tensor, transmission: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The two (size, size, 3) linear radiance images under the photos' light."""
        if self.flat:
            return reflection, transmission
        # both photos' coefficients in one copy to the images' device (each copy to a GPU waits for it)
        c = torch.tensor((self.reflection, self.transmission), dtype=reflection.dtype, device=reflection.device)
        return tuple(image * _gain(c[k], image.shape[0])[..., None]
                     for k, image in enumerate((reflection, transmission)))

    @property
    def flat(self) -> bool:
        return self.reflection == NO_LIGHT and self.transmission == NO_LIGHT

    def to_dict(self) -> dict:
        return {"reflection": [round(c, 5) for c in self.reflection],
                "transmission": [round(c, 5) for c in self.transmission]}

    @classmethod
    def from_dict(cls, data: dict | None) -> "PhotoLight":
        if not data:
            return cls()
        return cls(*(tuple(float(c) for c in data[k]) for k in ("reflection", "transmission")))


def _gain(c: torch.Tensor, size: int) -> torch.Tensor:
    """(size, size) linear gain exp(c . basis) of the coefficients ``c`` (3,)."""
    return torch.exp(torch.einsum("k,kij->ij", c, basis(size, c.dtype, c.device)))


def linear_photo(display: torch.Tensor, gamma: float, vignette: torch.Tensor | None
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """(linear radiance, unclipped mask) of a display-space photo (size, size, 3) taken through the
    rig's vignetting: the radiance it shows, where it shows it."""
    v = torch.ones(display.shape[:2], dtype=display.dtype, device=display.device) if vignette is None else vignette
    relative = display / v[..., None].clamp_min(1e-6)
    unclipped = (relative < CLIPPED).all(dim=-1)
    return relative.clamp(0, 1) ** gamma, unclipped


def solve(render: torch.Tensor, render_ok: torch.Tensor, photo: torch.Tensor, photo_ok: torch.Tensor
          ) -> tuple[float, float, float]:
    """(c_x, c_y, c_r) fitting log(photo / render) over the BLOCKS x BLOCKS blocks where neither is
    clipped nor black. ``render`` and ``photo`` are (size, size) linear luminances, the masks are True
    where a pixel is usable."""
    return solve_blocks(block_means(render, render_ok, photo, photo_ok).cpu())


def block_means(render: torch.Tensor, render_ok: torch.Tensor, photo: torch.Tensor, photo_ok: torch.Tensor
                ) -> torch.Tensor:
    """(3, BLOCKS^2) float64 on the images' device: per block the share of usable pixels, the render's
    and the photo's mean (:func:`solve`'s inputs reduced to what the least squares read)."""
    with torch.no_grad():
        def blocks(image):
            return F.adaptive_avg_pool2d(image[None, None].double(), BLOCKS)[0, 0].ravel()

        return torch.stack((blocks((render_ok & photo_ok).double()), blocks(render), blocks(photo)))


def solve_blocks(means: torch.Tensor) -> tuple[float, float, float]:
    """:func:`solve` from its :func:`block_means`, on the CPU: a fit on a GPU brings the block means of
    both photos over in one copy (16 x 16 blocks: a least-squares problem too small for a device)."""
    with torch.no_grad():
        usable, r, p = means
        ok = usable > 0.99
        ok &= (r > DARK) & (p > DARK)
        if int(ok.sum()) < 16:  # too little of the image to see a falloff on
            return NO_LIGHT
        design = torch.cat((torch.ones(1, BLOCKS, BLOCKS, dtype=torch.float64, device=means.device),
                            basis(BLOCKS, torch.float64, means.device)), 0).reshape(4, -1).T[ok]
        ratio = (torch.log(p) - torch.log(r))[ok]
        coefficients = torch.linalg.lstsq(design, ratio[:, None]).solution[1:, 0]
        return tuple(float(c) for c in coefficients.clamp(-LIMIT, LIMIT))
