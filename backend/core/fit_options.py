"""The fit command's options: the one declaration of their names, values, defaults and help.

Everything else reads :data:`FIT_OPTIONS`: the ``fit`` and ``batch`` command lines (argparse built
from it in backend/app/cli/fit.py), the fit-a-folder job's options and their translation into
:class:`backend.fit.settings.FitSettings` (backend/app/folder.py), the add-on's request
(blender_addon/core/backend_bridge.py: :func:`command_line`) and the README's table of fit options
(:func:`markdown_table`); tests/test_fit_options.py keeps them in step. Torch-free, so that the
add-on reads it too (blender_addon/core/declarations.py).

Every value is checked here, with one line naming the option: text from a command line by
:meth:`FitOption.parse` (argparse's ``type``), typed values (the job's, the batch's, the add-on's)
by :func:`check_values`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

from .priors import FIT_PATTERNS
from .rig import DEFAULT_RIG, MAX_CAMERA_BLUR_PX, MAX_SAMPLE_ROTATION_DEG

# Kinds of value: one of ``choices``; an integer in [lo, hi]; 'auto' or a number in [lo, hi] (kept
# as its text); on when given; a path or a name; four integers (a box).
CHOICE, WHOLE, AUTO_OR_NUMBER, FLAG, TEXT, BOX = "choice", "whole", "auto_or_number", "flag", "text", "box"
_TYPES = {CHOICE: str, WHOLE: int, AUTO_OR_NUMBER: (str, int, float), FLAG: bool, TEXT: (str, os.PathLike),
          BOX: (tuple, list)}

MIN_WORKING_SIZE = 32   # the smallest working size of the loss the command takes (smaller: bad input)
MAX_SEED = 2**32 - 1    # the renders' jitter hashes the seed to 32 bits: a larger one repeats a smaller one's
# The re-renders' samples per pixel: 6 x 6, a square of an even side, so that the camera blur acts on
# sub-pixels (backend.model.render.subpixel_size); more samples hardly move the metrics
# (devtools/bench/results/history/backend.app.jsonl).
OUTPUT_SPP = 36
# --blur-on -> FitSettings.subpixel_blur: on the pixel means, on sub-pixels, or on sub-pixels only
# where the blur is narrow (None; backend.model.render.AUTO_SUBPIXEL_BELOW_PX)
BLUR_ON = {"pixels": False, "subpixels": True, "auto": None}
FIT_OR_NONE = {"fit": True, "none": False}
PHOTOS_OR_NONE = {"photos": True, "none": False}
FIT_OR_RIG = {"fit": True, "rig": False}


class FitOptionError(ValueError):
    """A fit option's value is malformed or out of range; the message names the option."""


