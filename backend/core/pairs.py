"""Photo pairs in a folder: ``<name>_R.<ext>`` (reflection, lit from the front) and ``<name>_T.<ext>``
(transmission, lit from behind); the side letter may be lower case, the suffix any of
:data:`backend.core.formats.PHOTO_SUFFIXES`. One rule for every batch (the backend's, the add-on's).

A name with a missing partner, or with two candidate files for one side, is a :class:`PairProblem`
whose message names the files. Plain Python: the add-on reads this module without torch.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from .formats import PHOTO_SUFFIXES

_PAIR_NAME = re.compile(r"^(?P<name>.+)_(?P<side>[RrTt])$")


@dataclass(frozen=True)
class PhotoFiles:
    """The two files of one pair (the working images are :class:`backend.image.photos.PhotoPair`)."""

    name: str
    reflection: Path
    transmission: Path


@dataclass(frozen=True)
class PairProblem:
    name: str
    message: str


def find_pairs(folder: str | Path) -> tuple[list[PhotoFiles], list[PairProblem]]:
    """Every ``<name>_R.* / <name>_T.*`` pair of a folder (not recursive), sorted by name."""
    folder = Path(folder)
    sides: dict[str, dict[str, list[Path]]] = {}
    for path in sorted(folder.iterdir()):
        if not path.is_file() or path.suffix.lower() not in PHOTO_SUFFIXES:
            continue
        match = _PAIR_NAME.match(path.stem)
        if match:
            side = match["side"].upper()
            sides.setdefault(match["name"], {"R": [], "T": []})[side].append(path)
    pairs, problems = [], []
    for name in sorted(sides):
        found = sides[name]
        if len(found["R"]) == 1 and len(found["T"]) == 1:
            pairs.append(PhotoFiles(name, found["R"][0], found["T"][0]))
            continue
        for side, label, partner in (("R", "reflection", "T"), ("T", "transmission", "R")):
            if not found[side]:
                problems.append(PairProblem(name, f"no {label} photo ({name}_{side}.*) beside "
                                                  f"{', '.join(p.name for p in found[partner])}"))
            elif len(found[side]) > 1:
                problems.append(PairProblem(name, f"more than one {label} photo "
                                                  f"({', '.join(p.name for p in found[side])}); keep one"))
    return pairs, problems
