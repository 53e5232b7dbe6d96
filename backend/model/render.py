"""Differentiable renderer of the rig's reflection and transmission images.

    pixel radiance   = mean over the pixel's samples of  BSDF * intensity / distance^2
                       (+ glow * fraction of samples seeing no yarn, transmission only)
    displayed value  = min(blur(radiance), clamp) ** (1 / gamma) * vignette
                       (blur: the rig's camera point spread, a Gaussian; none by default)

Work is split into chunks of film rows (``max_chunk_samples`` samples each) so that memory stays
bounded at any resolution and sample count; when gradients are needed over several chunks each
chunk is checkpointed (recomputed in the backward pass) instead of keeping its intermediates.

For optimisation, a :class:`Renderer` keeps its camera samples (the fixed jitter) and the
geometry of the last few discrete states (pattern, tiles, gap scale, twist), so an iteration
only evaluates the differentiable BSDF. With ``compile=True`` that evaluation is fused by
``torch.compile`` (about 5x faster on the CPU, once a compile of seconds to a minute is paid; it is
cached on disk across runs); ``compile=None`` compiles only where a C++ compiler is found, and
any compile failure falls back to the eager path with a warning. ``WFC_COMPILE=0`` or ``1`` in
the environment overrides the automatic choice.
"""
from __future__ import annotations

import os
import shutil
import warnings
from collections import OrderedDict
from dataclasses import dataclass

import torch
from torch.utils.checkpoint import checkpoint

from ..core.options import RenderOptions
from ..core.params import FabricParams
from ..core.rig import DEFAULT_RIG, CaptureRig
from .bsdf import eval_pair
from .camera import CameraSamples, SampleChunk
from .geometry import GeometryKey, SampleGeometry, sample_geometry
from .imaging import display_transform, gaussian_blur
from .layers import WeaveLookup
from .param_tensors import ParamTensors


@dataclass
class RenderedPair:
    """Displayed images (size, size, 3) in [0, 1], and the linear radiance before the transform."""

    reflection: torch.Tensor
    transmission: torch.Tensor
    reflection_radiance: torch.Tensor
    transmission_radiance: torch.Tensor


def compile_available() -> bool:
    """Whether torch.compile can build CPU kernels here (it needs a C++ compiler)."""
    forced = os.environ.get("WFC_COMPILE")
    if forced in ("0", "1"):
        return forced == "1"
    return any(shutil.which(c) for c in (os.environ.get("CXX", "g++"), "c++", "clang++"))


