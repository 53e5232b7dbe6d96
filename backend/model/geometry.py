"""Per-sample fabric geometry: the non-differentiable stage between the camera and the BSDF.

From world positions to, per layer: warp/weft masks, the yarn normal and fiber direction before
height scaling, the tension thickness factor, and the noise factors of spec 4.6. It depends only on
the discrete parameters (pattern, tiles, gap scale, twist, noise), so the optimiser computes it
once per discrete state and reuses it across iterations. Most of it depends on the lattice alone
(pattern and tiles: :func:`tile_bands`), which the renderer keeps while a discrete search tries
gap scales and twists on one lattice.

UV mapping (spec 1): u = x / P, v = y / P + 1; tile coordinates s = frac(u tu), t = 1 - frac(v tv);
tile units X = s * tile_width, Y = t * tile_height (Y grows down the image). A sample whose warps are
turned by theta_1 and wefts by theta_2 about the view centre c (the rig's ``yarn_angles_deg``:
rotation +- skew / 2) is looked up at the fabric point

    f = c + ( cos(theta_1) d_x + sin(theta_1) d_y,  -sin(theta_2) d_x + cos(theta_2) d_y ),  d = p - c

(lines of constant f_x, the warps, run along R(theta_1) y; lines of constant f_y, the wefts, along
R(theta_2) x; with no skew this is c + R(-theta)(p - c)), and the yarn normals and fiber directions of
a warp are turned by R(theta_1) about z, those of a weft by R(theta_2).
Tension (spec 3.4): thickness *= S_min + (1 - mu)(1 - S_min).
Yarn variation (:mod:`backend.core.variation`, beyond the spec; none by default): each yarn's width,
sideways slide, thickness factor and brightness factor from the hash of its plane-wide index and
along-yarn position (:mod:`backend.model.variation`); the width and the slide act in the layer lookup,
the thickness on the tension factor, the brightness on the albedo factor and, for the yarn seen, on the
diffuse term (``SampleGeometry.diffuse_scale``).
Noise (spec 4.6, N > 0): for non-plain weaves the albedos are scaled by min(-ln xi, 10) per cell of
a grid of spacing 1 / (11 - N) tile units; for plain the height scale of each yarn segment moves by
-0.1 N + 0.15 N r. xi and r are hashes of the cell or segment (a free choice of the spec).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from ..core.rig import CaptureRig
from . import rng
from . import variation as yarn_variation
from .camera import SampleChunk
from .layers import GAP, WARP, WEFT, Bands, Layer, WeaveLookup
from .yarn import fiber_direction, local_frame


@dataclass
class LayerGeometry:
    warp: torch.Tensor                    # (S,) 1 where the layer is a warp yarn
    weft: torch.Tensor                    # (S,) 1 where it is a weft yarn
    normal: torch.Tensor                  # (3, S) before height scaling
    fiber: torch.Tensor                   # (3, S) before height scaling
    thickness_scale: torch.Tensor         # (S,) tension factor
    albedo_scale: torch.Tensor | None     # (S,) noise factor on k_s, k_m
    height_offset: torch.Tensor | None    # (S,) noise offset on beta

    @property
    def is_yarn(self) -> torch.Tensor:
        return self.warp + self.weft


@dataclass
class SampleGeometry:
    layers: list[LayerGeometry]   # front, then back (one layer in the single-layer variant)
    no_yarn: torch.Tensor         # (S,) 1 where every layer is a gap (the glow shows through)
    diffuse_scale: torch.Tensor | None = None  # (S,) brightness of the yarn seen (yarn variation), on k_d


@dataclass(frozen=True)
class GeometryKey:
    """The discrete state the geometry depends on."""

    pattern: str
    tiles: tuple[float, float]
    gap_scale: tuple[float, float]
    twist_deg: tuple[float, float]
    noise: float
    tension: bool
    layers: int
    variation: yarn_variation.VariationSettings | None = None  # the yarn variations (None: none)

    @property
    def varied(self) -> bool:
        return self.variation is not None and self.variation.active


def fabric_point(x: torch.Tensor, y: torch.Tensor, rig: CaptureRig) -> tuple[torch.Tensor, torch.Tensor]:
    """The point of the (turned, sheared) fabric under world (x, y) (the module's formula)."""
    warp_deg, weft_deg = rig.yarn_angles_deg
    if warp_deg == 0 and weft_deg == 0:
        return x, y
    t1, t2 = math.radians(warp_deg), math.radians(weft_deg)
    cx, cy = rig.view_centre
    dx, dy = x - cx, y - cy
    return cx + math.cos(t1) * dx + math.sin(t1) * dy, cy - math.sin(t2) * dx + math.cos(t2) * dy


def turned(vectors: tuple[torch.Tensor, ...], rig: CaptureRig, warp: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """(3, S) directions of the yarns' frames in the world, each of ``vectors`` (the yarn normals
    and fiber directions at the same samples): R(theta_1) about z where ``warp`` (S,) is true,
    R(theta_2) elsewhere."""
    warp_deg, weft_deg = rig.yarn_angles_deg
    if warp_deg == 0 and weft_deg == 0:
        return vectors
    dtype = vectors[0].dtype
    if warp_deg == weft_deg:
        theta = torch.tensor(math.radians(warp_deg), dtype=dtype, device=vectors[0].device)
    else:
        theta = torch.where(warp, math.radians(warp_deg), math.radians(weft_deg)).to(dtype)
    c, s = torch.cos(theta), torch.sin(theta)
    return tuple(torch.stack((c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])) for v in vectors)


def tile_coordinates(x: torch.Tensor, y: torch.Tensor, rig: CaptureRig, tiles, lookup: WeaveLookup):
    """World (x, y) -> tile units (X, Y), plus the integer tile indices (for noise)."""
    x, y = fabric_point(x, y, rig)
    u = x / rig.plane_size * tiles[0]
    v = (y / rig.plane_size + 1.0) * tiles[1]
    s = u - torch.floor(u)
    t = 1.0 - (v - torch.floor(v))
    return s * lookup.weave.tile_width, t * lookup.weave.tile_height, torch.floor(u).long(), torch.floor(v).long()


@dataclass
class TileBands:
    """The part of a chunk's geometry that only the lattice sets (tiles; the pattern is the lookup's):
    tile coordinates, tile indices and the :class:`backend.model.layers.Bands` there."""

    X: torch.Tensor
    Y: torch.Tensor
    tile_u: torch.Tensor
    tile_v: torch.Tensor
    bands: Bands


def tile_bands(chunk: SampleChunk, lookup: WeaveLookup, rig: CaptureRig, tiles) -> TileBands:
    X, Y, tile_u, tile_v = tile_coordinates(chunk.x, chunk.y, rig, tiles, lookup)
    return TileBands(X, Y, tile_u, tile_v, lookup.bands(X, Y))


def sample_geometry(chunk: SampleChunk, lookup: WeaveLookup, rig: CaptureRig, key: GeometryKey,
                    dtype=torch.float32, bands: TileBands | None = None) -> SampleGeometry:
    """The geometry of ``key`` at the chunk's samples; ``bands``: its :func:`tile_bands` when known
    (the same chunk, lookup and tiles), which is most of the work."""
    found = tile_bands(chunk, lookup, rig, key.tiles) if bands is None else bands
    X, Y, tile_u, tile_v = found.X, found.Y, found.tile_u, found.tile_v
    s_min = lookup.weave.s_min if key.tension else 1.0
    twist = _twist_rad(key)
    out = []
    brightness = []
    for index, layer in enumerate(_layers(lookup, key, found)):
        n, o = local_frame(layer, twist)
        is_warp = layer.yarn == WARP
        n, o = turned((n, o), rig, is_warp)
        warp = is_warp.to(dtype)
        weft = (layer.yarn == WEFT).to(dtype)
        thickness_scale = (s_min + (1.0 - layer.mu) * (1.0 - s_min)).to(dtype)
        albedo_scale = height_offset = None
        if key.noise > 0:
            albedo_scale, height_offset = _noise(layer, index, X, Y, tile_u, tile_v, lookup, key, dtype)
        if key.varied:
            thickness_scale = thickness_scale * layer.ids("thickness")
            brightness.append(layer.ids("brightness"))
            albedo_scale = brightness[-1] if albedo_scale is None else albedo_scale * brightness[-1]
        out.append(LayerGeometry(warp, weft, n.to(dtype), o.to(dtype), thickness_scale, albedo_scale, height_offset))
    no_yarn = torch.ones_like(out[0].warp)
    for layer in out:
        no_yarn = no_yarn * (1.0 - layer.is_yarn)
    diffuse_scale = None
    if brightness:  # the yarn seen: the front one, else the back one through a gap in front
        diffuse_scale = brightness[0] if len(out) == 1 else torch.where(out[0].is_yarn > 0, *brightness)
    return SampleGeometry(out, no_yarn, diffuse_scale)


def twisted_fibers(lookup: WeaveLookup, rig: CaptureRig, key: GeometryKey, dtype, bands: TileBands
                   ) -> list[torch.Tensor]:
    """Each layer's fiber direction (3, S) in the state ``key``, the numbers :func:`sample_geometry`
    gives it: all a twist changes (:func:`backend.model.projections.retwisted`)."""
    twist = _twist_rad(key)
    out = []
    for layer in _layers(lookup, key, bands):
        (o,) = turned((fiber_direction(layer, twist),), rig, layer.yarn == WARP)
        out.append(o.to(dtype))
    return out


def _layers(lookup: WeaveLookup, key: GeometryKey, bands: TileBands) -> list[Layer]:
    varied = None
    if key.varied:
        found = bands.bands
        varied = yarn_variation.factors(key.variation, lookup.weave, key.gap_scale, bands.X, bands.Y, bands.tile_u,
                                        bands.tile_v, found.warp["index"], found.weft["index"], lookup.dtype)
    front, back = lookup.layers_of(bands.bands, key.gap_scale, varied)
    return [front, back][: key.layers]


def _twist_rad(key: GeometryKey) -> tuple[float, ...]:
    return tuple(math.radians(a) for a in key.twist_deg)


def _noise(layer: Layer, index: int, X, Y, tile_u, tile_v, lookup: WeaveLookup, key: GeometryKey, dtype):
    is_yarn = layer.yarn != GAP
    if key.pattern == "plain":
        r = rng.uniform(tile_u, tile_v, layer.yarn.long(), layer.yarn_index, layer.segment, seed=7)
        offset = torch.where(is_yarn, -0.1 * key.noise + 0.15 * key.noise * r, torch.zeros_like(r))
        return None, offset.to(dtype)
    density = 11.0 - key.noise
    gx = torch.floor((tile_u * lookup.weave.tile_width + X) * density).long()
    gy = torch.floor((tile_v * lookup.weave.tile_height - Y) * density).long()
    xi = (rng.uniform(gx, gy, index, seed=11) + 0.5 / (1 << 24)).clamp(max=1.0)
    factor = torch.where(is_yarn, torch.clamp(-torch.log(xi), max=10.0), torch.ones_like(xi))
    return factor.to(dtype), None
