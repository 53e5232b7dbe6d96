"""What the application reads from its environment and the machine: whether the renderer compiles.

The library takes its choices as values (:class:`backend.model.render.Renderer`'s ``compile``,
``FitSettings.compile``); this module makes the fit command's from the process environment:

    ===============  ===========================================================================
    WFC_COMPILE      ``1``: compile the renderer's BSDF with ``torch.compile``; ``0``: never.
                     Unset (or anything else): compile where a C++ compiler is found, which
                     ``torch.compile`` needs to build CPU kernels (``$CXX``, else g++, c++ or
                     clang++ on the ``PATH``)
    ===============  ===========================================================================

Tests and short runs set ``WFC_COMPILE=0``: a cold compile would take longer than their fits.
"""
from __future__ import annotations

import os
import shutil
from typing import Mapping

COMPILE_SWITCH = "WFC_COMPILE"


def compiler_found(environ: Mapping[str, str] = os.environ) -> bool:
    """Whether ``torch.compile`` can build CPU kernels here: a C++ compiler on the ``PATH``."""
    path = environ.get("PATH")
    return any(shutil.which(c, path=path) for c in (environ.get("CXX", "g++"), "c++", "clang++"))


def renderer_compiles(environ: Mapping[str, str] = os.environ) -> bool:
    """The fit's ``compile`` setting: ``WFC_COMPILE=0`` or ``1`` decides, else :func:`compiler_found`."""
    forced = environ.get(COMPILE_SWITCH)
    if forced in ("0", "1"):
        return forced == "1"
    return compiler_found(environ)
