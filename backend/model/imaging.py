"""Image operations of the forward model, differentiable (torch): the camera's point spread, the
display transform of spec section 1, and the linear-light area downsample that compares a render
with a photo at a working size.

    blurred     = radiance convolved with a Gaussian of sigma pixels (separable, mirrored borders;
                  a depthwise convolution for short kernels on colour images, otherwise a product
                  with precomputed blur matrices)
    displayed   = min(radiance, clamp) ** (1 / gamma) * vignette
    downsampled = (area mean of display ** gamma) ** (1 / gamma)
"""
from __future__ import annotations

import functools
import math

import numpy as np
import torch
import torch.nn.functional as F

from .param_tensors import as_float


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


NO_BLUR_PX = 1e-3  # a Gaussian blur this narrow or narrower is none (the identity)
CONV_TAPS_PER_PIXEL = 0.1  # the convolution where a kernel's taps are at most this share of the image's side


def gaussian_blur(image: torch.Tensor, sigma: float | torch.Tensor, value: float | None = None) -> torch.Tensor:
    """Separable Gaussian blur of an (H, W, C) image, standard deviation ``sigma`` pixels, with
    mirrored borders (differentiable; the identity for sigma <= 0): the weights
    exp(-t^2 / 2 sigma^2) / sum over |t| <= radius = ceil(3 sigma) (at most min(H, W) - 1).

    A 0-d tensor ``sigma`` is differentiable too (the fit estimates the camera blur by gradient with
    the fabric's parameters): its weights are computed in torch (:func:`gaussian_taps`) and applied
    by the convolution; the radius follows its value and carries no gradient.

    Two ways to the same sums (within float rounding), whichever is cheaper:

    - ``B_H @ plane @ B_W^T`` per channel with the blur matrices of :func:`blur_matrix`: its cost
      (n^3 per plane) is the same at any radius, where a convolution's grows with it (the spectrum's
      16-px high-pass has 97 taps at 512 px);
    - a depthwise convolution of the mirror-padded image, rows then columns (:func:`_convolved`),
      for colour images whose kernel has at most CONV_TAPS_PER_PIXEL taps per pixel of the side:
      faster for the camera's short kernels. On a single plane (the spectrum's blurs) PyTorch's
      convolution is the slower, so one channel keeps the products.

    ``value``: a tensor ``sigma``'s value where the caller has read it already (each read of a GPU
    tensor waits for the device).
    """
    value = as_float(sigma) if value is None else value
    if value <= NO_BLUR_PX:
        return image
    height, width = image.shape[0], image.shape[1]
    limit = min(height, width) - 1  # one radius for both axes, as the add-on's preview blur
    radius = blur_radius(value, limit)
    if isinstance(sigma, torch.Tensor):
        return _convolved(image, gaussian_taps(sigma, radius, image.dtype), radius)
    if image.shape[2] > 1 and 2 * radius + 1 <= CONV_TAPS_PER_PIXEL * min(height, width):
        return _convolved(image, gaussian_kernel(sigma, radius), radius)
    return gaussian_blur_products(image, sigma)


