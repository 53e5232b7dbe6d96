"""A fuzz case: files, a command line over them, and what its end may be.

A case is plain data (it travels to the worker process that runs it): the files to write into a
fresh folder, the ``python -m backend`` command line run on them (``{dir}`` stands for that folder),
the names a refusal may give (the files and options the case made bad, or may have), and what is
expected of it: a result (``FIT``), a refusal (``REFUSE``), or either (``EITHER``: a mutation that
may leave the input valid, such as a bit flip in a photo's pixels).
"""
from __future__ import annotations

from dataclasses import dataclass

FIT, REFUSE, EITHER = "fit", "refuse", "either"


@dataclass(frozen=True)
class Case:
    kind: str                           # photo, options, params, rig
    label: str                          # what was done to the input, in words
    files: tuple[tuple[str, bytes], ...]
    command: tuple[str, ...]            # the command line, "{dir}" for the case's folder
    suspects: tuple[str, ...]           # a refusal names one of these (a file's name or an option's flag)
    expect: str = EITHER
    loader: tuple[str, str] | None = None  # also fed to load_pair directly: (reflection, transmission) names