@dataclass(frozen=True)
class FitOption:
    """Declaration of one option of the fit command.

    name: the job's field (``FolderFitOptions``) and argparse's ``dest``; the flag is ``--`` and
    the name with dashes. kind: one of the kinds above; choices, lo, hi: what it accepts (None: no
    bound); unit: what its numbers count, for messages. help: one line (``--help`` and the README);
    details: more, for the README; default_text: the README's words for a default of None.
    setting: the FitSettings field it sets (None: the job uses it otherwise), through ``setting_of``
    (choice -> the setting's value) where the two differ.
    batch: ``batch`` takes it too and passes it on to every pair's fit.
    """

    name: str
    kind: str
    default: Any
    help: str
    details: str = ""
    choices: tuple[str, ...] = ()
    lo: float | None = None
    hi: float | None = None
    unit: str = ""
    default_text: str = ""
    metavar: str | tuple[str, ...] | None = None
    setting: str | None = None
    setting_of: dict = field(default_factory=dict, compare=False)
    batch: bool = False

    @property
    def flag(self) -> str:
        return "--" + self.name.replace("_", "-")

    @property
    def expects(self) -> str:
        """What the option takes, in words (messages)."""
        of = f" of {self.unit}" if self.unit else ""
        return {CHOICE: "one of " + ", ".join(self.choices), WHOLE: f"a whole number{of}",
                AUTO_OR_NUMBER: f"'auto' or a number{of}", FLAG: "true or false", TEXT: "a path or a name",
                BOX: f"four whole numbers{of} (x, y, w, h)"}[self.kind]

    @property
    def expects_word(self) -> str:
        """What one command-line word of the option takes (a box's: one of its numbers)."""
        return f"a whole number{' of ' + self.unit if self.unit else ''}" if self.kind == BOX else self.expects

    @property
    def annotation(self) -> str:
        """The Python type of the option's values (a dataclass field's annotation)."""
        kind = {CHOICE: "str", WHOLE: "int", AUTO_OR_NUMBER: "str", FLAG: "bool", TEXT: "str",
                BOX: "tuple[int, int, int, int]"}[self.kind]
        return kind if self.default is not None else f"{kind} | None"

    def parse(self, text: str):
        """The value of ``text`` given on a command line (one of a box's four numbers); ValueError
        saying what is wrong (without the flag: argparse names it)."""
        if self.kind == CHOICE and text not in self.choices:
            raise ValueError(f"expected {self.expects}, got {text!r}")
        if self.kind in (CHOICE, FLAG, TEXT) or (self.kind == AUTO_OR_NUMBER and text == "auto"):
            return text
        try:
            value = float(text) if self.kind == AUTO_OR_NUMBER else int(text)
        except ValueError:
            raise ValueError(f"expected {self.expects_word}, got {text!r}") from None
        self._check_range(value, text)
        return text if self.kind == AUTO_OR_NUMBER else value

    def _check_range(self, value: float, text: str) -> None:
        unit = f" {self.unit}" if self.unit else ""
        if self.hi is not None and not self.lo <= value <= self.hi:
            raise ValueError(f"must be in [{_number(self.lo)}, {_number(self.hi)}]{unit}, got {text}")
        if self.lo is not None and not value >= self.lo:
            raise ValueError(f"must be at least {_number(self.lo)}{unit}, got {text}")

    def check(self, value) -> None:
        """Raises :class:`FitOptionError` naming the option where ``value`` (a typed value, not
        text) is not one it takes; None is its default where that is None."""
        if value is None and self.default is None:
            return
        wrong_type = (not isinstance(value, _TYPES[self.kind]) or isinstance(value, bool) != (self.kind == FLAG)
                      or self.kind == BOX and (len(value) != 4 or not all(_is_int(v) for v in value)))
        if wrong_type:
            raise FitOptionError(f"{self.flag}: expected {self.expects}, got {value!r}")
        try:
            for item in value if self.kind == BOX else (value,):
                self.parse(str(item))
        except ValueError as exc:
            raise FitOptionError(f"{self.flag}: {exc}") from None

    def arguments(self, value) -> list[str]:
        """The command-line words that give ``value`` (checked; none for None, the default where
        that is None, or an off flag)."""
        self.check(value)
        if value is None or value is False:
            return []
        if self.kind == FLAG:
            return [self.flag]
        return [self.flag, *(str(v) for v in (value if self.kind == BOX else (value,)))]

    def setting_value(self, value):
        """The FitSettings value of the option's ``value`` (an 'auto' capture value: None)."""
        if self.kind == AUTO_OR_NUMBER:
            return None if value == "auto" else float(value)
        return self.setting_of.get(value, value) if self.setting_of else value


def _number(bound: float) -> str:
    """A bound as written: 4294967295, 4, -45, 0.5."""
    return str(int(bound)) if float(bound).is_integer() else f"{bound:g}"


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


