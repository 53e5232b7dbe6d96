"""Option sets: the ``fit`` command on the base pair with random combinations of valid and invalid
values for every option of :data:`backend.core.fit_options.FIT_OPTIONS` and ``--out`` (the photos'
own problems are the photo cases', :mod:`.photos`).

About two sets in five are valid throughout (each option absent or given a valid value): they must
reach the fit. The others make one to three options invalid: they must be refused, naming one of them.
Every set gives ``--rig`` (a valid one has the film size :data:`.images.FILM`, so that the base
pair loads fast); the other options are absent or given in turn.

A value is a list of command-line words (a flag's: none) and the files it needs (name -> bytes).
"""
from __future__ import annotations

import json

import numpy as np

from backend.core.fit_options import FIT_OPTIONS

from .cases import FIT, REFUSE, Case
from .images import ENCODINGS, FILM, SIDE, base_pair

_RIG = {"film_size": FILM}
_FILES = {
    "rig.json": json.dumps(_RIG).encode(),
    "rig_moved.json": json.dumps({**_RIG, "camera_height": 7.5, "fov_deg": 50.0, "camera_blur_px": 1.2,
                                   "sample_rotation_deg": -3.0, "width_cm": 4.0}).encode(),
    "rig_lights.json": json.dumps({**_RIG, "front_light": [1.0, 6.0, 9.0], "back_light": [0, 0.5, -7]}).encode(),
    "rig_huge_film.json": json.dumps({"film_size": 100000}).encode(),
    "rig_negative.json": json.dumps({**_RIG, "camera_height": -8}).encode(),
    "rig_text.json": json.dumps({**_RIG, "fov_deg": "wide"}).encode(),
    "rig_unknown.json": json.dumps({**_RIG, "flash": True}).encode(),
    "rig_list.json": b"[64]",
    "rig_broken.json": b'{"film_size": 64,',
    "weights_garbage.pt": b"\x80\x04not a torch file",
    "notes.txt": b"not an image",
}
_OUT_WITH_FIT = (["{dir}/out_with_fit"], ("out_with_fit",))
_PHOTOS = ("cloth_R.png", "cloth_T.png")
VALID_SHARE = 0.4                 # of the option sets, valid throughout
ALWAYS_GIVEN = ("rig", "out")     # the others are absent (their default) half the time
_FLAGS = {**{option.name: option.flag for option in FIT_OPTIONS}, "out": "--out"}


def _file_value(name: str):
    return [f"{{dir}}/{name}"], (name,)


# option name -> (valid values, invalid values); a value is (words, file names it uses)
def _values() -> dict[str, tuple[list, list]]:
    return {
        "pattern": (_each(*FIT_OPTIONS[0].choices), _each("", "PLAIN", "twill9", "satin", "plain ", "auto,plain", "ñ")),
        "iterations": (_each("1", "7", "150", "1_000", " 12", "99999999999999999999"),
                       _each("0", "-3", "1.5", "1e3", "", "nan", "inf", "0x10", "three")),
        "size": (_each("32", "48", str(FILM)), _each("31", "0", "-64", str(FILM + 1), "4096", "64.0", "", "abc")),
        "rig": ([_file_value("rig.json"), _file_value("rig_moved.json"), _file_value("rig_lights.json")],
                [_file_value(name) for name in ("rig_huge_film.json", "rig_negative.json", "rig_text.json",
                                                "rig_unknown.json", "rig_list.json", "rig_broken.json",
                                                "missing_rig.json", "notes.txt")]
                + [_file_value("rig_folder.json")]),
        "strict": ([([], ())], []),
        "seed": (_each("0", "42", "4294967295"), _each("-1", "4294967296", "1.5", "", "x")),
        "camera_blur": (_each("auto", "0", "1.5", "4"), _each("-0.1", "4.01", "nan", "inf", "-inf", "", "Auto",
                                                              "1e400")),
        "sample_rotation": (_each("auto", "-45", "0", "12.5"), _each("46", "-45.5", "nan", "", "auto!")),
        "light_falloff": (_each("fit", "none"), _each("yes", "")),
        "spacing_warp": (_each("fit", "none"), _each("no", "FIT")),
        "blur_on": (_each("pixels", "subpixels", "auto"), _each("sub-pixels", "")),
        "init": (_each("network", "prior"), _each("net", "")),
        "output_spp": (_each("1", "36"), _each("0", "-1", "2.5")),
        "device": (_each("cpu", "cpu:0"), _each("tpu", "", "meta", "cuda:99", "cpu:-1", "gpu")),
        "crop": (_each_box("0 0 96 96", "10 10 64 64", "0 0 48 48", "32 0 64 64"),
                 [(words, (*files, *_PHOTOS)) for words, files in _each_box(  # the loader names the photos
                     "0 0 96 95", "-1 0 64 64", "50 50 64 64", "0 0 0 0", "0 0 16 16", "a b c d", "1.5 0 64 64",
                     "0 0 200 200")]),
        "flat_field": ([_file_value("flat.png")],
                       [_file_value(name) for name in ("flat_small.png", "flat_black.png", "notes.txt",
                                                       "missing_flat.png")]),
        "vgg_weights": ([], [_file_value(name) for name in ("weights_garbage.pt", "missing_weights.pt", "notes.txt")]),
        "overwrite": ([([], ())], []),
        "out": ([(["{dir}/out_new"], ()), (["{dir}/deeper/still/out"], ())],
                [(["/proc/forbidden/out"], ("/proc/forbidden/out",)), (["{dir}/notes.txt"], ("notes.txt",)),
                 (["{dir}/notes.txt/out"], ("notes.txt",)), ([""], ("--out",)), _OUT_WITH_FIT]),
    }


