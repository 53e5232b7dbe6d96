"""Yarn-dyed patterns: the warp and weft colour sequences (setts) of a check, a stripe or a plaid (no bpy).

A weaver specifies a yarn-dyed cloth by its sett: for each yarn direction, the colours of the yarns
in order with their thread counts, repeated across the cloth. As text, one token per stripe, a
colour code and a count::

    W8 R8                        gingham: 8 white threads, 8 red, repeated
    B/24 K4 B4 K4 B4 K20 G/24    a symmetric (tartan) sett: "/" marks the two pivots
    F24 #F0F0F0/2 ...            F: the fitted colour (the yarn undyed); #rrggbb: any sRGB colour

Colour codes are the tartan registers' letters (:data:`COLOURS`, case-insensitive). A symmetric sett
(its first and last stripes pivots, written ``K/4``) repeats as the stripes there and back, each
pivot once: ``B/24 K4 G/24`` is ``B24 K4 G24 K4``. Adjacent stripes of one colour merge. The weft's
text may be empty: the same sett as the warp (a square sett, as tartans and ginghams are).

In the node group (shader_params.socket_specs, panels "Warp stripes" / "Weft stripes") each
direction has :data:`STRIPES` stripes, each a colour and a thread count; unused ones count 0 threads
and a sett of 0 threads is no pattern. The shader gives the yarn with global index i (counted along
the cloth, see shaders/woven_fabric.osl and core/shader_dye.py) the colour of the stripe holding
``i mod (sum of the counts)``; that colour is the yarn's dye target (core/dye.py). ``F`` stripes get
the fitted fabric's base colour when the sett is written (:func:`socket_values`); with no threads at
all every yarn keeps the base colour the shader computes from the albedos.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

STRIPES = 12  # stripes per yarn direction in the node group (a 7-stripe symmetric sett fills them)
MAX_THREADS = 9999  # one stripe's thread count at most (the socket's range)
NATURAL_CODE = "F"
DIRECTIONS = ("warp", "weft")

# Colour codes (the tartan registers' letters) -> (name, display sRGB hex).
COLOURS = {
    "K": ("black", "#141414"), "W": ("white", "#F2F2F2"), "N": ("grey", "#808080"),
    "R": ("red", "#C8102E"), "G": ("green", "#00573F"), "B": ("blue", "#1B2A5C"),
    "Y": ("yellow", "#F2C200"), "O": ("orange", "#E0701C"), "P": ("purple", "#5B2A6E"),
    "A": ("azure", "#5B8DC9"), "T": ("tan", "#A27C5B"), "C": ("crimson", "#9E1B32"),
}

# Presets: identifier -> (label, warp text, weft text; empty: as the warp).
PRESETS = {
    "GINGHAM": ("Gingham", "W8 R8", ""),
    "TARTAN": ("Tartan", "B/24 K4 B4 K4 B4 K20 G/24", ""),
    "PINSTRIPE": ("Pinstripe", "F24 W2", "F1"),
}

_TOKEN = re.compile(r"^(?P<code>#[0-9A-Fa-f]{6}|[A-Za-z])(?P<pivot>/?)(?P<count>\d+)$")


class SettError(ValueError):
    """A sett text that cannot be read (the message names the token and the problem)."""


@dataclass(frozen=True)
class Stripe:
    """``threads`` yarns of one colour: ``colour`` linear RGB, or None for the fitted colour."""

    code: str
    threads: int
    colour: tuple[float, float, float] | None


def srgb_to_linear(value: float) -> float:
    """The linear value of a display (sRGB) value in [0, 1]."""
    return value / 12.92 if value <= 0.04045 else ((value + 0.055) / 1.055) ** 2.4


def _colour(code: str) -> tuple[float, float, float] | None:
    if code.upper() == NATURAL_CODE:
        return None
    hex_code = code if code.startswith("#") else COLOURS.get(code.upper(), (None, None))[1]
    if hex_code is None:
        known = ", ".join(f"{k} {name}" for k, (name, _) in COLOURS.items())
        raise SettError(f"unknown colour code {code!r} (known: {known}, {NATURAL_CODE} the fitted colour, "
                        f"#rrggbb)")
    return tuple(srgb_to_linear(int(hex_code[i:i + 2], 16) / 255.0) for i in (1, 3, 5))


def _tokens(text: str) -> list[tuple[str, bool, int]]:
    tokens = []
    for token in text.replace(",", " ").split():
        match = _TOKEN.match(token)
        if match is None:
            raise SettError(f"{token!r} is not a stripe: write a colour code and a thread count, like K4 or #1B2A5C8")
        count = int(match["count"])
        if not 0 < count <= MAX_THREADS:
            raise SettError(f"{token!r}: a stripe has 1 to {MAX_THREADS} threads")
        tokens.append((match["code"], bool(match["pivot"]), count))
    return tokens


def parse(text: str) -> tuple[Stripe, ...]:
    """The stripes of one direction's sett text (empty text: no stripes); raises SettError."""
    tokens = _tokens(text)
    pivots = [i for i, (_, pivot, _) in enumerate(tokens) if pivot]
    if pivots and (pivots != [0, len(tokens) - 1] or len(tokens) < 2):
        raise SettError("a symmetric sett marks exactly its first and last stripes as pivots (like B/24 K4 G/24)")
    if pivots:
        tokens = tokens + tokens[-2:0:-1]
    stripes: list[Stripe] = []
    for code, _, count in tokens:
        colour = _colour(code)
        if stripes and stripes[-1].colour == colour:
            stripes[-1] = Stripe(stripes[-1].code, stripes[-1].threads + count, colour)
        else:
            stripes.append(Stripe(code.upper(), count, colour))
    if len(stripes) > STRIPES:
        raise SettError(f"{len(stripes)} stripes in one repeat: the material holds at most {STRIPES}")
    return tuple(stripes)


