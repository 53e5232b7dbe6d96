"""What every command shares: the input-error convention, argument types, the device."""
from __future__ import annotations

import argparse

import torch

from ...core.options import OptionsError
from ...core.params import ParamError
from ...core.rig import RigError
from ...core.weave import WeaveError


class InputError(ValueError):
    """Bad user input detected by the command line layer."""


# Errors that mean "the user's input is wrong": exit code 2 and one line naming the file and the problem.
INPUT_ERRORS = (InputError, ParamError, RigError, OptionsError, WeaveError, FileNotFoundError)


def input_error_message(exc: BaseException) -> str:
    return f"{exc.filename}: file not found" if isinstance(exc, FileNotFoundError) else str(exc)


def folder_name(text: str) -> str:
    """argparse type of ``--out``: a path, not an empty word (which would be the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a folder, got an empty name")
    return text


def positive_int(text: str) -> int:
    """argparse type: an integer of at least 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def device(name: str) -> torch.device:
    """The torch device ``name`` (cpu, cuda or cuda:N); an :class:`InputError` naming ``--device``
    when it is no such device, or CUDA is asked for and missing."""
    try:
        chosen = torch.device(name)
    except (RuntimeError, TypeError, ValueError):  # torch's word for a name it cannot parse
        chosen = None
    if chosen is None or chosen.type not in ("cpu", "cuda"):
        raise InputError(f"--device {name!r}: not a device the backend runs on (expected cpu, cuda or cuda:N)")
    if chosen.type == "cuda" and not torch.cuda.is_available():
        raise InputError(f"--device {name}: CUDA is not available in this PyTorch build or on this machine")
    if chosen.type == "cuda" and chosen.index is not None and chosen.index >= torch.cuda.device_count():
        raise InputError(f"--device {name}: this machine has {torch.cuda.device_count()} CUDA device(s)")
    return chosen