def _each(*texts):
    return [([text], ()) for text in texts]


def _each_box(*texts):
    return [(text.split(), ()) for text in texts]


def _image_files() -> dict[str, bytes]:
    """The base pair and the flat-fields the values name, as 8-bit PNGs."""
    reflection, transmission = base_pair()
    encode = ENCODINGS["png8"][1]
    yy, xx = (np.mgrid[0:SIDE, 0:SIDE] + 0.5) / SIDE
    vignette = np.exp(-((xx - 0.5) ** 2 + (yy - 0.5) ** 2) / 0.5)[..., None] * np.ones(3, np.float32)
    return {"cloth_R.png": encode(reflection), "cloth_T.png": encode(transmission),
            "flat.png": encode(0.7 * vignette), "flat_small.png": encode(0.7 * vignette[:48, :48]),
            "flat_black.png": encode(np.zeros_like(vignette)), "notes.txt": _FILES["notes.txt"],
            "out_with_fit/params.json": b"{}", "rig_folder.json/.keep": b""}


def option_cases(count: int, seed: int = 0) -> list[Case]:
    """``count`` option sets, the same for the same seed."""
    values, images = _values(), _image_files()
    can_be_bad = [name for name, (_, wrong) in values.items() if wrong]
    cases = []
    for index in range(count):
        rng = np.random.default_rng((seed, index))
        bad = set()
        if rng.random() >= VALID_SHARE:
            bad = {str(name) for name in rng.choice(can_be_bad, int(rng.integers(1, 4)), replace=False)}
        given = [name for name, (good, _) in values.items()
                 if name in bad or (good and (name in ALWAYS_GIVEN or rng.random() < 0.5))]
        picks = {name: _pick(values[name][1 if name in bad else 0], rng) for name in given}
        if picks.get("out") == _OUT_WITH_FIT and "overwrite" in picks:
            bad.discard("out")  # a folder holding a fit, with --overwrite: valid after all
        cases.append(_case(picks, bad, images))
    return cases


def _pick(choices: list, rng):
    return choices[int(rng.integers(len(choices)))]


def _case(picks: dict, bad: set, images: dict) -> Case:
    words, labels, suspects, used = [], [], [], set()
    for name, (value_words, files) in picks.items():
        flag = _FLAGS[name]
        words += [flag, *value_words]
        labels.append(" ".join([flag, *value_words]) + (" (bad)" if name in bad else ""))
        used |= {file for file in files if file in _FILES}
        if name in bad:
            suspects += [flag, *files]
    content = {**images, **{name: _FILES[name] for name in used}}
    command = ("fit", "{dir}/cloth_R.png", "{dir}/cloth_T.png", *words)
    return Case("options", " ".join(labels), tuple(content.items()), command, tuple(suspects),
                REFUSE if bad else FIT)
