"""Per-sample layer geometry of a weave: which yarn is in front and behind, and where on its segment.

Given tile coordinates (X, Y) in tile units (X to the right, Y down the image), every point has two
layers (spec section 3): layer 0 (front, camera side) is the yarn on top or alone, or a gap; layer 1
(back) is the yarn underneath, or a gap. For the yarn in a layer we need the bent-cylinder
coordinates of spec 3.2,

    u = (l / (length / 2)) * umax     (negated on the back layer)
    v = a * pi / (width * xi)

with l the offset along the yarn from its segment centre (up the image for a warp, right for a
weft) and a the offset across it (right for a warp, down for a weft); the tension mu (spec 3.4);
and the gap test |a| >= width * xi / 2 (spec 3.1).

Everything here is a lookup: no gradients flow through the weave (tiles, gap scale and the pattern
are searched, not differentiated). The segment facts come from :meth:`Weave.interval_table`,
gathered per point, so evaluation is analytic at any resolution.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch

from ..core.weave import WARP, WEFT, Weave

GAP = 2  # yarn id of a gap (WARP = 0, WEFT = 1)

# Columns of the packed interval tables.
_CENTRE, _LENGTH, _LAYER, _MU, _DPREV, _MUPREV, _DNEXT, _MUNEXT, _SEGMENT, _FLAT = range(10)


@dataclass
class Layer:
    """One layer at every sample: yarn id (WARP, WEFT or GAP), u, v (radians), tension mu.

    ``flat`` marks segments too short to bend (spec 3.2: n = o = z). ``segment`` is a per-tile id of
    the segment (for the noise of spec 4.6); ``yarn_index`` the yarn's column or row in the tile:
    both picked only when read (``ids``: by the column's name), since only the noise reads them.
    """

    yarn: torch.Tensor
    u: torch.Tensor
    v: torch.Tensor
    mu: torch.Tensor
    flat: torch.Tensor
    ids: Callable[[str], torch.Tensor]

    @property
    def segment(self) -> torch.Tensor:
        return self.ids("segment")

    @property
    def yarn_index(self) -> torch.Tensor:
        return self.ids("index")


@dataclass
class Bands:
    """Per point, which bands of the tile it lies in and each yarn's segment coordinates there
    (:meth:`WeaveLookup.bands`): all of a layer lookup but the gap scale's part."""

    warp: dict                 # the warp through each point: u, across (tile units), mu, flat, segment, index
    weft: dict                 # the same for the weft
    in_warp: torch.Tensor      # in a warp band
    in_weft: torch.Tensor      # in a weft band
    warp_over: torch.Tensor    # the weave matrix at the point's cell: the warp on top


class WeaveLookup:
    """Tensor form of a weave's interval tables, on one device, for per-sample evaluation.

    Each table column is a flat tensor indexed by ``yarn_index * intervals + interval`` so a lookup
    is one ``take`` per column. Positions arrive in float64 (tile units are computed from large
    world products) and are reduced to float32 once they are wrapped into the tile.
    """

    COLUMNS = ("centre", "length", "layer", "mu", "dist_prev", "mu_prev", "dist_next", "mu_next", "segment", "flat")

    def __init__(self, weave: Weave, device="cpu", dtype=torch.float32):
        self.weave = weave
        self.device, self.dtype = torch.device(device), dtype
        self.matrix = torch.tensor(weave.matrix, dtype=torch.bool, device=self.device).flatten()
        self.umax = [math.radians(a) for a in weave.umax_deg]
        self.tables = [self._pack(weave, WARP), self._pack(weave, WEFT)]

    def _pack(self, weave: Weave, yarn: int) -> dict[str, torch.Tensor]:
        width = weave.band(yarn)[0]
        umax = math.radians(weave.umax_deg[yarn])
        rows = [[e.centre, e.length, e.layer, e.tension, e.dist_prev, e.tension_prev, e.dist_next,
                 e.tension_next, e.segment, float(width * math.sin(umax) >= e.length)]
                for entries in weave.interval_table(yarn) for e in entries]
        table = torch.tensor(rows, dtype=self.dtype, device=self.device)
        columns = {name: table[:, k].contiguous() for k, name in enumerate(self.COLUMNS)}
        columns["intervals"] = 2 * (weave.rows if yarn == WARP else weave.cols)
        return columns

    def layers(self, X: torch.Tensor, Y: torch.Tensor, gap_scale: tuple[float, float]) -> tuple[Layer, Layer]:
        """Front and back layers at tile coordinates (X, Y) (any shape, tile units, wrapped here)."""
        return self.layers_of(self.bands(X, Y), gap_scale)

    def bands(self, X: torch.Tensor, Y: torch.Tensor) -> Bands:
        """Everything :meth:`layers` reads at (X, Y) that the gap scale does not change: a fit's
        discrete search tries several gap scales (and twists) on one lattice, and this is most of
        the work of each (:class:`backend.model.render.Renderer` keeps it)."""
        w = self.weave
        # Position across the bands, from the first band's leading edge (wraps the tile).
        xr = torch.remainder(X - w.warp_offset, w.tile_width).to(self.dtype)
        yr = torch.remainder(Y - w.weft_offset, w.tile_height).to(self.dtype)
        col = torch.floor(xr * (1.0 / w.warp_pitch)).long().clamp_(0, w.cols - 1)
        row = torch.floor(yr * (1.0 / w.weft_pitch)).long().clamp_(0, w.rows - 1)
        x_in = xr - col * w.warp_pitch
        y_in = yr - row * w.weft_pitch
        in_warp = x_in < w.warp_width
        in_weft = y_in < w.weft_width
        warp_over = self.matrix.take(row * w.cols + col)
        warp = self._yarn(WARP, col, row, in_weft, yr, x_in - w.warp_width / 2, w.tile_height)
        weft = self._yarn(WEFT, row, col, in_warp, xr, y_in - w.weft_width / 2, w.tile_width)
        return Bands(warp, weft, in_warp, in_weft, warp_over)

    def layers_of(self, bands: Bands, gap_scale: tuple[float, float], varied: tuple[dict, dict] | None = None
                  ) -> tuple[Layer, Layer]:
        """:meth:`layers` from the :meth:`bands` at the same points: v and the gap test, per spec 3.1-3.2.

        ``varied``: the warp's and the weft's yarn variation at the points
        (:func:`backend.model.variation.factors`: the varied gap scale ``xi``, the sideways ``shift``, and
        the ``thickness`` and ``brightness`` factors, which the layers then carry: ``Layer.ids``)."""
        varied = varied or ({}, {})
        warp, weft = (self._across(yarn, found, gap_scale[yarn], varied[yarn])
                      for yarn, found in ((WARP, bands.warp), (WEFT, bands.weft)))
        in_warp, in_weft, warp_over = bands.in_warp, bands.in_weft, bands.warp_over
        crossing = in_warp & in_weft
        front_is_warp = in_warp & (~in_weft | warp_over)
        front_is_weft = in_weft & (~in_warp | ~warp_over)
        front = self._compose(warp, weft, front_is_warp, front_is_weft)
        back = self._compose(warp, weft, crossing & ~warp_over, crossing & warp_over)
        return front, back

    def _yarn(self, yarn, index, cross_index, in_crossing, along, across, period) -> dict:
        """Segment coordinates of the yarn of direction `yarn` through every point (present or not),
        but for those the gap scale sets (:meth:`_across`)."""
        table = self.tables[yarn]
        flat_index = index * table["intervals"] + 2 * cross_index + (~in_crossing).long()

        def column(name):
            return table[name].take(flat_index)

        centre, length = column("centre"), column("length")
        # Signed offset from the segment centre along the increasing coordinate, wrapped to the period.
        offset = torch.remainder(along - centre + period / 2, period) - period / 2
        # Tension: linear between this segment's centre and the neighbour's on the point's side.
        mu_here = column("mu")
        before = offset < 0
        mu_there = torch.where(before, column("mu_prev"), column("mu_next"))
        dist_there = torch.where(before, column("dist_prev"), column("dist_next"))
        mu = mu_here + (mu_there - mu_here) * offset.abs() / dist_there
        # Along-yarn offset l: up the image for a warp (the along-coordinate runs down), right for a weft.
        # u = l / (length / 2) * umax, negated on the back layer.
        sign = (1.0 - 2.0 * column("layer")) * (-1.0 if yarn == WARP else 1.0)
        u = offset * sign * (2.0 * self.umax[yarn]) / length
        return dict(u=u, across=across, mu=mu, flat=column("flat") > 0, segment=column("segment").long(),
                    index=index)

    def _across(self, yarn: int, found: dict, xi: float, varied: dict) -> dict:
        """:meth:`_yarn`'s coordinates with v and the gap test at gap scale ``xi`` (per point, and the
        centre line moved across, where ``varied`` holds a yarn variation)."""
        width = self.weave.band(yarn)[0]
        across = found["across"]
        if varied:
            across, xi = across - varied["shift"], varied["xi"]
        return {**found, **varied, "v": across * (math.pi / (width * xi)), "gap": across.abs() >= width * xi / 2}

    @staticmethod
    def _compose(warp: dict, weft: dict, is_warp, is_weft) -> Layer:
        is_warp = is_warp & ~warp["gap"]
        is_weft = is_weft & ~weft["gap"] & ~is_warp
        yarn = torch.full_like(is_warp, GAP, dtype=torch.int8)
        yarn.masked_fill_(is_warp, WARP).masked_fill_(is_weft, WEFT)

        def pick(key):
            chosen = weft[key]
            return torch.where(is_warp, warp[key], torch.where(is_weft, chosen, chosen.new_zeros(())))

        return Layer(yarn=yarn, u=pick("u"), v=pick("v"), mu=pick("mu"), flat=pick("flat"), ids=pick)