def parse_pair(warp_text: str, weft_text: str = "") -> tuple[tuple[Stripe, ...], tuple[Stripe, ...]]:
    """(warp stripes, weft stripes); an empty weft text is the warp's sett. Errors name the direction."""
    setts = []
    for direction, text in zip(DIRECTIONS, (warp_text, weft_text)):
        try:
            setts.append(parse(text))
        except SettError as exc:
            raise SettError(f"{direction} sett: {exc}") from None
    if not weft_text.strip():
        setts[1] = setts[0]
    return setts[0], setts[1]


def socket_name(direction: str, index: int, what: str) -> str:
    """The node group input of one stripe: ``warp stripe 3 colour`` / ``warp stripe 3 threads``."""
    return f"{direction} stripe {index + 1} {what}"


def socket_values(warp: tuple[Stripe, ...], weft: tuple[Stripe, ...], fitted) -> dict[str, object]:
    """Node group input -> value for both directions' stripes; ``F`` stripes and unused ones (0
    threads) get ``fitted``, the fabric's base colour (core/dye.base_colour)."""
    values: dict[str, object] = {}
    for direction, stripes in zip(DIRECTIONS, (warp, weft)):
        for index in range(STRIPES):
            stripe = stripes[index] if index < len(stripes) else None
            colour = stripe.colour if stripe is not None and stripe.colour is not None else fitted
            values[socket_name(direction, index, "colour")] = tuple(float(c) for c in colour)
            values[socket_name(direction, index, "threads")] = stripe.threads if stripe is not None else 0
    return values


def yarn_colours(stripes: tuple[Stripe, ...], indices) -> list[tuple[float, float, float] | None]:
    """The stripe colour (None: the fitted colour) of the yarns with these global indices: the
    reference of what the shader draws (every yarn None where the sett has no threads)."""
    total = sum(s.threads for s in stripes)
    out = []
    for index in indices:
        if total == 0:
            out.append(None)
            continue
        position = index % total
        for stripe in stripes:
            if position < stripe.threads:
                out.append(stripe.colour)
                break
            position -= stripe.threads
    return out
