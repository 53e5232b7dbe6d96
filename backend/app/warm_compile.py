"""Compiled kernels made ahead of the fits that use them: ``python -m backend warm-compile``.

A fit compiles the renderer on the CPU only where its kernels are in the disk cache already
(:func:`backend.app.environment.renderer_compiles`). Where a compiler is found and the cache is cold,
the fit command runs eager and, once its results are written, starts this in a background process at
the lowest priority (:func:`start_warming`; beside a running fit, even at that priority, the compile
slowed the fit by more than a compile in the fit costs: the compiler's work shares the caches the
eager renderer's speed rests on). It compiles the graphs a fit's renderer compiles, its BSDF with the
gradient of every optimised parameter over one chunk of 2^20 samples (512 px at 4 spp and 256 px at
16: the working sizes' chunks), once without and once with a yarn variation's per-sample albedo
(the variation stage's), and then records them as warm (:func:`backend.model.compile_cache.mark_warm`).
The fits after it load the kernels instead of compiling them. One warm-up at a time: a lock file in
the cache folder, taken as stale after STALE_LOCK_S.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Mapping

from ..core.params import FabricParams
from ..core.rig import DEFAULT_RIG
from ..fit.settings import OPTIMISED
from ..model.compile_cache import cache_folder, mark_warm
from ..model.param_tensors import ParamTensors
from ..model.render import Renderer
from .environment import kernels_wanted

LOCK = "warming.lock"
STALE_LOCK_S = 1800.0  # a warm-up takes a minute or two of CPU; a lock this old was left by one that died
# A fabric whose render builds the plain graph, and with a brightness variation the varied one.
WARM_FABRIC = FabricParams(pattern="twill0", tiles=(60.0, 60.0), forward_scattering=(0.2, 0.2))
WARM_VARIED = WARM_FABRIC.replace(brightness_variation=(0.1, 0.1))


def warm_kernels(size: int = 512, spp: int = 4) -> None:
    """Compiles (or loads) the fit renderer's graphs (the module docstring), then records them as warm."""
    for params in (WARM_FABRIC, WARM_VARIED):
        renderer = Renderer(DEFAULT_RIG, size, spp, compile=True, gradient_inputs=OPTIMISED)
        fabric = ParamTensors.from_params(params, requires_grad=OPTIMISED)
        reflection, transmission = renderer.radiance(fabric)
        (reflection.sum() + transmission.sum()).backward()
        if not renderer.compiled:  # the compile failed (and said so): nothing to record
            return
    mark_warm()


def start_warming(environ: Mapping[str, str] = os.environ, device: str = "cpu") -> bool:
    """Starts ``python -m backend warm-compile`` in the background where a fit runs eager only because
    the kernels are cold (:func:`backend.app.environment.kernels_wanted`) and no warm-up is running;
    returns whether it started one. It runs in a session of its own at the lowest priority, so the
    fit (and Blender) keep the machine."""
    if not kernels_wanted(environ, device):
        return False
    folder = cache_folder(environ)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        lock = folder / LOCK
        if lock.exists() and time.time() - lock.stat().st_mtime < STALE_LOCK_S:
            return False
        lock.write_text(f"{os.getpid()}\n")
    except OSError:  # an unwritable cache: the fits stay eager
        return False
    options = {"start_new_session": True} if os.name == "posix" else {
        "creationflags": subprocess.CREATE_NEW_PROCESS_GROUP | subprocess.IDLE_PRIORITY_CLASS}
    subprocess.Popen([sys.executable, *interpreter_flags(), "-m", "backend", "warm-compile"], stdin=subprocess.DEVNULL,
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=dict(environ), **options)
    return True


def lowest_priority() -> None:
    """This process at the lowest CPU priority. On Linux with autogroups (most desktops) the scheduler
    weighs sessions against each other before processes, so a process in a session of its own (as
    :func:`start_warming` starts it) also lowers its session's: nice alone left it half the CPU."""
    if hasattr(os, "nice"):
        os.nice(19)
    if os.name == "posix" and os.getsid(0) == os.getpid():  # a session's leader: the session is only its own
        try:
            Path("/proc/self/autogroup").write_text("19")
        except OSError:  # no autogroups here: nice is enough
            pass


def interpreter_flags(flags=sys.flags) -> list[str]:
    """This interpreter's isolation flags, for the warm-up to import what the fit imported: the add-on
    runs the backend in Blender's Python with ``-S -P`` and its packages on PYTHONPATH
    (``blender_addon.core.backend_bridge.Backend``), which the warm-up inherits."""
    return [flag for flag, on in (("-S", flags.no_site), ("-s", flags.no_user_site),
                                  ("-P", getattr(flags, "safe_path", False))) if on]


def run_warm(args) -> int:
    """The command: at the lowest priority, compiles the kernels and records them; the lock goes at the end."""
    lowest_priority()  # with the fits' thread count: inductor's kernels are made (and cached) for it
    try:
        warm_kernels()
    finally:
        try:
            (cache_folder() / LOCK).unlink()
        except OSError:
            pass
    return 0


def add_parser(sub) -> None:
    parser = sub.add_parser("warm-compile", help="compile the renderer's kernels for later fits (in the background)")
    parser.set_defaults(run=run_warm)
