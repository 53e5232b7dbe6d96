"""Weave geometry: an interlacing matrix plus band layout, and the yarn segments it implies.

A weave (spec section 3) is a binary matrix P, ``rows x cols``, listed top to bottom: P[i][j] = 1
where the warp of column j lies over the weft of row i. Warp j occupies a column band of width
``warp_width`` starting ``warp_offset`` into its pitch ``warp_pitch``; weft i a row band of width
``weft_width`` starting ``weft_offset`` (measured downwards) into its pitch ``weft_pitch``. The tile
is ``cols * warp_pitch`` wide and ``rows * weft_pitch`` tall, in *tile units*.

Along a yarn, the bands of the other direction are *crossings*; what lies between two crossings
(when those bands are narrower than their pitch) is an *open stretch*. A yarn is in the front layer
where it lies over or alone, in the back layer where it lies under. A *segment* is a maximal
stretch in one layer (stretches wrap around the tile): so back segments are runs of adjacent
under-crossings, and open stretches always belong to front segments.

Tension (spec 3.4): along each yarn, mu = 0 at the centre of its longest segments, 1 at the centre
of the shorter ones, linear in between.

Parameters of :class:`Weave`:

    ===============  ===================  ==========================================================
    name             str                  the preset's name, or ``custom``
    matrix           rows of 0 / 1        P, top to bottom (a row may be a string, ``"0110"``)
    warp_width       tile units (1)       width of a warp band, at most ``warp_pitch``
    warp_pitch       tile units (1)       distance from one warp band to the next
    warp_offset      tile units (0)       where the band starts in its pitch
    weft_*           tile units           the same for the wefts, measured downwards
    umax_deg         degrees (24, 24)     (warp, weft) inclination of a yarn at its segment ends
    s_min            (0, 1] (0.5)         thickness scale at full tension; 1 disables tension
    ===============  ===================  ==========================================================

This module is plain Python; :mod:`backend.model.layers` turns :meth:`Weave.interval_table` into tensors
and evaluates the layers per sample point.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from .jsonfile import listed

WARP, WEFT = 0, 1
FRONT, BACK = 0, 1


class WeaveError(ValueError):
    """A weave definition is malformed; the message says what is wrong."""


@dataclass(frozen=True)
class Segment:
    """A maximal stretch of one yarn in one layer, in the yarn's along-coordinate.

    start: where it begins, measured from the first crossing's leading edge, in [0, period).
    length: its length along the yarn. layer: FRONT or BACK. tension: mu at its centre.
    """

    start: float
    length: float
    layer: int
    tension: float

    @property
    def centre(self) -> float:
        return self.start + self.length / 2


@dataclass(frozen=True)
class IntervalEntry:
    """What a point needs to know about the segment it falls in, for one interval along a yarn.

    Interval 2k is crossing k, interval 2k + 1 the open stretch after it. ``centre`` is the
    segment centre in the along-coordinate (mod period); prev/next describe the neighbouring
    segment centres for the tension interpolation (distances are positive).
    """

    centre: float
    length: float
    layer: int
    tension: float
    dist_prev: float
    tension_prev: float
    dist_next: float
    tension_next: float
    segment: int


@dataclass(frozen=True)
class Weave:
    """An interlacing matrix and its band layout (see the module docstring).

    umax_deg: maximum longitudinal inclination of (warp, weft) yarns at segment ends (degrees).
    s_min: thickness scale at full tension (spec 3.4); 1 disables the tension effect.
    """

    name: str
    matrix: tuple[tuple[int, ...], ...]
    warp_width: float = 1.0
    warp_pitch: float = 1.0
    warp_offset: float = 0.0
    weft_width: float = 1.0
    weft_pitch: float = 1.0
    weft_offset: float = 0.0
    umax_deg: tuple[float, float] = (24.0, 24.0)
    s_min: float = 0.5
    _tables: dict = field(default_factory=dict, init=False, repr=False, compare=False, hash=False)

    def __post_init__(self):
        object.__setattr__(self, "matrix", self._checked_matrix())
        for yarn in ("warp", "weft"):
            self._check_band(yarn)
        object.__setattr__(self, "umax_deg", self._checked_umax())
        if not 0 < self.s_min <= 1:
            raise WeaveError(f"weave {self.name!r}: s_min must be in (0, 1]")

    def _checked_matrix(self) -> tuple[tuple[int, ...], ...]:
        """The matrix as rows of 0/1 ints (a row may be a string such as ``"0110"``), all one length."""
        matrix = self.matrix
        if isinstance(matrix, (str, bytes)) or not hasattr(matrix, "__len__") or not matrix:
            raise WeaveError(f"weave {self.name!r}: matrix must be a non-empty list of rows")
        rows = [self._checked_row(r, row) for r, row in enumerate(matrix)]
        if len({len(r) for r in rows}) != 1 or not rows[0]:
            raise WeaveError(f"weave {self.name!r}: all rows must have the same non-zero length")
        return tuple(rows)

    def _checked_row(self, r: int, row) -> tuple[int, ...]:
        cells = list(row) if not isinstance(row, str) else [c for c in row if not c.isspace()]
        try:
            cells = [int(c) for c in cells]
        except (TypeError, ValueError):
            raise WeaveError(f"weave {self.name!r}: row {r} {row!r} must hold only 0 and 1") from None
        if any(c not in (0, 1) for c in cells):
            raise WeaveError(f"weave {self.name!r}: row {r} {row!r} must hold only 0 and 1")
        return tuple(cells)

    def _check_band(self, yarn: str) -> None:
        """A band of ``yarn`` ("warp" or "weft") fits inside its pitch."""
        width, pitch, offset = (float(getattr(self, f"{yarn}_{k}")) for k in ("width", "pitch", "offset"))
        if not (pitch > 0 and 0 < width <= pitch and 0 <= offset and offset + width <= pitch + 1e-12):
            raise WeaveError(f"weave {self.name!r}: {yarn} band needs 0 < width <= pitch and "
                             f"0 <= offset <= pitch - width (got width {width}, pitch {pitch}, offset {offset})")

    def _checked_umax(self) -> tuple[float, float]:
        umax = tuple(float(x) for x in self.umax_deg)
        if len(umax) != 2 or not all(0 <= x < 90 for x in umax):
            raise WeaveError(f"weave {self.name!r}: umax_deg must be two angles in [0, 90)")
        return umax

    # -- sizes -------------------------------------------------------------------------------
    @property
    def rows(self) -> int:
        return len(self.matrix)

    @property
    def cols(self) -> int:
        return len(self.matrix[0])

    @property
    def tile_width(self) -> float:
        return self.cols * self.warp_pitch

    @property
    def tile_height(self) -> float:
        return self.rows * self.weft_pitch

    def band(self, yarn: int) -> tuple[float, float, float]:
        """(width, pitch, offset) of the bands of `yarn` (WARP or WEFT)."""
        if yarn == WARP:
            return self.warp_width, self.warp_pitch, self.warp_offset
        return self.weft_width, self.weft_pitch, self.weft_offset

    def over(self, yarn: int, index: int) -> list[bool]:
        """For yarn `index` of direction `yarn`: at each of its crossings, does it lie on top?"""
        if yarn == WARP:
            return [self.matrix[i][index] == 1 for i in range(self.rows)]
        return [self.matrix[index][j] == 0 for j in range(self.cols)]

    # -- segments ----------------------------------------------------------------------------
    def segments(self, yarn: int, index: int) -> list[Segment]:
        """The segments of one yarn in along-coordinate order (see the module docstring).

        The along-coordinate runs down the image for a warp and to the right for a weft, and is
        measured from the leading edge of the first crossing band (so it is ``Y - weft_offset``
        for a warp and ``X - warp_offset`` for a weft, in tile units, modulo the period).
        """
        width, pitch, _ = self.band(WEFT if yarn == WARP else WARP)
        over = self.over(yarn, index)
        # Elementary intervals (start, length, layer): crossing k, then the open stretch after it.
        pieces = []
        for k, on_top in enumerate(over):
            pieces.append((k * pitch, width, FRONT if on_top else BACK))
            if pitch - width > 1e-12:
                pieces.append((k * pitch + width, pitch - width, FRONT))
        period = len(over) * pitch
        if len({layer for _, _, layer in pieces}) == 1:
            return [Segment(0.0, period, pieces[0][2], 0.0)]
        # Rotate so that the list starts at a layer change, then merge runs of equal layer.
        first = next(n for n in range(len(pieces)) if pieces[n][2] != pieces[n - 1][2])
        pieces = pieces[first:] + pieces[:first]
        merged: list[list] = []
        for start, length, layer in pieces:
            if merged and merged[-1][2] == layer:
                merged[-1][1] += length
            else:
                merged.append([start, length, layer])
        longest = max(length for _, length, _ in merged)
        return [Segment(start % period, length, layer, 0.0 if length >= longest - 1e-9 else 1.0)
                for start, length, layer in merged]

    def interval_table(self, yarn: int) -> list[list[IntervalEntry]]:
        """table[index][k]: the segment facts for interval k (2 per crossing) of yarn `index`."""
        key = ("intervals", yarn)
        if key not in self._tables:
            self._tables[key] = [self._yarn_intervals(yarn, index)
                                 for index in range(self.cols if yarn == WARP else self.rows)]
        return self._tables[key]

    def _yarn_intervals(self, yarn: int, index: int) -> list[IntervalEntry]:
        width, pitch, _ = self.band(WEFT if yarn == WARP else WARP)
        crossings = self.rows if yarn == WARP else self.cols
        period = crossings * pitch
        segs = self.segments(yarn, index)
        n = len(segs)
        entries = []
        for k in range(2 * crossings):
            # A point inside interval k: its midpoint (the open stretch may be empty: then use its start).
            start = (k // 2) * pitch + (width if k % 2 else 0.0)
            length = (pitch - width) if k % 2 else width
            probe = (start + max(length, 0.0) / 2) % period
            s = next(m for m, seg in enumerate(segs)
                     if (probe - seg.start) % period < seg.length or n == 1)
            seg, prev, nxt = segs[s], segs[(s - 1) % n], segs[(s + 1) % n]
            dist_prev = seg.centre - prev.centre if n > 1 else period
            dist_next = nxt.centre - seg.centre if n > 1 else period
            entries.append(IntervalEntry(
                centre=seg.centre % period, length=seg.length, layer=seg.layer, tension=seg.tension,
                dist_prev=dist_prev % period or period, tension_prev=prev.tension,
                dist_next=dist_next % period or period, tension_next=nxt.tension, segment=s))
        return entries

    # -- JSON ------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {"name": self.name, "matrix": ["".join(str(c) for c in row) for row in self.matrix],
                "warp_width": self.warp_width, "warp_pitch": self.warp_pitch, "warp_offset": self.warp_offset,
                "weft_width": self.weft_width, "weft_pitch": self.weft_pitch, "weft_offset": self.weft_offset,
                "umax_deg": list(self.umax_deg), "s_min": self.s_min}

    @classmethod
    def from_dict(cls, data: dict) -> "Weave":
        if not isinstance(data, dict) or "matrix" not in data:
            raise WeaveError("weave: expected an object with at least a 'matrix' (rows of 0/1)")
        known = {"name", "matrix", "warp_width", "warp_pitch", "warp_offset", "weft_width",
                 "weft_pitch", "weft_offset", "umax_deg", "s_min"}
        unknown = set(data) - known
        if unknown:
            raise WeaveError(f"weave: unknown key(s) {listed(unknown)}")
        args = dict(data)
        args.setdefault("name", "custom")
        try:
            return cls(**args)
        except TypeError as exc:
            raise WeaveError(f"weave: {exc}") from None


def _rows(text: str) -> tuple[tuple[int, ...], ...]:
    return tuple(tuple(int(c) for c in row) for row in text.split("/"))


def mirrored(weave: Weave, name: str) -> Weave:
    """The left-right mirror image of ``weave`` (x -> tile_width - x): its columns in reverse order,
    each warp band moved to ``pitch - width - offset`` into its pitch. Its twill or satin diagonal
    runs the other way; nothing else changes (a plain weave mirrored is itself, one column on)."""
    return dataclasses.replace(weave, name=name, matrix=tuple(row[::-1] for row in weave.matrix),
                               warp_offset=weave.warp_pitch - weave.warp_width - weave.warp_offset)


PAPER_PRESETS: dict[str, Weave] = {
    "plain": Weave("plain", _rows("01/10"), umax_deg=(22.0, 16.0), s_min=1.0),
    "twill0": Weave("twill0", _rows("0111/1011/1101/1110"), weft_width=2.0, weft_pitch=2.0,
                    umax_deg=(24.0, 24.0), s_min=0.5),
    "twill1": Weave("twill1", _rows("0001/0010/0100/1000"), warp_width=2.0, warp_pitch=2.0,
                    umax_deg=(24.0, 24.0), s_min=0.5),
    # satin0: each warp band sits in the right half of its pitch.
    "satin0": Weave("satin0", _rows("00001/00100/10000/00010/01000"), warp_pitch=2.0, warp_offset=1.0,
                    umax_deg=(60.0, 35.0), s_min=0.5),
    # satin1: each weft band sits in the top half of its pitch.
    "satin1": Weave("satin1", _rows("01111/11101/10111/11110/11011"), weft_pitch=2.0, weft_offset=0.0,
                    umax_deg=(35.0, 60.0), s_min=0.5),
}
"""The paper's five weaves (spec section 3). Their diagonals, read from the points where the
sparser yarn comes up: twill0's step one column right per row going down the tile, twill1's one
column left, both satins' three columns right (two left). So a warp-faced twill with twill1's
diagonal, a weft-faced one with twill0's, or a satin with the other step (the fabric seen from its
other side, or woven so) is none of them: their mirror images (:data:`PRESETS`) are."""

MIRROR_SUFFIX = "m"
MIRRORED_OF: dict[str, str] = {f"{name}{MIRROR_SUFFIX}": name for name in PAPER_PRESETS if name != "plain"}
"""Mirrored preset -> the paper's preset it mirrors (twill0m is twill0 mirrored left-right)."""
MIRROR_OF: dict[str, str] = {base: name for name, base in MIRRORED_OF.items()}
"""The paper's preset -> its mirror image (plain has none: mirrored, it is itself)."""

