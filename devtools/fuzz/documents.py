"""params.json and rig file cases: a valid document, one mutation of it, fed to the command that reads it.

- params.json: as ``fit`` writes it (the parameters, the interchange string, version, rig, fit
  details); read by ``render PARAMS.json`` (:func:`backend.core.params.load_params`).
- rig file: a film of :data:`.images.FILM` pixels and some of the rig's settings; read by ``fit
  --rig`` on the base pair.

Mutations: a value of the wrong type (text, a number as text, true, null, a list, an object), a key
removed or unknown, NaN or an infinity (JSON's non-standard literals, which Python reads), a
value out of range, a huge array, an integer of thousands of digits, arrays nested thousands deep,
an unknown or unhashable weave, a custom weave drawn at random, a document that is not an object,
broken JSON syntax, text that is not UTF-8.
"""
from __future__ import annotations

import json
import math

import numpy as np

from backend.core.params import PARAMETERS, FabricParams
from backend.core.rig import DEFAULT_RIG

from .cases import EITHER, FIT, REFUSE, Case
from .images import ENCODINGS, FILM, base_pair

_WRONG_TYPES = ("text", "0.5", True, None, [], {}, [[0.5, 0.5]], {"warp": 0.5})
_NON_FINITE = (math.nan, math.inf, -math.inf)
_PARAMETER_NAMES = tuple(spec.name for spec in PARAMETERS)


def _params_document(rng) -> dict:
    params = FabricParams.clamped_from(pattern=str(rng.choice(["plain", "twill0", "twill1m", "satin1"])),
                                       roughness=rng.uniform(0.1, 0.9, 2).tolist(), tiles=[80.0, 96.0])
    return json.loads(params.to_json(interchange=params.to_interchange(), version="0.1.0", rig=DEFAULT_RIG.to_dict(),
                                      fit={"loss": 0.1, "settings": {"pattern": "auto", "size": 256}},
                                      photos={"size": 512}))


def _rig_document(rng) -> dict:
    document = {"film_size": FILM}
    for name, value in DEFAULT_RIG.to_dict().items():
        if name != "film_size" and rng.random() < 0.4:
            document[name] = value
    return document


def _leaf_paths(value, path=()):
    """Every path (tuple of keys and indices) to a number in ``value``."""
    if isinstance(value, dict):
        return [p for key, item in value.items() for p in _leaf_paths(item, (*path, key))]
    if isinstance(value, list):
        return [p for index, item in enumerate(value) for p in _leaf_paths(item, (*path, index))]
    return [path] if isinstance(value, (int, float)) and not isinstance(value, bool) else []


def _set(document, path, value):
    target = document
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value


class _Doc:
    """A document being mutated, and which keys are read (a change to another key changes nothing)."""

    def __init__(self, document: dict, read: tuple[str, ...], optional: tuple[str, ...]):
        self.document, self.read, self.optional = document, read, optional

    def pick_path(self, rng, read_only: bool):
        paths = [p for p in _leaf_paths(self.document) if not read_only or p[0] in self.read]
        return paths[int(rng.integers(len(paths)))]

    def expect_for(self, path) -> str:
        return REFUSE if path[0] in self.read else FIT


def _wrong_type(doc: _Doc, rng):
    path = doc.pick_path(rng, read_only=rng.random() < 0.8)
    value = _WRONG_TYPES[int(rng.integers(len(_WRONG_TYPES)))]
    where = path[:1] if rng.random() < 0.5 else path  # the whole value, or one of its numbers
    _set(doc.document, where, value)
    return f"{'.'.join(map(str, where))} = {value!r}", doc.expect_for(path)


def _non_finite(doc: _Doc, rng):
    path = doc.pick_path(rng, read_only=rng.random() < 0.8)
    value = _NON_FINITE[int(rng.integers(3))]
    _set(doc.document, path, value)
    return f"{'.'.join(map(str, path))} = {value}", doc.expect_for(path)


def _out_of_range(doc: _Doc, rng):
    path = doc.pick_path(rng, read_only=True)
    value = float((-1.0, 0.0, 1e6, -1e9, 1e300)[int(rng.integers(5))])
    _set(doc.document, path, value)
    return f"{'.'.join(map(str, path))} = {value}", EITHER  # 0 and -1 are in range for some


def _huge_array(doc: _Doc, rng):
    path = doc.pick_path(rng, read_only=rng.random() < 0.8)
    length = int(rng.choice([10_000, 1_000_000]))
    _set(doc.document, path[:1], [0.5] * length)
    return f"{path[0]} = [0.5] * {length}", doc.expect_for(path)


def _removed(doc: _Doc, rng):
    keys = list(doc.document)
    key = keys[int(rng.integers(len(keys)))]
    del doc.document[key]
    return f"{key} removed", EITHER if key in doc.optional else (REFUSE if key in doc.read else FIT)


def _unknown_keys(doc: _Doc, rng):
    count = int(rng.choice([1, 20_000]))
    doc.document.update((f"extra_{index}", 1.0) for index in range(count))
    return f"{count} unknown key(s)", EITHER


