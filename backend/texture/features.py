"""Weight-free texture statistics of an image (no downloaded network), differentiable.

A woven fabric photographed by the rig is a periodic texture on a known lattice (see
:mod:`backend.texture.lattice`): all of its structure lives at the harmonics (m a, n b). Statistics are
taken on the *linearised* image (display value ** gamma), where a render's Monte Carlo noise and a
camera's noise are zero-mean: averaging display values would bias noisy pixels (the gamma curve is
concave), and a 4-spp render of a sharp highlight would look darker than the photo of it. The
descriptor of an (H, W, 3) display-space image is:

- ``colour``: the 16 x 16 area downsample (the paper's pixel term: tone, colour, lighting gradient);
- ``harmonics``: for a 3 x 3 grid of regions, the magnitude of the Hann-windowed Fourier transform
  of each RGB channel at the lattice harmonics |m| <= 4, 0 <= n <= 4 (half plane), divided by the
  region's mean colour (modulation depth). Phase-invariant (a translated weave matches), robust to
  pixel noise (it averages out at a single frequency) and regional, so it sees how the texture's
  contrast changes with the lighting angle across the image (roughness, height, twist). Computed at
  the image's own lattice, so a render and a photo are compared harmonic by harmonic even when
  their lattices differ slightly. On a pixel grid a frequency past Nyquist is automatically folded,
  exactly as in the image. Each region also gets a noise floor: the median magnitude at the
  off-lattice frequencies (m + 1/2, n + 1/2);
- ``quantiles``: 24 luminance quantiles (the highlight distribution);
- ``spectrum``: the standardised log power spectrum of the high-passed display luminance over the
  central half band (:func:`log_spectrum`): the project's spectrum metric
  (:func:`backend.image.metrics.spectrum_corr`) at the working size. It sees every peak the image
  has, wherever it sits, smoothed over 1.5 bins: a lattice a little off (a turn the rotation
  estimate missed, uneven yarn spacing, a framing difference) still matches where the exact-frequency
  harmonics above lose it; and it is what the fit is judged by.

:func:`descriptor_terms` compares two descriptors: L1 of the 16 x 16 colours, L1 of the log
harmonic amplitudes above a noise floor, L1 of the quantiles.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from ..image.metrics import SPECTRUM_DC_HALF, SPECTRUM_HIGHPASS_PX, SPECTRUM_KEEP, SPECTRUM_POWER_BLUR
from ..image.tone import LUMA
from ..model.imaging import blur_matrix, gaussian_blur
from .frequencies import turned_frequencies

QUANTILES = 24
ORDER = 4
REGIONS = 3
MIN_FLOOR = 1e-3  # modulation depth below which harmonics are treated as noise


def luminance(image: torch.Tensor) -> torch.Tensor:
    return image @ _luma(image.dtype, image.device)


@functools.lru_cache(maxsize=8)
def _luma(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """LUMA as a tensor, made once per device (a copy to a GPU at every use would wait for it)."""
    return torch.tensor(LUMA, dtype=dtype, device=device)


def colour16(image: torch.Tensor) -> torch.Tensor:
    """16 x 16 area downsample, (3, 16, 16)."""
    return F.adaptive_avg_pool2d(image.permute(2, 0, 1)[None], 16)[0]


QUANTILE_SIZE = 256  # quantiles are read at most at this size: a 512-px render has 4 samples per pixel


def luminance_quantiles(image: torch.Tensor) -> torch.Tensor:
    """QUANTILES quantiles of the luminance of a linear image, area-pooled to at most QUANTILE_SIZE
    pixels: the per-pixel Monte Carlo noise of a few samples widens the distribution, pooling to 16
    samples per pixel keeps render and photo comparable whatever the working size."""
    pool = image.shape[0] // QUANTILE_SIZE
    if pool > 1:
        image = F.avg_pool2d(image.permute(2, 0, 1)[None], pool)[0].permute(1, 2, 0)
    y = luminance(image).flatten()
    q = torch.linspace(0.02, 0.98, QUANTILES, dtype=y.dtype, device=y.device)
    return torch.quantile(y, q)


def harmonic_indices(order: int = ORDER) -> list[tuple[int, int]]:
    """Lattice harmonics (m, n) with |m|, n <= order in the half plane n > 0 or (n = 0, m > 0)."""
    return [(m, n) for n in range(order + 1) for m in range(-order, order + 1) if n > 0 or m > 0]


class LatticeProbe:
    """Regional Fourier magnitudes of an image at the harmonics of one lattice (a, b).

    a, b: tiles across and down the fabric (cycles per image); ``rotation_deg``, ``skew_deg``: the
    sample's turn and shear in the holder, so harmonic (m, n) sits at the image frequency
    :func:`backend.texture.lattice.turned_frequencies` (m a, n b). The frequency is still one 2D
    plane wave, so the transform stays separable: with the Hann-windowed exponentials
    e_y[k, y] of region row i and e_x[k, x] of region column j (zero outside their band),

        coefficient[i, j, k, c] = sum_y sum_x e_y[k, y] image[y, x, c] e_x[k, x]

    is one real matrix product per row band (the real and imaginary rows of e_y stacked) and one
    batched product over k for every (i, j) at once, in real arithmetic (about half the time of a
    complex einsum per region, forward and backward). The literal sums, region by region and frequency by
    frequency, are :func:`tests.oracles.reference.lattice_coefficients`, which it is tested against.
    """

    def __init__(self, size: int, a: float, b: float, device="cpu", dtype=torch.float32,
                 regions: int = REGIONS, order: int = ORDER, rotation_deg: float = 0.0,
                 skew_deg: float = 0.0):
        self.size, self.a, self.b, self.regions = size, a, b, regions
        self.rotation_deg, self.skew_deg = rotation_deg, skew_deg
        self.harmonics = harmonic_indices(order)
        # Lattice harmonics, then the same count of off-lattice probes for the noise floor.
        ms = torch.tensor([m for m, _ in self.harmonics] + [m + 0.5 for m, _ in self.harmonics], dtype=torch.float64)
        ns = torch.tensor([n for _, n in self.harmonics] + [n + 0.5 for _, n in self.harmonics], dtype=torch.float64)
        fx, fy = turned_frequencies(ms * a, ns * b, rotation_deg, skew_deg)
        self.bounds = [round(k * size / regions) for k in range(regions + 1)]
        probes = len(ms)
        self.ey = []  # per region row: (2 probes, band height), real parts then imaginary parts
        ex = torch.zeros(2, regions, probes, size, dtype=torch.float64)  # (re/im, region column, probe, x)
        band = torch.zeros(regions, size, dtype=torch.float64)           # 1 inside region column j
        for k in range(regions):
            lo, hi = self.bounds[k], self.bounds[k + 1]
            coords = torch.arange(lo, hi, dtype=torch.float64)
            window = torch.hann_window(hi - lo + 2, periodic=False, dtype=torch.float64)[1:-1]
            window = window / window.sum()
            # e^{-2 pi i f x / size} with the window folded in: (probes, band width)
            ey = torch.exp(-2j * math.pi * torch.outer(fy, coords) / size) * window
            self.ey.append(torch.cat((ey.real, ey.imag)).to(device=device, dtype=dtype))
            ex_k = torch.exp(-2j * math.pi * torch.outer(fx, coords) / size) * window
            ex[0, k, :, lo:hi], ex[1, k, :, lo:hi] = ex_k.real, ex_k.imag
            band[k, lo:hi] = 1.0
        # (probes, x, re/im x region column): the right-hand side of the batched product
        self.ex = ex.permute(2, 3, 0, 1).reshape(probes, size, 2 * regions).to(device=device, dtype=dtype)
        areas = torch.tensor([[(self.bounds[i + 1] - self.bounds[i]) * (self.bounds[j + 1] - self.bounds[j])
                               for j in range(regions)] for i in range(regions)], dtype=torch.float64)
        self.column_means = (band / areas[..., None]).to(device=device, dtype=dtype)  # (i, j, x)
        self.dtype = dtype
        self._orders: tuple[torch.Tensor, torch.Tensor] | None = None  # the harmonics' m and n (phase_ramp)

    def __call__(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(coefficients / region mean (regions^2, harmonics, 3), complex; noise floor (regions^2, 1, 3))."""
        r, n, channels = self.regions, self.size, image.shape[2]
        probes = self.ex.shape[0]
        image = image.to(self.dtype)
        rows, sums = [], []
        heights = [self.bounds[i + 1] - self.bounds[i] for i in range(r)]
        for i, band in enumerate(image.split(heights, dim=0)):  # split: its backward is one concatenation
            rows.append((self.ey[i] @ band.reshape(band.shape[0], n * channels)).view(2, probes, n, channels))
            sums.append(band.sum(dim=0))                                             # (x, c)
        # (probes, re/im x region row x channel, x) @ (probes, x, re/im x region column)
        left = torch.stack(rows, dim=1).permute(2, 0, 1, 4, 3).reshape(probes, 2 * r * channels, n)
        products = torch.bmm(left, self.ex).view(probes, 2, r, channels, 2, r)
        real = products[:, 0, :, :, 0] - products[:, 1, :, :, 1]                      # (probes, i, c, j)
        imag = products[:, 0, :, :, 1] + products[:, 1, :, :, 0]
        coeff = torch.complex(real, imag).permute(1, 3, 0, 2).reshape(r * r, probes, channels)
        means = torch.einsum("ixc,ijx->ijc", torch.stack(sums), self.column_means).reshape(r * r, 1, channels)
        stacked = coeff / means.clamp_min(1e-4)
        count = len(self.harmonics)
        # A channel that is black (an albedo of 0) has no noise either: keep a floor of 0.1 %.
        floor = stacked[:, count:].abs().median(dim=1, keepdim=True).values.clamp_min(MIN_FLOOR)
        return stacked[:, :count], floor

    def phase_ramp(self, dx: torch.Tensor, dy: torch.Tensor) -> torch.Tensor:
        """e^{2 pi i (m dx + n dy)} for translations (dx, dy) in tile units: (..., harmonics)."""
        if self._orders is None or self._orders[0].device != dx.device:  # made once: a copy to a GPU waits for it
            self._orders = (torch.tensor([h[0] for h in self.harmonics], dtype=torch.float32, device=dx.device),
                            torch.tensor([h[1] for h in self.harmonics], dtype=torch.float32, device=dx.device))
        m, n = self._orders
        return torch.polar(torch.ones(1, device=dx.device), 2 * math.pi * (dx[..., None] * m + dy[..., None] * n))