def subpixel_blur(image: torch.Tensor, sigma: float | torch.Tensor, value: float | None = None) -> torch.Tensor:
    """The camera blur of ``sigma`` pixels acting on an image of sub-pixels (2 H, 2 W, C): blurred
    there (``2 sigma`` sub-pixels, :func:`gaussian_blur`), then each pixel the mean of its 2 x 2
    (H, W, C), as a sensor integrates the light the optics blurred.

    The order matters where the image holds frequencies near or above the pixels' Nyquist frequency
    (a dense weave's harmonics at 2-3 px per yarn, G(f) = exp(-2 pi^2 sigma^2 f^2), f in cycles per
    pixel): a harmonic at f > 1/2 is attenuated by G(f) before the pixels sample it (at 0.7 and a
    blur of 0.9 px, 4e-4), whereas blurring the pixel means acts on its alias at 1 - f (G(0.3) =
    0.24): a false lattice. And a Gaussian's weights sampled at whole pixels pass f at its response
    folded about the pixel grid, G(f) + G(1 - f): twice the optics' at Nyquist. On sub-pixels both
    folds move to 1 cycle per pixel, where the Gaussian has nothing left (tests/test_render.py).
    ``value``: as :func:`gaussian_blur`'s.
    """
    value = as_float(sigma) if value is None else value
    if value <= NO_BLUR_PX:
        return _pooled(image)
    radius = blur_radius(2.0 * value, min(image.shape[0], image.shape[1]) - 1)
    # The blur and the 2 x 2 mean in one kernel (the Gaussian's taps convolved with (1/2, 1/2)),
    # evaluated at every other sub-pixel: the same sums as subpixel_blur_reference's, and the whole
    # blurred sub-pixel image is never made.
    if isinstance(sigma, torch.Tensor):
        taps = gaussian_taps(2.0 * sigma, radius, image.dtype)
        return _convolved(image, 0.5 * (F.pad(taps, (1, 0)) + F.pad(taps, (0, 1))), radius, stride=2)
    return _convolved(image, np.convolve(gaussian_kernel(2.0 * sigma, radius), [0.5, 0.5]), radius, stride=2)


def subpixel_blur_reference(image: torch.Tensor, sigma: float) -> torch.Tensor:
    """:func:`subpixel_blur` step by step: the whole sub-pixel image blurred, then the 2 x 2 means."""
    return _pooled(gaussian_blur(image, 2.0 * sigma))


def _pooled(image: torch.Tensor) -> torch.Tensor:
    """The 2 x 2 means of an (2 H, 2 W, C) image: (H, W, C)."""
    return F.avg_pool2d(image.permute(2, 0, 1)[None], 2)[0].permute(1, 2, 0)


def gaussian_blur_products(image: torch.Tensor, sigma: float) -> torch.Tensor:
    """:func:`gaussian_blur` always by the matrix products ``B_H @ plane @ B_W^T``: the photo-like
    benchmark's phone (:mod:`devtools.phone`) blurs this way, so that its images stay bit-identical
    to those of earlier versions (the convolution rounds differently, which moves a few of their
    JPEG pixels)."""
    if sigma <= NO_BLUR_PX:
        return image
    height, width = image.shape[0], image.shape[1]
    limit = min(height, width) - 1
    rows = blur_matrix(height, sigma, limit, image.dtype, image.device)
    cols = rows if width == height else blur_matrix(width, sigma, limit, image.dtype, image.device)
    planes = image.permute(2, 0, 1)
    return torch.matmul(torch.matmul(rows, planes), cols.T).permute(1, 2, 0)


def blur_radius(sigma: float, limit: int) -> int:
    """Taps on each side of a Gaussian kernel of ``sigma`` pixels: ceil(3 sigma), at least 1, at most ``limit``."""
    return max(1, min(int(math.ceil(3.0 * sigma)), limit))


def gaussian_kernel(sigma: float, radius: int) -> np.ndarray:
    """The normalised weights exp(-t^2 / 2 sigma^2) of the offsets t = -radius..radius (float64)."""
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (offsets / sigma) ** 2)
    return kernel / kernel.sum()


def gaussian_taps(sigma: torch.Tensor, radius: int, dtype=torch.float32) -> torch.Tensor:
    """:func:`gaussian_kernel` of a 0-d tensor ``sigma`` in torch: differentiable with respect to it."""
    offsets = torch.arange(-radius, radius + 1, dtype=dtype, device=sigma.device)
    kernel = torch.exp(-0.5 * (offsets / sigma.to(dtype)) ** 2)
    return kernel / kernel.sum()


def _convolved(image: torch.Tensor, taps: np.ndarray | torch.Tensor, radius: int, stride: int = 1) -> torch.Tensor:
    """A depthwise convolution by ``taps`` along the rows, then the columns, of the image
    mirror-padded by ``radius`` ("reflect": the edge sample is not repeated, as in
    :func:`blur_matrix`), evaluated every ``stride`` pixels: :func:`gaussian_blur` with a Gaussian's
    taps, :func:`subpixel_blur` with its blur-and-mean taps at stride 2.

    At stride 1 as a sum of shifted copies of the padded planes, one per tap (:func:`_shifted_sums`):
    the same values as PyTorch's depthwise convolution (:func:`_depthwise_conv`, its plain twin, which
    the strided blur keeps) and its gradients to float rounding, at half its time or less for the
    camera's kernels (forward and backward of a 512-px colour image at sigma 0.45-2.8 px, 2 threads).
    """
    planes = F.pad(image.permute(2, 0, 1)[None], (radius, radius, radius, radius), mode="reflect")
    if stride == 1:
        return _shifted_sums(planes[0], taps).permute(1, 2, 0)
    return _depthwise_conv(planes, taps, stride)[0].permute(1, 2, 0)