PRESETS: dict[str, Weave] = {**PAPER_PRESETS,
                             **{name: mirrored(PAPER_PRESETS[base], name) for name, base in MIRRORED_OF.items()}}
"""Every preset, in the shader's pattern-index order: the paper's five, then their mirror images."""


def _cyclic_shifts(matrix: tuple[tuple[int, ...], ...]) -> set[tuple[tuple[int, ...], ...]]:
    """``matrix`` started at every row and column of its tile."""
    height, width = len(matrix), len(matrix[0])
    return {tuple(tuple(matrix[(r + i) % height][(c + j) % width] for c in range(width)) for r in range(height))
            for i in range(height) for j in range(width)}


def face_twin(weave: Weave) -> str | None:
    """The preset whose matrix is ``weave``'s with every crossing turned over (warp over weft <-> weft
    over warp), up to where the tile starts: the same diagonal with the floats of the other yarn
    (twill0 <-> twill1m, twill1 <-> twill0m, satin0 <-> satin1, satin0m <-> satin1m; plain is its
    own). Seen at a pixel or two per yarn, a weave and its twin show the same lattice and diagonal."""
    turned = tuple(tuple(1 - c for c in row) for row in weave.matrix)
    return next((name for name, other in PRESETS.items()
                 if name != weave.name and turned in _cyclic_shifts(other.matrix)), None)


def paper_preset(pattern: str) -> str:
    """The paper's preset that ``pattern`` is, or mirrors (other names are returned as they are)."""
    return MIRRORED_OF.get(pattern, pattern)


def is_mirrored(pattern: str) -> bool:
    return pattern in MIRRORED_OF

