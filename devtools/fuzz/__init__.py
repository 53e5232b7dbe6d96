"""The fuzz harness of bad input (issue 91): generated cases of every kind of input the fit command
takes, run against the contract (:mod:`.runner`): a result, or exit code 2 with one line naming the
file or option and the problem; never a traceback, a hang, a crash or a result from NaN.

Kinds: ``photo`` (:mod:`.photos`: mutated photo files in every format), ``options`` (:mod:`.options`:
combinations of valid and invalid ``fit`` options), ``params`` and ``rig`` (:mod:`.documents`:
mutated params.json and rig files). Cases are drawn from seeded generators, so a seed gives the same
cases every time. ``python -m devtools fuzz`` runs the full set and prints the counts;
tests/test_fuzz.py runs a small one.
"""
from __future__ import annotations

from .cases import Case
from .documents import params_cases, rig_cases
from .options import option_cases
from .photos import photo_cases

GENERATORS = {"photo": photo_cases, "options": option_cases, "params": params_cases, "rig": rig_cases}


def cases(counts: dict[str, int], seed: int = 0) -> list[Case]:
    """``counts[kind]`` cases of each kind, drawn with ``seed``."""
    return [case for kind, count in counts.items() for case in GENERATORS[kind](count, seed)]