class Renderer:
    """Renders (reflection, transmission) pairs of one rig, size, sample count and jitter seed."""

    def __init__(self, rig: CaptureRig = DEFAULT_RIG, size: int = 512, spp: int = 4, seed: int = 0,
                 options: RenderOptions = RenderOptions(), device="cpu", dtype=torch.float32,
                 max_chunk_samples: int = 1 << 20, cache_samples: int = 1 << 21, geometry_cache: int = 4,
                 compile: bool | None = False):
        self.rig, self.options, self.device, self.dtype = rig, options, torch.device(device), dtype
        self.camera = CameraSamples(rig, size, spp, seed, self.device, dtype)
        self.size, self.spp = size, spp
        self.ranges = self.camera.row_chunks(max_chunk_samples)
        self._keep = size * size * spp <= cache_samples
        self._chunks: dict[tuple[int, int], SampleChunk] = {}
        self._geometry: OrderedDict = OrderedDict()
        self._geometry_slots = geometry_cache if self._keep else 0
        self._lookups: dict = {}
        self.vignette = self.camera.pixel_falloff(rig.vignette_sigma_px) if options.vignette else None
        self.glow = (self.camera.pixel_falloff(rig.glow_sigma_px) * rig.glow_strength
                     if options.glow and rig.glow_strength > 0 else None)
        if compile is None:
            compile = compile_available()
        self._compiled = torch.compile(self._pixels, dynamic=False) if compile else None

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
                           tension=self.options.tension, layers=self.options.layers)

    def _geometry_for(self, key: GeometryKey, lookup: WeaveLookup, rows, chunk) -> SampleGeometry:
        cache_key = (key, rows)
        if cache_key in self._geometry:
            self._geometry.move_to_end(cache_key)
            return self._geometry[cache_key]
        with torch.no_grad():
            geometry = sample_geometry(chunk, lookup, self.rig, key, self.dtype)
        if self._geometry_slots:
            self._geometry[cache_key] = geometry
            while len(self._geometry) > self._geometry_slots * len(self.ranges):
                self._geometry.popitem(last=False)
        return geometry

    # -- rendering ---------------------------------------------------------------------------
    def radiance(self, fabric: ParamTensors, progress=None) -> tuple[torch.Tensor, torch.Tensor]:
        """Linear radiance images (size, size, 3) of the front-lit and back-lit captures.

        ``progress(done, total)`` is called after each chunk of rows (long renders report through it).
        """
        key = self.geometry_key(fabric)
        lookup = self._lookup(fabric)
        needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in fabric.values.values())
        pieces_r, pieces_t = [], []
        for rows in self.ranges:
            chunk = self._chunk(rows)
            geometry = self._geometry_for(key, lookup, rows, chunk)
            if needs_grad and len(self.ranges) > 1:
                tensors = tuple(fabric.values.values())
                r, t = checkpoint(self._pixels_from_tensors, chunk, geometry, fabric, *tensors, use_reentrant=False)
            else:
                r, t = self._evaluate(chunk, geometry, fabric)
            pieces_r.append(r)
            pieces_t.append(t)
            if progress is not None:
                progress(len(pieces_r), len(self.ranges))
        return torch.cat(pieces_r, 0), torch.cat(pieces_t, 0)

    @property
    def compiled(self) -> bool:
        return self._compiled is not None

    def _evaluate(self, chunk, geometry, fabric):
        if self._compiled is None:
            return self._pixels(chunk, geometry, fabric)
        try:
            return self._compiled(chunk, geometry, fabric)
        except Exception as exc:  # a missing or broken compiler must not stop a render
            warnings.warn(f"torch.compile failed ({type(exc).__name__}: {str(exc)[:200]}); "
                          "continuing with the slower eager renderer", RuntimeWarning, stacklevel=2)
            self._compiled = None
            return self._pixels(chunk, geometry, fabric)

    def _pixels_from_tensors(self, chunk, geometry, fabric: ParamTensors, *tensors):
        return self._evaluate(chunk, geometry, ParamTensors(fabric.pattern, fabric.weave,
                                                            dict(zip(fabric.values, tensors))))

    def _pixels(self, chunk: SampleChunk, geometry: SampleGeometry, fabric: ParamTensors):
        """Per-pixel mean radiance (rows, size, 3) of one chunk, glow included."""
        reflection, transmission = eval_pair(chunk, geometry, fabric, self.options)
        rows = chunk.row1 - chunk.row0
        pixels = rows * self.size

        def mean_radiance(terms):
            weights = terms.weights.reshape(terms.weights.shape[0], pixels, self.spp).mean(-1)
            return (terms.colours @ weights).reshape(3, rows, self.size)

        r, t = mean_radiance(reflection), mean_radiance(transmission)
        if self.glow is not None:
            open_fraction = geometry.no_yarn.reshape(rows, self.size, self.spp).mean(-1)
            t = t + (self.glow[chunk.row0:chunk.row1] * open_fraction)[None]
        return r.permute(1, 2, 0), t.permute(1, 2, 0)

    def render(self, fabric: ParamTensors | FabricParams, progress=None,
               camera_blur_px: float | None = None) -> RenderedPair:
        """Displayed images of ``fabric``; ``camera_blur_px`` (film pixels) overrides the rig's."""
        if isinstance(fabric, FabricParams):
            fabric = ParamTensors.from_params(fabric, self.device, self.dtype)
        r, t = self.radiance(fabric, progress)
        blur = self.rig.camera_blur_px if camera_blur_px is None else camera_blur_px
        sigma = blur * self.size / self.rig.film_size
        r, t = gaussian_blur(r, sigma), gaussian_blur(t, sigma)
        g, c = self.rig.gamma, self.rig.clamp
        return RenderedPair(display_transform(r, g, c, self.vignette), display_transform(t, g, c, self.vignette), r, t)


def render_pair(params: FabricParams, rig: CaptureRig = DEFAULT_RIG, size: int = 512, spp: int = 4,
                seed: int = 0, options: RenderOptions = RenderOptions(), device="cpu", progress=None) -> RenderedPair:
    """One-shot render (no caching beyond this call), without gradients; ``progress(done, total)``."""
    renderer = Renderer(rig, size, spp, seed, options, device, cache_samples=0)
    with torch.no_grad():
        return renderer.render(params, progress)