_FILM = DEFAULT_RIG.film_size
FIT_OPTIONS: tuple[FitOption, ...] = (
    FitOption("pattern", CHOICE, "auto", choices=("auto", *FIT_PATTERNS), setting="pattern", batch=True,
              help="the weave: auto (chosen from the photos, default), one of the paper's five, or the mirror image "
                   "of a twill or satin (its name + m: the diagonal running the other way, as in a fabric seen from "
                   "its back)",
              details="With auto the fit chooses among them all, but not a weave whose tile lattice makes much less "
                      "of the photos' strongest spectral peaks than another candidate's (the network rates each weave "
                      "on every lattice proposed for its family, plain, twill or satin, and may rule candidates out, "
                      "but not every one of a family it keeps on a lattice that makes those peaks)."),
    FitOption("iterations", WHOLE, None, lo=1, metavar="N", setting="iterations", batch=True,
              default_text="150 or 100",
              help="Adam steps of the winner's optimisation at most (default: 150 at 256 px, 100 at a larger working "
                   "size); it ends sooner once its best loss has not moved for 20 steps at its last learning rate",
              details="Discrete steps on the gap scale, twist and camera blur come after 25, 50 and 75 iterations; "
                      "where one falls inside the run, the optimisation does not end before it has had its turn. "
                      "From 10 steps after the last, it ends once its best loss has gained less than 0.05 % over the "
                      "last 10 steps. "
                      "A stall at a higher learning rate goes on from the best parameters at the last rate. Each of "
                      "its steps takes its gradient through a quarter of the film's rows, another quarter at each "
                      "step, while its loss is every pixel's: a step costs about 0.6 of one through every row, and "
                      "four steps' gradients add up to the whole one (the short runs whose ends are compared, the "
                      "trials, the duel and the variation's settling, take every row's; a compiled renderer takes "
                      "every row's too)."),
    FitOption("size", WHOLE, None, lo=MIN_WORKING_SIZE, unit="pixels", metavar="N", setting="size", batch=True,
              default_text=f"256 or {_FILM}",
              help=f"working size of the loss in pixels, {MIN_WORKING_SIZE} up to the photos' working size (the rig's "
                   f"film size, {_FILM}); default: 256, or {_FILM} where the yarns are too dense for 256 (the search "
                   "still runs at 256)",
              details=f"At {_FILM} px the pattern search still works at 256, then the optimisation at {_FILM} starts "
                      "from the chosen weave's starting point, its first 10 steps beside the weave's face twin on the "
                      "same lattice (every crossing turned over: `twill0` and `twill1m`, `twill1` and `twill0m`, "
                      "`satin0` and `satin1`, ...), which 256 px cannot tell from it: the twin goes on instead only "
                      "where its loss is then lower by more than 0.2."),
    FitOption("rig", TEXT, None, metavar="RIG.json", batch=True, default_text="the paper's rig",
              help="capture rig JSON (default: the paper's rig)"),
    FitOption("strict", FLAG, False, batch=True, help="refuse (not just warn) photos that look swapped"),
    FitOption("seed", WHOLE, 0, lo=0, hi=MAX_SEED, metavar="S", setting="seed", batch=True,
              help="seed of the fit's random numbers (its renders' sample jitter, torch's generator): the same photos, "
                   "options and seed give the same fit on one machine with one thread count (another processor or "
                   "thread count rounds sums differently, and a fit can end elsewhere)"),
    FitOption("camera_blur", AUTO_OR_NUMBER, "auto", lo=0.0, hi=MAX_CAMERA_BLUR_PX, unit="pixels", metavar="auto|PX",
              setting="camera_blur", batch=True,
              help="the camera's blur in film pixels: estimated with the fit (auto, default; a rig file's non-zero "
                   "camera_blur_px is kept) or fixed",
              details="With auto it is estimated by gradient with the fabric's parameters, never below the blur the "
                      "photos' noise spectrum reads, and with `--blur-ceiling photos` at most 1 pixel above it "
                      "(`camera_blur_px` in `params.json`'s rig; the range in its `fit`)."),
    FitOption("sample_rotation", AUTO_OR_NUMBER, "auto", lo=-MAX_SAMPLE_ROTATION_DEG, hi=MAX_SAMPLE_ROTATION_DEG,
              unit="degrees", metavar="auto|DEG", setting="sample_rotation", batch=True,
              help="how far the sample is turned in the holder (counter-clockwise, degrees): read from the photos with "
                   "its skew (auto, default; a rig file's non-zero sample_rotation_deg is kept) or fixed (then the rig "
                   "file's sample_skew_deg, 0 by default, is kept too)",
              details="Where the lattices found at one turn make few of the photos' strongest spectral peaks, another "
                      "turn the spectra suggest is tried, and kept where its lattices make them. The skew, read where "
                      "both photos clearly show one, is the few degrees a cloth is pulled out of square "
                      "(`sample_rotation_deg`, `sample_skew_deg`: the warps turned by rotation + skew / 2, the wefts "
                      "by rotation - skew / 2)."),
    FitOption("light_falloff", CHOICE, "fit", choices=tuple(FIT_OR_NONE), setting="light_falloff",
              setting_of=FIT_OR_NONE, batch=True,
              help="the photos' smooth light falloff (a tilt and a bowl per photo, which the rig's point lamps do not "
                   "make): solved with the fit and kept out of the material (fit, default), or none",
              details="The falloff is in the re-renders and `params.json`, never in the material."),
    FitOption("spacing_warp", CHOICE, "fit", choices=tuple(FIT_OR_NONE), setting="spacing_warp",
              setting_of=FIT_OR_NONE, batch=True,
              help="the photos' uneven yarn spacing (a smooth warp of the lattice, read from the phase of its "
                   "harmonics against the fit's renders): read with the fit and kept out of the material (fit, "
                   "default), or none (the renders' yarns evenly spaced)",
              details="It is read again before each discrete step and kept where it lowers the loss; it is in the "
                      "re-renders and in `params.json` as `fit.spacing_warp`, never in the material."),
    FitOption("glow", CHOICE, "rig", choices=tuple(FIT_OR_RIG), setting="estimate_glow", setting_of=FIT_OR_RIG,
              batch=True,
              help="the back light's glow seen through the yarns' gaps: the rig's glow_strength (rig, default), or "
                   "read from the photos at the first discrete step (fit: the strength among a few whose "
                   "transmission's block colours are closest)",
              details="A lamp behind a diffuser shows no round spot through the gaps. Not the default: read that "
                      "early, before the parameters are the photos', it misreads renders made with the rig's glow "
                      "and moves the rest of the fit, better on some real pairs and worse on others (the "
                      "benchmark's results). The strength used is `glow_strength` in `params.json`'s rig and in "
                      "the re-renders, never in the material."),
    FitOption("blur_on", CHOICE, "pixels", choices=tuple(BLUR_ON), setting="subpixel_blur", setting_of=BLUR_ON,
              batch=True,
              help="where the camera blur acts in the fit's own renders: on the pixel means (pixels, default), on "
                   "sub-pixels as the optics do before the sensor (subpixels), or on sub-pixels only where the blur "
                   "is under 1.2 render pixels (auto: closer fits of dense plain weaves, slower; no better on the "
                   "twills measured)"),
    FitOption("blur_ceiling", CHOICE, "none", choices=tuple(PHOTOS_OR_NONE), setting="blur_ceiling",
              setting_of=PHOTOS_OR_NONE, batch=True,
              help="the most camera blur an estimated blur may reach: none (default: up to the rig's 4 pixels) or "
                   "what the photos allow (photos: the blur their noise spectrum reads, plus 1 pixel)",
              details="A pixel loss falls wherever a softer render hides what the model cannot draw (a yarn texture, "
                      "speckle, a random yarn pattern), so a fit can blur a sharp photo's texture away. With photos "
                      "the re-renders keep the yarn texture (the texture gap falls) and the blur comes within a few "
                      "tenths of a pixel of a phone's, but the other parameters then make up for what the blur hid: "
                      "not the default, as a satin's transmission colour can go far off (the benchmark's results). "
                      "A blur left at the ceiling is listed with the parameters at a bound."),
    FitOption("init", CHOICE, "network", choices=("network", "prior"), batch=True,
              help="starting parameters: the shipped network's prediction (network, default: "
                   "backend/data/init_net.pt) or the pattern's prior"),
    FitOption("output_spp", WHOLE, OUTPUT_SPP, lo=1, metavar="N", batch=True,
              help=f"samples per pixel of the re-renders (default {OUTPUT_SPP}; a square of an even side, k x k, lets "
                   "the camera blur act on sub-pixels)"),
    FitOption("device", TEXT, "cpu", metavar="DEVICE", setting="device",
              help="torch device of the fit: cpu (default), cuda or cuda:N (batch: --gpus-per-fit)"),
    FitOption("crop", BOX, None, unit="pixels", metavar=("X", "Y", "W", "H"),
              default_text="the largest centred square",
              help="square crop box in photo pixels (default: the centred largest square)"),
    FitOption("flat_field", TEXT, None, metavar="PATH",
              help="photo of a uniform target under the same light (vignetting)"),
    FitOption("vgg_weights", TEXT, None, metavar="PATH", setting="vgg_weights",
              help="a VGG-19 features state dict you provide: adds the paper's Gram loss (slow on a CPU)"),
    FitOption("overwrite", FLAG, False, help="replace an earlier fit in --out"),
)
OPTIONS: dict[str, FitOption] = {option.name: option for option in FIT_OPTIONS}
BATCH_OPTIONS: tuple[FitOption, ...] = tuple(option for option in FIT_OPTIONS if option.batch)