MUTATIONS = {"wrong-type": _wrong_type, "non-finite": _non_finite, "out-of-range": _out_of_range,
             "huge-array": _huge_array, "removed": _removed, "unknown-keys": _unknown_keys}
TEXT_MUTATIONS = ("huge-integer", "deep-nesting", "not-an-object", "syntax", "not-utf8")


def _text_mutation(mutation: str, text: str, rng) -> tuple[bytes, str]:
    if mutation == "huge-integer":
        return text.replace("{", '{"big": ' + "9" * int(rng.integers(4400, 20000)) + ", ", 1).encode(), "a huge integer"
    if mutation == "deep-nesting":
        depth = int(rng.choice([2_000, 100_000]))
        return text.replace("{", '{"deep": ' + "[" * depth + "]" * depth + ", ", 1).encode(), f"nested {depth} deep"
    if mutation == "not-an-object":
        other = ("[]", "3", '"text"', "null", "[1, 2]")[int(rng.integers(5))]
        return other.encode(), f"the document is {other}"
    if mutation == "syntax":
        cut = int(rng.integers(0, len(text)))
        return text[:cut].encode() + b"}{", f"cut at {cut} and garbage"
    return b"\xff\xfe" + text.encode("utf-16-le"), "UTF-16 text"


def _document_case(kind: str, doc: _Doc, mutation: str, rng, command, files, suspects) -> Case:
    if mutation in MUTATIONS:
        label, expect = MUTATIONS[mutation](doc, rng)
        data = json.dumps(doc.document).encode()
    else:
        data, label = _text_mutation(mutation, json.dumps(doc.document), rng)
        expect = REFUSE
    name = "params.json" if kind == "params" else "rig.json"
    return Case(kind, f"{mutation}: {label}", ((name, data), *files), command, (name, *suspects), expect)


def params_cases(count: int, seed: int = 0) -> list[Case]:
    """``count`` params.json cases (``render`` on each), the same for the same seed."""
    mutations = (*MUTATIONS, *TEXT_MUTATIONS, "pattern", "custom-weave")
    command = ("render", "{dir}/params.json", "--out", "{dir}/render", "--size", "8", "--spp", "1")
    cases = []
    for index in range(count):
        rng = np.random.default_rng((seed, index))
        mutation = mutations[index % len(mutations)]
        document = _params_document(rng)
        doc = _Doc(document, ("pattern", *_PARAMETER_NAMES), _PARAMETER_NAMES)
        if mutation in ("pattern", "custom-weave"):
            cases.append(_weave_case(mutation, document, rng, command))
            continue
        cases.append(_document_case("params", doc, mutation, rng, command, (), ()))
    return cases


def _weave_case(mutation: str, document: dict, rng, command) -> Case:
    if mutation == "pattern":
        value = ("satin9", "", 5, None, ["plain"], {"name": "plain"}, "PLAIN", "custom")[int(rng.integers(8))]
        document["pattern"] = value
        label = f"pattern = {value!r}"
    else:
        rows, cols = int(rng.integers(0, 5)), int(rng.integers(0, 5))
        matrix = rng.integers(0, 3, (rows, cols)).tolist() if rng.random() < 0.5 else "0110"
        document["pattern"], document["weave"] = "custom", {"matrix": matrix}
        for key in ("warp_width", "warp_pitch", "weft_offset", "umax_deg", "s_min"):
            if rng.random() < 0.3:
                document["weave"][key] = _WRONG_TYPES[int(rng.integers(len(_WRONG_TYPES)))] if rng.random() < 0.5 \
                    else float(rng.uniform(-2, 4))
        label = f"weave = {document['weave']!r}"[:200]
    return Case("params", f"{mutation}: {label}", (("params.json", json.dumps(document).encode()),), command,
                ("params.json",), EITHER if mutation == "custom-weave" else REFUSE)


def rig_cases(count: int, seed: int = 0) -> list[Case]:
    """``count`` rig file cases (``fit --rig`` on the base pair), the same for the same seed."""
    reflection, transmission = base_pair()
    encode = ENCODINGS["png8"][1]
    photos = (("cloth_R.png", encode(reflection)), ("cloth_T.png", encode(transmission)))
    command = ("fit", "{dir}/cloth_R.png", "{dir}/cloth_T.png", "--rig", "{dir}/rig.json", "--out", "{dir}/out",
               "--json-progress")
    mutations = (*MUTATIONS, *TEXT_MUTATIONS)
    fields = tuple(DEFAULT_RIG.to_dict())
    cases = []
    for index in range(count):
        rng = np.random.default_rng((seed, index))
        document = _rig_document(rng)
        doc = _Doc(document, fields, tuple(f for f in fields if f != "film_size"))
        mutation = mutations[index % len(mutations)]
        # a valid rig of another film size can leave the photos too small: the refusal then names them
        cases.append(_document_case("rig", doc, mutation, rng, command, photos, ("cloth_R.png", "cloth_T.png")))
    return cases
