"""Image operations of the forward model, differentiable (torch): the camera's point spread, the
display transform of spec section 1, and the linear-light area downsample that compares a render
with a photo at a working size.

    blurred     = radiance convolved with a Gaussian of sigma pixels (separable, mirrored borders)
    displayed   = min(radiance, clamp) ** (1 / gamma) * vignette
    downsampled = (area mean of display ** gamma) ** (1 / gamma)
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F


def display_transform(radiance: torch.Tensor, gamma: float, clamp: float,
                      vignette: torch.Tensor | None) -> torch.Tensor:
    """min(radiance, clamp) ** (1 / gamma) * vignette, with a finite gradient at 0.

    The exact power is used in the forward pass; the gradient is that of the power of
    max(radiance, 1e-6), so black pixels do not produce infinite gradients.
    """
    clipped = radiance.clamp(0.0, clamp)
    exact = clipped.pow(1.0 / gamma)
    safe = clipped.clamp_min(1e-6).pow(1.0 / gamma)
    out = safe + (exact - safe).detach()
    return out * vignette[..., None] if vignette is not None else out


def gaussian_blur(image: torch.Tensor, sigma: float) -> torch.Tensor:
    """Separable Gaussian blur of an (H, W, C) image, standard deviation ``sigma`` pixels, with
    mirrored borders (differentiable; the identity for sigma <= 0)."""
    if sigma <= 1e-3:
        return image
    radius = max(1, min(int(math.ceil(3.0 * sigma)), image.shape[0] - 1, image.shape[1] - 1))
    x = torch.arange(-radius, radius + 1, device=image.device, dtype=image.dtype)
    kernel = torch.exp(-0.5 * (x / sigma) ** 2)
    kernel = kernel / kernel.sum()
    channels = image.shape[2]
    planes = image.permute(2, 0, 1)[None]
    planes = F.pad(planes, (radius, radius, radius, radius), mode="reflect")
    planes = F.conv2d(planes, kernel.view(1, 1, 1, -1).expand(channels, 1, 1, -1), groups=channels)
    planes = F.conv2d(planes, kernel.view(1, 1, -1, 1).expand(channels, 1, -1, 1), groups=channels)
    return planes[0].permute(1, 2, 0)


def downsample_linear(image: torch.Tensor, size: int, gamma: float = 2.2) -> torch.Tensor:
    """Area downsample of a display-space (H, W, 3) image, averaged in linear light."""
    if image.shape[0] == size:
        return image
    linear = image.clamp_min(0).pow(gamma).permute(2, 0, 1)[None]
    return F.adaptive_avg_pool2d(linear, size)[0].permute(1, 2, 0).pow(1 / gamma)