def check_values(values: dict) -> None:
    """Raises :class:`FitOptionError` (naming the option) for the first value of ``values`` (name ->
    value) that its option does not take, or for a name that is no option."""
    for name, value in values.items():
        if name not in OPTIONS:
            raise FitOptionError(f"{name}: not an option of the fit; known: {', '.join(OPTIONS)}")
        OPTIONS[name].check(value)


def command_line(values: dict) -> list[str]:
    """The ``fit`` command-line words that give ``values`` (name -> value, None: the default), in
    their order; each checked first (:class:`FitOptionError`)."""
    given = {name: value for name, value in values.items() if value is not None}
    check_values(given)
    return [word for name, value in given.items() for word in OPTIONS[name].arguments(value)]


# -- the README's table -------------------------------------------------------------------------

def _values_cell(option: FitOption) -> str:
    unit = f" {option.unit}" if option.unit else ""
    if option.kind == CHOICE:
        return ", ".join(f"`{choice}`" for choice in option.choices)
    if option.kind == WHOLE:
        bound = (f"{_number(option.lo)} to {_number(option.hi)}" if option.hi is not None
                 else f"at least {_number(option.lo)}")
        return f"`{option.metavar}`: {bound}{unit}"
    if option.kind == AUTO_OR_NUMBER:
        return f"`auto`, or {_number(option.lo)} to {_number(option.hi)}{unit}"
    if option.kind == BOX:
        return f"`{' '.join(option.metavar)}`"
    return "(flag)" if option.kind == FLAG else f"`{option.metavar}`"


def _default_cell(option: FitOption) -> str:
    if option.kind == FLAG:
        return "off"
    if option.default is None:
        return option.default_text or "none"
    return f"`{option.default}`"


def markdown_table(options: tuple[FitOption, ...] = FIT_OPTIONS) -> str:
    """The README's table of the options (GitHub markdown): flag, values, default, whether ``batch``
    takes it, help and details."""
    rows = ["| option | values | default | `batch` | what it does |", "|---|---|---|---|---|"]
    for option in options:
        text = f"{option.help}. {option.details}" if option.details else option.help
        cells = (f"`{option.flag}`", _values_cell(option), _default_cell(option), "yes" if option.batch else "",
                 text)
        rows.append("| " + " | ".join(cell.replace("|", "\\|") for cell in cells) + " |")
    return "\n".join(rows)
