"""The facts the add-on shares with the backend, read from the backend's torch-free ``core`` modules.

Each is declared once, in ``backend/core/``, and read here (through :func:`paths.backend_module`,
without torch), so the panel, the batch, the node group and the shader cannot drift from the fit:

- the fabric parameters (``core.params``: names, ranges, labels, defaults): the node group's
  sockets and the OSL inputs; which of them are yarn variations and the variation's hash constants
  (``core.variation``);
- the preset weaves (``core.weave.PRESETS``; their order is the shader's ``pattern`` index), which
  of them mirror which (``core.weave.MIRRORED_OF``) and the
  patterns the fit command accepts (``core.priors.FIT_PATTERNS``, with ``auto`` first);
- the fit command's options (``core.fit_options``: names, accepted values; the request's command line);
- the capture rig (``core.rig.CaptureRig``; its field defaults are the spec's rig);
- the photo suffixes (``core.formats``) and the ``<name>_R.* / <name>_T.*`` pairing rule
  (``core.pairs.find_pairs``);
- the files of a complete fit's results folder (``core.results``);
- the JSON-lines progress protocol (``core.protocol``) and a fit's progress over all its stages
  (``core.progress``).
"""
from __future__ import annotations

from pathlib import Path

from .paths import backend_module

AUTO_PATTERN = "auto"  # the fit command's "let the fit choose the weave"


def parameters() -> tuple:
    """The backend's ``PARAMETERS`` tuple of ParamSpec (name, lo, hi, per_yarn, rgb, label, doc, unit)."""
    return backend_module("core.params").PARAMETERS


def variation():
    """The backend's ``core.variation`` module: the yarn variations' kinds, parameter names and hash."""
    return backend_module("core.variation")


def variation_parameters() -> tuple[str, ...]:
    """The yarn variations' parameter names (``core.variation.PARAMETER_NAMES``)."""
    return variation().PARAMETER_NAMES


def check_params(data) -> None:
    """Raises ValueError naming the parameter and the problem where ``data`` (a params.json's
    object) is not a fit the shader can draw: the backend's own check (``FabricParams.from_dict``:
    numbers of the declared shapes, finite and in range, a known weave), and a preset weave."""
    fabric = backend_module("core.params").FabricParams.from_dict(data)
    if fabric.pattern not in preset_names():
        raise ValueError(f"pattern: the Woven Fabric shader draws the preset weaves ({', '.join(preset_names())}), "
                         f"not {fabric.pattern!r}")


def default_params() -> dict:
    """``FabricParams().to_dict()``: every parameter's default value."""
    return backend_module("core.params").FabricParams().to_dict()


def weave_presets() -> dict:
    """The backend's preset weaves (name -> Weave with matrix, bands, umax_deg, s_min)."""
    return backend_module("core.weave").PRESETS


def preset_names() -> tuple[str, ...]:
    """The preset weaves' names in the backend's order (= the shader's ``pattern`` index)."""
    return tuple(weave_presets())


def pattern_label(name: str) -> str:
    """A preset weave's name for people, from its declaration: the family, which yarn floats on the
    face (the share of the matrix where the warp lies over) and whether it is a mirror image:
    ``plain`` -> "Plain", ``twill0`` -> "Twill (warp-faced)", ``satin0m`` -> "Satin (weft-faced, mirrored)"."""
    weave = weave_presets()[name]
    family = mirrored_of().get(name, name).rstrip("0123456789")
    cells = [c for row in weave.matrix for c in row]
    over = sum(cells) / len(cells)
    notes = ["warp-faced" if over > 0.5 else "weft-faced"] if over != 0.5 else []
    notes += ["mirrored"] if name in mirrored_of() else []
    return family.capitalize() + (f" ({', '.join(notes)})" if notes else "")


def mirrored_of() -> dict[str, str]:
    """Mirrored preset -> the paper's preset it mirrors (``twill0m`` -> ``twill0``)."""
    return backend_module("core.weave").MIRRORED_OF


def fit_patterns() -> tuple[str, ...]:
    """What the fit command's ``--pattern`` accepts: ``auto``, then the backend's patterns."""
    return (AUTO_PATTERN, *backend_module("core.priors").FIT_PATTERNS)


def fit_options():
    """The backend's ``core.fit_options`` module: the fit command's options (``FIT_OPTIONS``),
    ``command_line`` (checked flags for a dict of values) and ``FitOptionError``."""
    return backend_module("core.fit_options")


def rig():
    """The backend's ``core.rig`` module: ``CaptureRig``, ``DEFAULT_RIG`` and ``RigError``."""
    return backend_module("core.rig")


def is_raw(suffix: str) -> bool:
    """Whether a file suffix (``.dng``, any case) names a camera RAW photo."""
    return backend_module("core.formats").is_raw(suffix)


def find_pairs(folder: str | Path) -> tuple[list, list]:
    """``(pairs, problems)`` of a folder by the backend's one ``<name>_R.* / <name>_T.*`` rule."""
    return backend_module("core.pairs").find_pairs(folder)


def result_files() -> tuple[str, ...]:
    """The files a finished fit leaves in its results folder (params.json, the re-renders, ...)."""
    return backend_module("core.results").RESULT_FILES


def missing_result_files(folder: str | Path) -> list[str]:
    """The result files ``folder`` lacks: empty for a complete fit."""
    return backend_module("core.results").missing_files(folder)


def protocol():
    """The backend's protocol module (decode, stages, exit codes): one definition for both sides."""
    return backend_module("core.protocol")


def fit_progress():
    """The backend's ``core.progress`` module: ``FitProgress``, a fit's progress over all its stages
    (one bar, its phase in words, the time left) from its protocol events."""
    return backend_module("core.progress")


def pair_jobs():
    """The backend's job model of a folder batch (``core.pair_jobs``): the jobs of a folder, their
    states, the retry rule; the add-on's batches run it."""
    return backend_module("core.pair_jobs")
