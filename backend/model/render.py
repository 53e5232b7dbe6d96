"""Differentiable renderer of the rig's reflection and transmission images.

    pixel radiance   = mean over the pixel's samples of  BSDF * intensity / distance^2
                       (+ glow * fraction of samples seeing no yarn, transmission only)
    displayed value  = min(gain * blur(radiance), clamp) ** (1 / gamma) * vignette

with blur the rig's camera point spread (a Gaussian; none by default) and gain the photos' light
falloff (:mod:`.photo_light`) when a fit has found one.

Where the blur acts. A camera blurs the light before the sensor integrates it over each pixel. With
``k x k`` stratified samples per pixel, k even, the samples of each quarter of a pixel make a
sub-pixel image at twice the size, which is blurred there and then averaged 2 x 2
(``subpixel_blur=True``, :func:`subpixel_size`, :func:`backend.model.imaging.subpixel_blur`): the
blur takes off a dense weave's harmonics above the pixels' Nyquist frequency before they alias into
a false lattice. Blurring the pixel means instead (``False``, the default) is cheaper and leaves
that alias damped only by the blur. Renders made to be looked at
(:func:`render_pair`: a fit's re-renders, the ``render`` command) use the sub-pixels; a fit's own
renders the pixel means, since sub-pixels at every step make a fit markedly slower without fitting
real photos better. ``None`` (``fit --blur-on auto``) takes the sub-pixels only for blurs under
:data:`AUTO_SUBPIXEL_BELOW_PX`, too narrow to damp the pixel means' aliases. Other sample counts
blur the pixel means.

Work is split into chunks of film rows (``max_chunk_samples`` samples each) so that memory stays
bounded at any resolution and sample count; when gradients are needed over several chunks each
chunk is checkpointed (recomputed in the backward pass) instead of keeping its intermediates.

For optimisation, a :class:`Renderer` keeps its camera samples (the fixed jitter) and the
geometry of the last few discrete states (pattern, tiles, gap scale, twist, and the yarn variation,
:mod:`backend.core.variation`, which a fit never changes), so an iteration
only evaluates the differentiable BSDF. With ``compile=True`` that evaluation is fused by
``torch.compile`` when gradients are wanted (several times faster on the CPU once the compile is
paid; the kernels are cached on disk, :mod:`.compile_cache`), and any compile failure falls back to
the eager path with a warning. Whether to compile is the caller's choice: the fit command's is made
from the machine and the environment by :mod:`backend.app.environment`.

Renders without gradients (a fit's starting points, scans and discrete steps) go through the same
compiled graph once it is known which inputs need gradients (``gradient_inputs``, which a fit
declares, or else those of the last render with gradients): the inputs are given that pattern and
grad mode is on, so nothing compiles again, and the outputs are detached (nothing is kept for a
backward pass). Before that, and in renderers that never take gradients (the final re-renders, the
placement's signatures), they stay eager: a graph of their own would cost a second compile per
working size.

Parameters of :class:`Renderer`:

    ==================  ====================  ==================================================
    rig                 CaptureRig            the rig rendered (the paper's)
    size                px (512)              side of the image; smaller is a downsample of the film
    spp                 (4)                   samples per pixel (k x k stratified, any more uniform)
    seed                (0)                   the camera jitter's seed: one fixed jitter per seed
    options             RenderOptions         the model variant (the full model)
    device, dtype       ("cpu", float32)      where and in which precision to render
    max_chunk_samples   (2^20)                samples per chunk of film rows: bounds the memory
    cache_samples       (2^21)                renders of at most this many samples keep their
                                              camera samples and geometry from call to call
    geometry_cache      (4)                   discrete states whose geometry is kept
    compile             bool (False)          fuse the BSDF's evaluation with ``torch.compile``
    subpixel_blur       True/False/None       where the camera blur acts (above; False)
    gradient_inputs     names (None)          the parameters a fit differentiates; None: those of
                                              the last render with gradients
    warp                SpacingWarp (None)    the photos' uneven yarn spacing (:mod:`.spacing_warp`)
    hand_gradient       bool (True)           the eager path's BSDF gradient by hand
                                              (:mod:`.bsdf_gradient`), else autograd's (benches)
    ==================  ====================  ==================================================
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import warnings
from collections import OrderedDict
from dataclasses import dataclass

import torch

from ..core.options import RenderOptions
from ..core.params import FabricParams
from ..core.rig import DEFAULT_RIG, CaptureRig
from .bsdf import eval_projected
from .bsdf_gradient import eval_with_hand_gradient
from .camera import CameraSamples, SampleChunk
from .compile_cache import allow_cached_custom_gradients, use_persistent_compile_cache
from .geometry import GeometryKey, TileBands, sample_geometry, tile_bands, twisted_fibers
from .imaging import NO_BLUR_PX, display_transform, gaussian_blur, subpixel_blur
from .layers import WeaveLookup
from .param_tensors import ParamTensors, as_float
from .photo_light import PhotoLight
from .projections import SampleProjections, project, retwisted
from .spacing_warp import SpacingWarp
from .variation import VariationSettings


@dataclass
class RenderedPair:
    """Displayed images (size, size, 3) in [0, 1], and the linear radiance before the transform."""

    reflection: torch.Tensor
    transmission: torch.Tensor
    reflection_radiance: torch.Tensor
    transmission_radiance: torch.Tensor


# Where a Renderer's subpixel_blur is None (auto), blurs of this many render pixels and wider act on
# the pixel means. Not alias-free: there the false lattice of an alias at 1 - f is damped to G(1 - f)
# (the worst, f near 1, to about 0.1 / sigma of the harmonic's amplitude), a trade against the cost
# of the sub-pixels, whose kernel is twice as wide.
AUTO_SUBPIXEL_BELOW_PX = 1.2


def subpixel_size(spp: int) -> int:
    """The side k / 2 of the block of stratified samples that make one sub-pixel of the blurred
    image (module docstring): spp = k x k with k even; 0 where the samples cannot be split so."""
    k = math.isqrt(spp)
    return k // 2 if k * k == spp and k % 2 == 0 else 0


# Inductor's cap on the nodes fused into one kernel (default 64). At 256 the BSDF's backward recomputes
# its per-sample values inside its reductions instead of writing and reading back about 90 buffers:
# faster, and the gradients are bit-identical (the same sums in the same order).
COMPILE_OPTIONS = {"max_fusion_size": 256}

# Samples per block of rows on the eager path: small enough for a block's tensors to stay in the CPU's
# caches from one operation to the next.
EAGER_BLOCK_SAMPLES = 1 << 17
# Samples per block whose gradient is not taken (a render without gradients, the rows outside a
# gradient share): with no backward pass keeping its tensors, fewer and larger operations are faster.
FORWARD_BLOCK_SAMPLES = 1 << 19


def full_precision_convolutions() -> None:
    """cuDNN's float32 convolutions in full precision, not TF32 (its default on recent GPUs: a 10-bit
    mantissa, about 1e-3 relative). The camera blur is such a convolution, and nothing of the model is
    measured in reduced precision: its gradient tests (against the float64 reference) allow float32
    rounding only. Process-wide: torch has no per-call switch."""
    torch.backends.cudnn.conv.fp32_precision = "ieee"


class Renderer:
    """Renders (reflection, transmission) pairs of one rig, size, sample count and jitter seed."""

    def __init__(self, rig: CaptureRig = DEFAULT_RIG, size: int = 512, spp: int = 4, seed: int = 0,
                 options: RenderOptions = RenderOptions(), device="cpu", dtype=torch.float32,
                 max_chunk_samples: int = 1 << 20, cache_samples: int = 1 << 21, geometry_cache: int = 4,
                 compile: bool = False, subpixel_blur: bool | None = False,
                 gradient_inputs: tuple[str, ...] | None = None, warp: SpacingWarp | None = None,
                 hand_gradient: bool = True):
        self.rig, self.options, self.device, self.dtype = rig, options, torch.device(device), dtype
        self.hand_gradient = hand_gradient
        if self.device.type == "cuda":
            full_precision_convolutions()
        self.camera = CameraSamples(rig, size, spp, seed, self.device, dtype, warp)
        self.size, self.spp, self.seed = size, spp, seed
        self._subpixel_blur = subpixel_blur
        self.ranges = self.camera.row_chunks(max_chunk_samples)
        self._keep = size * size * spp <= cache_samples
        self._chunks: dict[tuple[int, int], SampleChunk] = {}
        self._geometry: OrderedDict = OrderedDict()
        self._bands: dict = {}  # rows -> (lattice, TileBands) of the last lattice rendered
        self._geometry_slots = geometry_cache if self._keep else 0
        self._lookups: dict = {}
        self._last_radiance: tuple | None = None  # (parameter values, radiance) of the last render without gradients
        self.vignette = self.camera.pixel_falloff(rig.vignette_sigma_px) if options.vignette else None
        # samples per side of a sub-pixel the camera blur acts on; 0: it acts on the pixel means
        self.subpixel = subpixel_size(spp) if subpixel_blur is not False else 0
        # None: on the sub-pixels only where a blur is too narrow to damp the pixel means' aliases
        self._subpixel_below = AUTO_SUBPIXEL_BELOW_PX if subpixel_blur is None else math.inf
        self._glow_shapes: tuple | None = None  # the glow's falloff at strength 1: (pixels, sub-pixels or None)
        self.set_glow(rig.glow_strength)
        if compile:
            use_persistent_compile_cache()
            allow_cached_custom_gradients()
        self._compiled = torch.compile(self._terms, dynamic=False, options=COMPILE_OPTIONS) if compile else None
        # the parameters the compiled graph differentiates: as declared, else as the last render with gradients had them
        self._grad_names = None if gradient_inputs is None else frozenset(gradient_inputs)
        self._gradient_share: GradientShare | None = None  # set for one step by gradient_share()

    def like(self, size: int, spp: int, seed: int) -> "Renderer":
        """A renderer like this one (rig, options, camera blur's mode, spacing warp; eager) at another
        size, sample count and jitter seed: another seed's Monte Carlo noise is independent of this
        one's."""
        return Renderer(self.rig, size, spp, seed, self.options, self.device, self.dtype,
                        subpixel_blur=self._subpixel_blur, warp=self.warp)

    @property
    def warp(self) -> SpacingWarp | None:
        """The photos' uneven yarn spacing the renders show (:mod:`.spacing_warp`; None: even)."""
        return self.camera.warp

    def set_glow(self, strength: float) -> None:
        """Renders from now on add the back light's glow through the gaps at ``strength`` (the rig's
        ``glow_strength``; the rig is replaced by one that says so, which :meth:`like` carries)."""
        if strength < 0:
            raise ValueError(f"glow strength must be >= 0, got {strength!r}")
        self.rig = dataclasses.replace(self.rig, glow_strength=float(strength))
        on = self.options.glow and strength > 0
        if on and self._glow_shapes is None:   # made once: a glow scan sets several strengths
            sigma = self.rig.glow_sigma_px
            fine = (CameraSamples(self.rig, 2 * self.size, 1, self.seed, self.device, self.dtype)
                    if self.subpixel else None)
            self._glow_shapes = (self.camera.pixel_falloff(sigma), None if fine is None else fine.pixel_falloff(sigma))
        pixels, subpixels = self._glow_shapes if on else (None, None)
        self.glow = None if pixels is None else pixels * strength
        self._glow_fine = None if subpixels is None else subpixels * strength
        self._last_radiance = None

    def set_warp(self, warp: SpacingWarp | None) -> None:
        """Renders from now on show ``warp``: the camera samples and the geometry are made again (the
        compiled graph stays: it sees the same shapes)."""
        self.camera.warp = warp
        self._chunks.clear()
        self._geometry.clear()
        self._bands.clear()
        self._last_radiance = None

    @contextlib.contextmanager
    def gradient_share(self, share: "GradientShare | None"):
        """Renders with gradients in this block carry them through ``share``'s blocks of film rows only
        (:class:`GradientShare`); the values are those of every sample."""
        kept, self._gradient_share = self._gradient_share, share
        try:
            yield
        finally:
            self._gradient_share = kept

    # -- cached stages -----------------------------------------------------------------------
    def _chunk(self, rows: tuple[int, int]) -> SampleChunk:
        if rows in self._chunks:
            return self._chunks[rows]
        chunk = self.camera.chunk(*rows)
        if self._keep:
            self._chunks[rows] = chunk
        return chunk

    def _lookup(self, fabric: ParamTensors) -> WeaveLookup:
        weave = FabricParams(pattern=fabric.pattern, weave=fabric.weave).resolved_weave
        if weave not in self._lookups:
            self._lookups[weave] = WeaveLookup(weave, self.device)
        return self._lookups[weave]

    def geometry_key(self, fabric: ParamTensors) -> GeometryKey:
        return GeometryKey(pattern=fabric.pattern if fabric.weave is None else f"custom:{fabric.weave}",
                           tiles=fabric.scalar("tiles"), gap_scale=fabric.scalar("gap_scale"),
                           twist_deg=fabric.scalar("twist_deg"), noise=fabric.scalar("noise"),
                           tension=self.options.tension, layers=self.options.layers,
                           variation=_variation(fabric))

    def _geometry_for(self, key: GeometryKey, lookup: WeaveLookup, rows, chunk) -> SampleProjections:
        """The chunk's projections in the state ``key``, kept for the last few states rendered; a new
        state at another twist of a kept one computes only what the twist changes (the fiber
        directions' projections, :func:`.projections.retwisted`): a discrete search tries several
        twists on each lattice and gap scale."""
        cache_key = (key, rows)
        if cache_key in self._geometry:
            self._geometry.move_to_end(cache_key)
            return self._geometry[cache_key]
        with torch.no_grad():
            bands = self._bands_for(key, lookup, rows, chunk)
            other_twist = self._kept_at_other_twist(key, rows)
            if other_twist is not None:
                geometry = retwisted(other_twist, chunk, twisted_fibers(lookup, self.rig, key, self.dtype, bands))
            else:
                geometry = project(chunk, sample_geometry(chunk, lookup, self.rig, key, self.dtype, bands))
        if self._geometry_slots:
            self._geometry[cache_key] = geometry
            while len(self._geometry) > self._geometry_slots * len(self.ranges):
                self._geometry.popitem(last=False)
        return geometry

    def _kept_at_other_twist(self, key: GeometryKey, rows) -> SampleProjections | None:
        """Kept projections of the chunk in ``key``'s state at another twist, if any (a twist sets only
        the fiber directions: :func:`.projections.retwisted`)."""
        for (other, other_rows), geometry in reversed(self._geometry.items()):
            if other_rows == rows and dataclasses.replace(other, twist_deg=key.twist_deg) == key:
                return geometry
        return None

    def _bands_for(self, key: GeometryKey, lookup: WeaveLookup, rows, chunk) -> TileBands:
        """The chunk's :func:`tile_bands` for the key's lattice, kept for the last lattice rendered: a
        discrete search (:meth:`backend.fit.optimise.Run.discrete_search`) and a starting point's gap
        scan render one lattice at several gap scales and twists."""
        lattice = (key.pattern, key.tiles)
        kept = self._bands.get(rows)
        if kept is not None and kept[0] == lattice:
            return kept[1]
        bands = tile_bands(chunk, lookup, self.rig, key.tiles)
        if self._geometry_slots:
            self._bands[rows] = (lattice, bands)
        return bands

    # -- rendering ---------------------------------------------------------------------------
    def radiance(self, fabric: ParamTensors, progress=None, fine: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """Linear radiance images (size, size, 3) of the front-lit and back-lit captures; with
        ``fine`` (only where :attr:`subpixel` is set), the sub-pixel images (2 size, 2 size, 3) that
        the camera blur acts on (module docstring).

        ``progress(done, total)`` is called after each chunk of rows (long renders report through it).
        """
        if fine and not self.subpixel:
            raise ValueError(f"{self.spp} samples per pixel make no sub-pixel image (k x k with k even)")
        key = self.geometry_key(fabric)
        lookup = self._lookup(fabric)
        needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in fabric.values.values())
        if needs_grad:
            self._grad_names = frozenset(n for n, v in fabric.values.items() if v.requires_grad)
        glow_field, scale = (self._glow_fine, 2) if fine else (self.glow, 1)
        pieces_r, pieces_t = [], []
        for rows in self.ranges:
            samples = self._geometry_for(key, lookup, rows, self._chunk(rows))
            glow = None if glow_field is None else glow_field[scale * rows[0]:scale * rows[1]]
            if needs_grad and len(self.ranges) > 1:
                def evaluate(*tensors, samples=samples, glow=glow):
                    values = dict(zip(fabric.values, tensors))
                    return self._evaluate(samples, ParamTensors(fabric.pattern, fabric.weave, values), glow,
                                          fine=fine)

                r, t = _Recomputed.apply(evaluate, *fabric.values.values())
            else:
                r, t = self._evaluate(samples, fabric, glow, fused=needs_grad, fine=fine)
            pieces_r.append(r)
            pieces_t.append(t)
            if progress is not None:
                progress(len(pieces_r), len(self.ranges))
        return torch.cat(pieces_r, 0), torch.cat(pieces_t, 0)

    @property
    def compiled(self) -> bool:
        return self._compiled is not None

    def _evaluate(self, samples: SampleProjections, fabric: ParamTensors, glow: torch.Tensor | None,
                  fused: bool = True, fine: bool = False):
        """The chunk's pixels (sub-pixels where ``fine``): the BSDF's terms by the compiled graph when
        there is one and ``fused`` (with gradients), or forward only through it once the inputs it
        differentiates are known (module docstring), else everything eager."""
        if self._compiled is None or not (fused or self._grad_names is not None):
            return self._eager(samples, fabric, glow, fine)
        try:
            if fused:
                terms = self._compiled(samples, fabric)
            else:  # forward only, through the gradient graph: the same inputs needing gradients, none kept
                with torch.enable_grad():
                    leaves = {n: v.detach().requires_grad_(n in self._grad_names) for n, v in fabric.values.items()}
                    terms = tuple(t.detach() for t in self._compiled(samples, ParamTensors(fabric.pattern,
                                                                                          fabric.weave, leaves)))
        except Exception as exc:  # a missing or broken compiler must not stop a render
            warnings.warn(f"torch.compile failed ({type(exc).__name__}: {str(exc)[:200]}); "
                          "continuing with the slower eager renderer", RuntimeWarning, stacklevel=2)
            self._compiled = None
            return self._eager(samples, fabric, glow, fine)
        return self._pixels(samples, terms, glow, fine)

    def _eager(self, samples: SampleProjections, fabric: ParamTensors, glow: torch.Tensor | None,
               fine: bool = False):
        """:meth:`_pixels` in blocks of rows small enough for the CPU's caches: every eager operation
        reads and writes whole tensors, and a block's tensors stay in cache from one to the next
        (:func:`eager_blocks`: larger where no gradient is taken)."""
        per_row = self.size * self.spp
        rows = samples.no_yarn.shape[0] // per_row
        gradients = torch.is_grad_enabled() and any(v.requires_grad for v in fabric.values.values())
        share = self._gradient_share if gradients else None
        carries = None if not gradients else (lambda index: True) if share is None else share.carries
        blocks = eager_blocks(rows, max(1, EAGER_BLOCK_SAMPLES // per_row), max(1, FORWARD_BLOCK_SAMPLES // per_row),
                              carries)
        if len(blocks) == 1:
            return self._pixels(samples, self._terms(samples, fabric, self.hand_gradient), glow, fine)
        scale = 2 if fine else 1  # glow rows per film row
        pieces = []
        for r0, r1, carried in blocks:
            block = samples.between(r0 * per_row, r1 * per_row)
            block_glow = None if glow is None else glow[scale * r0:scale * r1]
            with contextlib.nullcontext() if carried or not gradients else torch.no_grad():
                piece = self._pixels(block, self._terms(block, fabric, self.hand_gradient), block_glow, fine)
            pieces.append(tuple(map(share.scaled, piece)) if share is not None and carried else piece)
        return torch.cat([r for r, _ in pieces], 0), torch.cat([t for _, t in pieces], 0)

    def _terms(self, samples: SampleProjections, fabric: ParamTensors,
               hand_gradient: bool = False) -> tuple[torch.Tensor, ...]:
        """The BSDF of every sample as colour terms (:class:`backend.model.bsdf.ColourTerms`):
        (reflection colours (3, K), weights (K, S), transmission colours, weights). This is what
        the compiled graph fuses; the average over each pixel's samples stays outside it, because
        with fewer samples per pixel than a vector register holds (4 at 512 px) the backward of that
        average, fused in, indexes sample s at pixel s // spp and inductor falls back to scalar code
        for the whole BSDF. ``hand_gradient``: differentiated by :mod:`.bsdf_gradient` (the eager path),
        else by autograd (what the compiled graph fuses)."""
        evaluate = eval_with_hand_gradient if hand_gradient else eval_projected
        reflection, transmission = evaluate(samples, fabric, self.options)
        return reflection.colours, reflection.weights, transmission.colours, transmission.weights

    def _pixels(self, samples: SampleProjections, terms: tuple[torch.Tensor, ...], glow: torch.Tensor | None,
                fine: bool = False):
        """Per-pixel mean radiance (rows, size, 3) of whole film rows from the samples' colour
        terms (:meth:`_terms`), glow included; with ``fine``, per sub-pixel (2 rows, 2 size, 3): the
        mean of the samples of each quarter of a pixel's stratified k x k (the jitter's strata:
        sample s lies in column s % k and row s // k of them, :meth:`.CameraSamples.jitter`)."""
        colours_r, weights_r, colours_t, weights_t = terms
        pixels = samples.no_yarn.shape[0] // self.spp
        rows = pixels // self.size
        half = self.subpixel

        def means(values):  # (..., S) -> (..., rows, size) or (..., 2 rows, 2 size)
            lead = values.shape[:-1]
            if not fine:
                return values.reshape(*lead, rows, self.size, self.spp).mean(-1)
            quarters = quarter_means(values.reshape(*lead, rows, self.size, 2, half, 2, half))
            order = (*range(len(lead)), len(lead), len(lead) + 2, len(lead) + 1, len(lead) + 3)
            return quarters.permute(order).reshape(*lead, 2 * rows, 2 * self.size)

        def mean_radiance(colours, weights):
            # the per-yarn albedos are constants: averaging the K weights first is less work than (3, S)
            weights = means(weights)
            return (colours @ weights.reshape(weights.shape[0], -1)).reshape(3, *weights.shape[1:])

        r, t = mean_radiance(colours_r, weights_r), mean_radiance(colours_t, weights_t)
        if glow is not None:
            t = t + (glow * means(samples.no_yarn))[None]
        return r.permute(1, 2, 0), t.permute(1, 2, 0)

    def render(self, fabric: ParamTensors | FabricParams, progress=None, camera_blur_px: float | None = None,
               light: PhotoLight | None = None) -> RenderedPair:
        """Displayed images of ``fabric``; ``camera_blur_px`` (film pixels) overrides the rig's;
        ``light`` is the photos' light falloff (none by default)."""
        return self.display(*self.blurred(fabric, progress, camera_blur_px), light)

    def blurred(self, fabric: ParamTensors | FabricParams, progress=None,
                camera_blur_px: float | torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The linear radiance images of ``fabric`` after the camera blur (film pixels, a float or a 0-d
        tensor to differentiate; None: the rig's)."""
        if isinstance(fabric, FabricParams):
            fabric = ParamTensors.from_params(fabric, self.device, self.dtype)
        blur = self.rig.camera_blur_px if camera_blur_px is None else camera_blur_px
        sigma = blur * self.size / self.rig.film_size
        value = as_float(sigma)  # read once: on a GPU each read of a tensor waits for the device
        if value <= NO_BLUR_PX or value >= self._subpixel_below or not self.subpixel:
            r, t = self._radiance_once(fabric, progress)
            return gaussian_blur(r, sigma, value), gaussian_blur(t, sigma, value)
        r, t = self._radiance_once(fabric, progress, fine=True)
        return subpixel_blur(r, sigma, value), subpixel_blur(t, sigma, value)

    def _radiance_once(self, fabric: ParamTensors, progress=None, fine: bool = False
                       ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`radiance`; without gradients, the last result is reused for the same parameter values:
        the fit's camera-blur scans (:func:`backend.fit.search.best_blur`, the discrete search's blur
        step) render one parameter set at up to seven blurs, and the blur comes after the radiance."""
        if not self._keep or (torch.is_grad_enabled() and any(v.requires_grad for v in fabric.values.values())):
            return self.radiance(fabric, progress, fine)
        key = (fabric.pattern, fabric.weave, tuple((name, tuple(values)) for name, values in fabric.host().items()))
        if self._last_radiance is None or self._last_radiance[0] != key:
            self._last_radiance = (key, {})
        kept = self._last_radiance[1]
        if fine not in kept:  # a blur scan asks for both: none (the pixel means) and some (the sub-pixels)
            kept[fine] = self.radiance(fabric, progress, fine)
        return kept[fine]

    def display(self, reflection: torch.Tensor, transmission: torch.Tensor,
                light: PhotoLight | None = None) -> RenderedPair:
        """The displayed pair of blurred linear radiance images, under the photos' ``light``."""
        if light is not None:
            reflection, transmission = light.apply(reflection, transmission)
        g, c = self.rig.gamma, self.rig.clamp
        return RenderedPair(display_transform(reflection, g, c, self.vignette),
                            display_transform(transmission, g, c, self.vignette), reflection, transmission)


def quarter_means(strata: torch.Tensor) -> torch.Tensor:
    """(..., 2, half, 2, half) samples, a pixel's k x k strata (k = 2 half) as quarters of half x half
    -> (..., 2, 2), each quarter's mean: its columns added first, then its rows, by explicit
    additions. The numbers are those of ``strata.mean((-3, -1))`` (the same additions in the same
    order, tests/test_render.py); its strided reduction, and the division of an expanded tensor in
    its backward pass, took about four times as long at 16 samples per pixel (the search's trials)."""
    half = strata.shape[-1]
    columns = functools.reduce(torch.add, [strata[..., j] for j in range(half)])      # (..., 2, half, 2)
    return functools.reduce(torch.add, [columns[..., j, :] for j in range(half)]) / (half * half)


def eager_blocks(rows: int, step: int, forward_step: int, carries) -> list[tuple[int, int, bool]]:
    """The eager path's blocks of film rows as (first row, end row, whether its gradient is taken): the
    k-th block of ``step`` rows carries a gradient where ``carries(k)`` (None: no block does), and
    consecutive blocks that carry none are merged, up to ``forward_step`` rows. The values are the same
    whatever the blocks (each sample's are its own and whole rows are averaged), and a carrying block
    is the same block as without the merge (:class:`GradientShare` counts them)."""
    blocks: list[tuple[int, int, bool]] = []
    for index, r0 in enumerate(range(0, rows, step)):
        r1, carried = min(r0 + step, rows), carries is not None and carries(index)
        if blocks and not carried and not blocks[-1][2] and r1 - blocks[-1][0] <= forward_step:
            blocks[-1] = (blocks[-1][0], r1, False)
        else:
            blocks.append((r0, r1, carried))
    return blocks


@dataclass(frozen=True)
class GradientShare:
    """The blocks of film rows (of the eager path's blocks, :data:`EAGER_BLOCK_SAMPLES` samples each)
    whose samples carry a render's gradient: every ``period``-th, from the ``phase``-th. Their
    gradients are taken ``period`` times, the others' not at all; the values are every sample's.

        grad ~= period * sum over the carrying blocks of d(pixels)/d(parameters)

    Over ``period`` renders at the phases 0 .. period - 1 each block carries once, so their mean is
    the whole gradient (exactly, for the same parameters). Why: the fabric's parameters are the
    same in every block of rows (each holds many tiles of the weave), so a share of them points
    the gradient nearly as all of them do, and a backward pass through them costs that share of
    one through all; the forward pass, which the loss needs whole, is not shared. The compiled
    graph (``compile=True``) differentiates whole chunks, fused: it takes no share.
    """

    phase: int
    period: int

    def carries(self, block: int) -> bool:
        return block % self.period == self.phase % self.period

    def scaled(self, pixels: torch.Tensor) -> torch.Tensor:
        """``pixels`` unchanged, their gradient ``period`` times."""
        if self.period == 1:
            return pixels
        kept = pixels.detach()
        return kept + self.period * (pixels - kept)


def _variation(fabric: ParamTensors) -> VariationSettings | None:
    """The state's yarn variation (None where every amplitude is 0: the geometry is the unvaried one)."""
    settings = VariationSettings.of(fabric.scalar)
    return settings if settings.active else None


class _Recomputed(torch.autograd.Function):
    """Activation checkpointing of one chunk: ``fn(*tensors)`` runs without keeping its
    intermediates, and again in the backward pass to get the gradients. (The non-reentrant
    ``torch.utils.checkpoint`` cannot wrap a ``torch.compile``d function: its saved-tensor hooks
    assert on the compiled graph's.)"""

    @staticmethod
    def forward(ctx, fn, *tensors):
        ctx.fn = fn
        ctx.save_for_backward(*tensors)
        return fn(*tensors)

    @staticmethod
    def backward(ctx, *grads):
        inputs = [t.detach().requires_grad_(t.requires_grad) for t in ctx.saved_tensors]
        with torch.enable_grad():
            outputs = ctx.fn(*inputs)
        wanted = [t for t in inputs if t.requires_grad]
        found = iter(torch.autograd.grad(outputs, wanted, grads, allow_unused=True))
        return (None, *(next(found) if t.requires_grad else None for t in inputs))


def render_pair(params: FabricParams, rig: CaptureRig = DEFAULT_RIG, size: int = 512, spp: int = 4,
                seed: int = 0, options: RenderOptions = RenderOptions(), device="cpu", progress=None,
                light: PhotoLight | None = None, warp: SpacingWarp | None = None) -> RenderedPair:
    """One-shot render (no caching beyond this call), without gradients, the camera blur acting on
    sub-pixels where ``spp`` allows (module docstring); ``progress(done, total)``; ``light``: the
    photos' light falloff (:mod:`.photo_light`); ``warp``: their uneven yarn spacing (:mod:`.spacing_warp`)."""
    renderer = Renderer(rig, size, spp, seed, options, device, cache_samples=0, subpixel_blur=True, warp=warp)
    with torch.no_grad():
        return renderer.render(params, progress, light=light)