@dataclass
class Descriptor:
    colour: torch.Tensor        # (3, 16, 16) display space (area average taken in linear space)
    coefficients: torch.Tensor  # (regions^2, harmonics, 3) complex, relative to the region's mean
    floor: torch.Tensor         # (regions^2, 1, 3) noise floor of their magnitudes
    quantiles: torch.Tensor     # (QUANTILES,) linear luminance
    spectrum: torch.Tensor      # standardised log power spectrum, central half band
    probe: LatticeProbe

    @property
    def harmonics(self) -> torch.Tensor:
        """Modulation depth per harmonic (phase-invariant)."""
        return self.coefficients.abs()


METRIC_SIZE = 512  # the size the spectrum metric reads (the film's): its high-pass scales with the working size


def log_spectrum(image: torch.Tensor, keep: float = SPECTRUM_KEEP) -> torch.Tensor:
    """The standardised log power spectrum of an (N, N, 3) display-space image, as the spectrum metric
    reads it: luminance minus its Gaussian blur (16 px at 512 px), Hann window, |FFT|^2 blurred by 1.5
    bins, the central ``keep`` of the band without the 5 x 5 bins around DC, log, zero mean and unit
    spread. Differentiable."""
    n = image.shape[0]
    y = luminance(image)[..., None]
    y = (y - gaussian_blur(y, SPECTRUM_HIGHPASS_PX * n / METRIC_SIZE))[..., 0]
    window = torch.hann_window(n, periodic=False, dtype=y.dtype, device=y.device)
    spectrum = torch.fft.fftshift(torch.fft.fft2(y * window[:, None] * window[None, :]))
    power = torch.view_as_real(spectrum).square().sum(-1)
    half = int(n * keep / 2)
    # The power's blur (gaussian_blur's matrix products, B P B^T) at the kept bins only: B's rows of the band.
    rows = blur_matrix(n, SPECTRUM_POWER_BLUR, n - 1, power.dtype, power.device)[n // 2 - half: n // 2 + half]
    band = rows @ power @ rows.T
    values = torch.log(band.reshape(-1)[_kept_bins(2 * half, SPECTRUM_DC_HALF, band.device)] + 1e-12)
    return (values - values.mean()) / (values.std() + 1e-8)


@functools.lru_cache(maxsize=8)
def _kept_bins(side: int, dc_half: int, device: torch.device) -> torch.Tensor:
    """Flat indices, in row-major order, of a (side, side) band's bins without the (2 dc_half + 1)^2
    around its centre: made once on the CPU (a boolean mask's indexing would wait for the device at
    every loss evaluation to learn how many bins it keeps)."""
    mask = torch.ones(side, side, dtype=torch.bool, device="cpu")
    centre = side // 2
    mask[centre - dc_half: centre + dc_half + 1, centre - dc_half: centre + dc_half + 1] = False
    return mask.reshape(-1).nonzero()[:, 0].to(device)


def describe(image: torch.Tensor, probe: LatticeProbe, gamma: float = 2.2) -> Descriptor:
    """Descriptor of a display-space image (values in [0, 1], gamma-encoded)."""
    linear = image.clamp_min(0).pow(gamma)
    coefficients, floor = probe(linear)
    return Descriptor(colour16(linear).clamp_min(1e-8).pow(1 / gamma), coefficients, floor,
                      luminance_quantiles(linear), log_spectrum(image), probe)


ALIGN_STEPS = 32


def aligned_difference(render: Descriptor, photo: Descriptor, keep: torch.Tensor, floor: torch.Tensor) -> torch.Tensor:
    """Complex harmonics compared after the best translation of the render per region.

    A translation by (dx, dy) tiles multiplies harmonic (m, n) by e^{-2 pi i (m dx + n dy)}; per
    region the shift maximising the correlation of the significant harmonics (a 32 x 32 grid over
    one tile) is applied, then |render - photo| / (|photo| + 2 floor) is averaged. The relative
    phases of the harmonics carry the shape of the tile (where highlights sit on the yarns), which
    the magnitudes alone lose; the translation itself (the sample's placement) is free.
    """
    probe = render.probe
    grid = (torch.arange(ALIGN_STEPS, dtype=torch.float32, device=keep.device) + 0.5) / ALIGN_STEPS
    dy, dx = torch.meshgrid(grid, grid, indexing="ij")
    ramp = probe.phase_ramp(dx.flatten(), dy.flatten())                       # (shifts, harmonics)
    with torch.no_grad():
        weights = keep / (photo.harmonics + 2 * floor)
        cross = (photo.coefficients.conj() * render.coefficients * weights).sum(-1)  # (regions, harmonics)
        score = torch.einsum("rk,sk->rs", cross, ramp.to(cross.dtype)).real       # (regions, shifts)
        best = ramp[score.argmax(dim=1)].to(render.coefficients.dtype)            # (regions, harmonics)
    shifted = render.coefficients * best[..., None]
    diff = (shifted - photo.coefficients).abs() / (photo.harmonics + 2 * floor)
    return (diff * keep).sum() / keep.sum().clamp_min(1.0)


@dataclass(frozen=True)
class LossWeights:
    colour: float = 10.0
    harmonics: float = 1.0
    aligned: float = 0.5
    quantiles: float = 2.0
    spectrum: float = 1.0


def descriptor_terms(render: Descriptor, photo: Descriptor, significance: float = 4.0) -> dict[str, torch.Tensor]:
    """Unweighted distances. Harmonic magnitudes compare as log(x + f) with f twice the larger of
    the two noise floors, over the harmonics that stand ``significance`` times above the photo's
    floor in either image (the rest is noise in both and would only add noise to the loss)."""
    floor = torch.maximum(render.floor, photo.floor).detach()
    keep = ((photo.harmonics > significance * floor) | (render.harmonics.detach() > significance * floor)).float()
    log_diff = (torch.log(render.harmonics + 2 * floor) - torch.log(photo.harmonics + 2 * floor)).abs()
    return {"colour": (render.colour - photo.colour).abs().mean(),
            "harmonics": (log_diff * keep).sum() / keep.sum().clamp_min(1.0),
            "aligned": aligned_difference(render, photo, keep, floor),
            "quantiles": (render.quantiles - photo.quantiles).abs().mean(),
            "spectrum": 1.0 - (render.spectrum * photo.spectrum).mean()}
