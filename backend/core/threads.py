"""How the backend's CPU threads wait between parallel regions (briefly, so a fit shares the CPU),
and a map of independent pure-Python/numpy work over a few threads (:func:`ordered_map`).

PyTorch's CPU kernels (and the compiled renderer's) run in an OpenMP thread pool. A thread that has
done its share of a parallel region waits for the others, spinning before it sleeps: GNU OpenMP
(libgomp, PyTorch's on Linux) spins 300,000 times by default (``GOMP_SPINCOUNT``), LLVM's and
Intel's OpenMP (macOS, Windows) for 200 ms (``KMP_BLOCKTIME``). Alone on the CPU the spinning saves
a wake-up per region. Beside any other busy process (Blender rendering, a second fit, a cold
compile's C++ compiler) the spinning threads hold the cores the working ones need, and each
region waits for threads that are not running: the fit slows far beyond its fair share.

A short spin lets a fit beside another busy process run several times faster, costs a fit alone
next to nothing, and leaves the fitted parameters the same bit for bit. So the backend spins
:data:`SPIN_COUNT` times, unless the user has set either variable (or ``OMP_WAIT_POLICY``, which sets
both runtimes' own default). ``KMP_BLOCKTIME`` gets 1 ms, Intel's own advice for PyTorch on shared
machines.

The runtimes read these variables once, when they load: :func:`wait_briefly` must run before torch
is imported (``python -m backend`` calls it first).
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, MutableMapping, TypeVar

T = TypeVar("T")
R = TypeVar("R")

SPIN_COUNT = "10000"  # GNU OpenMP: spins before a waiting thread sleeps (default 300,000)
BLOCK_TIME_MS = "1"   # LLVM / Intel OpenMP: milliseconds a waiting thread spins (default 200)


def wait_briefly(environ: MutableMapping[str, str] = os.environ) -> None:
    """Sets the OpenMP runtimes' spin waits to SPIN_COUNT / BLOCK_TIME_MS where the user has set
    no waiting policy of their own."""
    if "OMP_WAIT_POLICY" in environ:
        return
    environ.setdefault("GOMP_SPINCOUNT", SPIN_COUNT)
    environ.setdefault("KMP_BLOCKTIME", BLOCK_TIME_MS)


def ordered_map(fn: Callable[[T], R], items: Iterable[T], workers: int) -> list[R]:
    """``[fn(item) for item in items]``, on up to ``workers`` threads: the same results in the same
    order, where each call is independent of the others (reads shared inputs, writes nothing shared).

    For numpy work made of many mid-sized array operations (the lattice search's scoring of a
    pattern's candidate lattices): numpy releases the GIL inside each operation, so two threads
    overlap most of it. ``workers`` is the caller's core budget (the backend passes
    ``torch.get_num_threads()``, which a batch job sets to its share); 1, or a single item, runs in
    this thread. An exception of any call is raised here, as the loop would."""
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        return [fn(item) for item in items]
    with ThreadPoolExecutor(max_workers=min(workers, len(items))) as pool:
        return list(pool.map(fn, items))
