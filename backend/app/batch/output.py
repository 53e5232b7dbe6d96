"""The batch's output folder DIR: one results folder per pair, there whole or not at all.

::

    DIR/<name>/              what ``python -m backend fit --out`` writes (core/results.py's RESULT_FILES)
    DIR/catalogue.json, .csv one row per pair (catalogue.py)
    DIR/logs/<name>.log      what the pair's fits said (warnings, errors, tracebacks), every attempt
    DIR/.staging/            results being written
    DIR/.incomplete/         incomplete results folders found by --resume, moved aside

Only the batch's driver writes here (the fits run in temporary folders on whichever machine Ray
chose and send their files back). A pair's files go into ``.staging/<name>`` first and the folder
is renamed to ``DIR/<name>`` once all are written, so a batch killed at any moment leaves no half
folder under a pair's name; a leftover ``.staging`` is emptied by the next run.

Nothing is overwritten: a new batch refuses a DIR that already holds results (the catalogue or a
pair's folder) unless it resumes. Resuming keeps every complete folder; an incomplete one (a copy
cut short, a file deleted by hand) is moved aside to ``DIR/.incomplete/<name>-N`` and the pair is
fitted again. (Folders whose names start with a dot are the batch's own: the Blender batch's
``--from-results`` passes them by.)
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

from ...core.results import is_complete
from .catalogue import CSV_NAME, JSON_NAME

LOGS, STAGING, INCOMPLETE = "logs", ".staging", ".incomplete"
RESERVED = (LOGS, STAGING, INCOMPLETE, JSON_NAME, CSV_NAME)  # the batch's own files: no pair may use these names


def name_problem(name: str) -> str | None:
    """Why a pair's name cannot be a folder of DIR (one of the batch's own names, or hidden), or None."""
    if name in RESERVED or name.startswith("."):
        return f"the name {name!r} is reserved for the batch's own files in the output folder; rename the photos"
    return None


class OutputError(ValueError):
    """DIR cannot take this batch; the message names the folder and says what to do."""


def prepare(out: Path, names: list[str], resume: bool) -> tuple[list[str], list[Path]]:
    """Makes DIR ready: returns the names whose complete folders are kept and the incomplete folders
    moved aside (both empty unless ``resume``)."""
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    earlier = [name for name in names if (out / name).exists()]
    if not resume and (earlier or (out / JSON_NAME).exists()):
        found = f"results of {len(earlier)} of these pairs" if earlier else "an earlier batch's catalogue"
        raise OutputError(f"{out}: already holds {found}; pass --resume to keep them and fit the rest, "
                          "or choose a new --out")
    (out / LOGS).mkdir(parents=True, exist_ok=True)
    remove_staging(out)  # a killed batch's leftovers: never renamed, so never a result
    kept, moved = [], []
    for name in earlier:
        if is_complete(out / name):
            kept.append(name)
        else:
            moved.append(move_aside(out / name))
    return kept, moved


def move_aside(folder: Path) -> Path:
    """Moves an incomplete results folder to ``DIR/.incomplete/<name>-N`` (the first free N)."""
    aside = folder.parent / INCOMPLETE
    aside.mkdir(exist_ok=True)
    for number in range(1, 100000):
        target = aside / f"{folder.name}-{number}"
        if not target.exists():
            folder.rename(target)
            return target
    raise OutputError(f"{folder}: no free name to move the incomplete folder aside")


def write_result(out: Path, name: str, files: dict[str, bytes]) -> Path:
    """Writes one pair's files as ``DIR/<name>`` (through ``.staging``) and returns the folder."""
    staging = out / STAGING / name
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    for file_name, data in files.items():
        (staging / file_name).write_bytes(data)
    target = out / name
    if target.exists():  # appeared while the pair was fitting (someone else writes here): keep it
        move_aside(target)
    staging.rename(target)
    return target


def remove_staging(out: Path) -> None:
    """Removes ``.staging`` when the batch ends (every pair's files are in place by then)."""
    shutil.rmtree(out / STAGING, ignore_errors=True)


def write_log(out: Path, name: str, attempt: int, text: str) -> Path:
    """Adds one attempt's log to ``DIR/logs/<name>.log`` (earlier attempts and runs stay above it)."""
    path = out / LOGS / f"{name}.log"
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(f"--- {name}, attempt {attempt}, {time.strftime('%Y-%m-%d %H:%M:%S')}\n{text}")
    return path
