"""What the application reads from its environment and the machine: whether the renderer compiles.

The library takes its choices as values (:class:`backend.model.render.Renderer`'s ``compile``,
``FitSettings.compile``); this module makes the fit command's from the process environment:

    ===============  ===========================================================================
    WFC_COMPILE      ``1``: compile the renderer's BSDF with ``torch.compile``; ``0``: never.
                     Unset (or anything else): compile where a C++ compiler is found, which
                     ``torch.compile`` needs to build CPU kernels (``$CXX``, else g++, c++ or
                     clang++ on the ``PATH``), and, on the CPU, only once its kernels are in the
                     disk cache (:func:`backend.model.compile_cache.kernels_warm`): until then the
                     fit runs eager and the kernels are made in the background
                     (:mod:`backend.app.warm_compile`)
    ===============  ===========================================================================

Why not compile at once: a cold compile of the fit's graphs costs more than compiling saves the
fit that pays it (the first fit on a machine would be the slowest), while a warm one only loads them.

Tests and short runs set ``WFC_COMPILE=0``: a cold compile would take longer than their fits.
"""
from __future__ import annotations

import os
import shutil
from typing import Mapping

from ..model.compile_cache import kernels_warm

COMPILE_SWITCH = "WFC_COMPILE"


def compiler_found(environ: Mapping[str, str] = os.environ) -> bool:
    """Whether ``torch.compile`` can build CPU kernels here: a C++ compiler on the ``PATH``."""
    path = environ.get("PATH")
    return any(shutil.which(c, path=path) for c in (environ.get("CXX", "g++"), "c++", "clang++"))


def renderer_compiles(environ: Mapping[str, str] = os.environ, device: str = "cpu") -> bool:
    """The fit's ``compile`` setting: ``WFC_COMPILE=0`` or ``1`` decides, else :func:`compiler_found`,
    and on the CPU the kernels' being warm too (the module docstring)."""
    forced = environ.get(COMPILE_SWITCH)
    if forced in ("0", "1"):
        return forced == "1"
    return compiler_found(environ) and (not _on_cpu(device) or kernels_warm(environ))


def kernels_wanted(environ: Mapping[str, str] = os.environ, device: str = "cpu") -> bool:
    """Whether a fit here runs eager only because the compiled kernels are not warm yet: the fit
    command then makes them in the background (:func:`backend.app.warm_compile.start_warming`)."""
    return (environ.get(COMPILE_SWITCH) not in ("0", "1") and _on_cpu(device) and compiler_found(environ)
            and not kernels_warm(environ))


def _on_cpu(device: str) -> bool:
    return str(device).split(":")[0] == "cpu"