def _shifted_sums(planes: torch.Tensor, taps: np.ndarray | torch.Tensor) -> torch.Tensor:
    """The valid part of the convolution of (C, H, W) ``planes`` by ``taps`` along W, then along H:
    out = sum_k taps[k] shift_k(planes), in the order of the taps. A tensor's taps stay differentiable."""
    weights = taps if isinstance(taps, torch.Tensor) else [float(t) for t in taps]
    differentiable = isinstance(weights, torch.Tensor)

    def along(x: torch.Tensor, dim: int) -> torch.Tensor:
        span = x.shape[dim] - len(weights) + 1
        total = x.narrow(dim, 0, span) * weights[0]
        for k in range(1, len(weights)):
            part = x.narrow(dim, k, span)
            total = torch.addcmul(total, part, weights[k]) if differentiable else total.add(part, alpha=weights[k])
        return total

    return along(along(planes, 2), 1)


def _depthwise_conv(planes: torch.Tensor, taps: np.ndarray | torch.Tensor, stride: int = 1) -> torch.Tensor:
    """PyTorch's depthwise convolution of padded (1, C, H, W) ``planes`` by ``taps`` along W, then H,
    evaluated every ``stride`` pixels."""
    kernel = taps if isinstance(taps, torch.Tensor) else _kernel(tuple(taps), planes.dtype, planes.device)
    channels = planes.shape[1]
    planes = F.conv2d(planes, kernel.view(1, 1, 1, -1).expand(channels, 1, 1, -1), stride=(1, stride),
                      groups=channels)
    return F.conv2d(planes, kernel.view(1, 1, -1, 1).expand(channels, 1, -1, 1), stride=(stride, 1),
                    groups=channels)


@functools.lru_cache(maxsize=32)
def _kernel(taps: tuple[float, ...], dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """Taps as a tensor, made once per device: a copy to a GPU at every blur would wait for it. Read
    it, never write to it."""
    return torch.tensor(taps, dtype=dtype, device=device)


@functools.lru_cache(maxsize=32)
def blur_matrix(n: int, sigma: float, limit: int, dtype=torch.float32, device="cpu") -> torch.Tensor:
    """(n, n) matrix of a 1-D Gaussian blur with mirrored borders: row i holds the weights
    exp(-t^2 / 2 sigma^2) / sum (|t| <= radius = :func:`blur_radius`) of the samples
    i + t, indices reflected about the first and last sample without repeating them (numpy's and
    torch's "reflect")."""
    radius = blur_radius(sigma, limit)
    offsets = np.arange(-radius, radius + 1)
    kernel = gaussian_kernel(sigma, radius)
    source = np.arange(n)[:, None] + offsets[None, :]
    source = np.abs(source)
    source = np.where(source > n - 1, 2 * (n - 1) - source, source)
    flat = (np.arange(n)[:, None] * n + source).ravel()  # mirrored samples may repeat: weights add up
    matrix = np.bincount(flat, weights=np.tile(kernel, n), minlength=n * n).reshape(n, n)
    return torch.tensor(matrix, dtype=dtype, device=device)


def downsample_linear(image: torch.Tensor, size: int, gamma: float = 2.2) -> torch.Tensor:
    """Area downsample of a display-space (H, W, 3) image, averaged in linear light."""
    if image.shape[0] == size:
        return image
    linear = image.clamp_min(0).pow(gamma).permute(2, 0, 1)[None]
    return F.adaptive_avg_pool2d(linear, size)[0].permute(1, 2, 0).pow(1 / gamma)
