"""Benchmarks (scripts that print figures; never timed tests).

``python -m devtools bench render [--json]``: one reflection/transmission pair of the published
example at 512 x 512 and 4 spp, as the fit loop renders it (camera samples and geometry cached,
all continuous parameters requiring gradients):

- forward_s: median time of a render with gradients enabled, without the backward pass (a fit
  step's forward; a render without gradients runs eager on both paths, see
  :mod:`backend.model.render`);
- backward_s: median time of a render plus the backward pass of a scalar loss (forward + backward);
- the same two for the eager (uncompiled) renderer, measured in the same run, and their ratio;
- autograd_backward_s: the eager forward + backward with autograd's gradient of the BSDF instead of
  the hand-written one (:mod:`backend.model.bsdf_gradient`), timed in turns with it (the same
  machine state), and hand_gradient_speedup, their ratio;
- compile_s: the first compiled call (compilation, cached on disk for later runs);
- cold_s: a render from nothing (camera samples, weave geometry, BSDF; eager, no cache);
- peak_mb: the process's peak resident memory (CPU) or peak allocated memory (CUDA) after the
  compiled path; eager_peak_mb after the eager path too.
"""
from __future__ import annotations

import json
import statistics
import sys
import time

import torch

from backend.app.environment import renderer_compiles
from backend.core.params import PARAMETERS, FabricParams
from backend.model.memory import peak_memory_mb
from backend.model.param_tensors import ParamTensors
from backend.model.render import Renderer

from .ledger import NOT_RECORDED, Ledger

EXAMPLE = ("twill1_R_0.6,0.66_S_0.75,1.53_T_1.33,1.39_N_0.0_UV_121.8,168.9_Kd_0.456,0.398,0.089,0.286,0.279,0.0"
           "_G_0.99,1.0_Rm_0.65,0.62_Tm_2.66,0.79_W_0.71,1.29_Ks_0.325,0.37,0.0,0.351,0.883,0.0_Psi_-30.5,-29.5")


def _sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize()


def _time(fn, runs: int, device) -> float:
    times = []
    for _ in range(runs):
        _sync(device)
        start = time.perf_counter()
        fn()
        _sync(device)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _forward_backward(renderer: Renderer, fabric: ParamTensors) -> None:
    """A render and the backward pass of a scalar loss of it."""
    pair = renderer.render(fabric)
    (pair.reflection.mean() + pair.transmission.mean()).backward()


def _measure(renderer: Renderer, fabric: ParamTensors, runs: int, device) -> dict:
    def forward():
        renderer.render(fabric)

    def forward_backward():
        _forward_backward(renderer, fabric)

    start = time.perf_counter()
    forward_backward()  # warm-up: caches, and compilation when enabled
    forward()
    warm = time.perf_counter() - start
    return {"forward_s": _time(forward, runs, device), "backward_s": _time(forward_backward, runs, device),
            "warmup_s": warm}


def _in_turns(renderers: list[Renderer], fabric: ParamTensors, runs: int, device) -> list[float]:
    """Median forward + backward time of each renderer, taking turns ``runs`` times (after a warm-up)."""
    times = [[] for _ in renderers]
    for renderer in renderers:
        _forward_backward(renderer, fabric)
    for _ in range(runs):
        for renderer, kept in zip(renderers, times):
            kept.append(_time(lambda: _forward_backward(renderer, fabric), 1, device))
    return [statistics.median(kept) for kept in times]


def bench_render(size: int = 512, spp: int = 4, runs: int = 5, as_json: bool = False,
                 device=torch.device("cpu"), ledger: Ledger = NOT_RECORDED) -> int:
    params = FabricParams.from_interchange(EXAMPLE)
    optimised = [s.name for s in PARAMETERS if s.optimised]
    fabric = ParamTensors.from_params(params, device, requires_grad=optimised)
    baseline_mb = peak_memory_mb(device)

    start = time.perf_counter()
    with torch.no_grad():
        Renderer(size=size, spp=spp, device=device, cache_samples=0).render(params)
    cold = time.perf_counter() - start

    # The compiled path first: the process peak after it is its own (the eager path keeps far more
    # tensors for the backward pass, and a peak never goes down).
    compiled_renderer = Renderer(size=size, spp=spp, device=device, compile=renderer_compiles(device=str(device)))
    fast = _measure(compiled_renderer, fabric, runs, device) if compiled_renderer.compiled else None
    fast_peak = peak_memory_mb(device)
    del compiled_renderer  # free its caches before the eager run
    eager_renderer = Renderer(size=size, spp=spp, device=device, compile=False)
    eager = _measure(eager_renderer, fabric, runs, device)
    by_hand, by_autograd = _in_turns([eager_renderer, Renderer(size=size, spp=spp, device=device, compile=False,
                                                               hand_gradient=False)], fabric, runs, device)
    compiled = fast is not None
    fast = fast or eager
    result = {
        "forward_s": round(fast["forward_s"], 4),
        "backward_s": round(fast["backward_s"], 4),
        "peak_mb": round(fast_peak if compiled else peak_memory_mb(device), 1),
        "eager_peak_mb": round(peak_memory_mb(device), 1),
        "compiled": compiled,
        "compile_s": round(fast["warmup_s"], 2) if compiled else None,
        "eager_forward_s": round(eager["forward_s"], 4),
        "eager_backward_s": round(eager["backward_s"], 4),
        "speedup_forward": round(eager["forward_s"] / fast["forward_s"], 2),
        "autograd_backward_s": round(by_autograd, 4),
        "hand_gradient_speedup": round(by_autograd / by_hand, 2),
        "cold_s": round(cold, 3),
        "baseline_mb": round(baseline_mb, 1),
        "size": size, "spp": spp, "runs": runs, "device": str(device), "threads": torch.get_num_threads(),
    }
    if as_json:
        print(json.dumps(result))
    else:
        print(f"render {size}x{size} @ {spp} spp, R+T pair, {device}, {result['threads']} threads, median of {runs}:")
        print(f"  forward           {result['forward_s'] * 1000:8.1f} ms  "
              f"(eager {result['eager_forward_s'] * 1000:.1f} ms, x{result['speedup_forward']})")
        print(f"  forward+backward  {result['backward_s'] * 1000:8.1f} ms  "
              f"(eager {result['eager_backward_s'] * 1000:.1f} ms)")
        print(f"  gradient by hand  x{result['hand_gradient_speedup']:<7} "
              f"(eager forward+backward with autograd's: {result['autograd_backward_s'] * 1000:.1f} ms, in turns)")
        print(f"  cold render       {result['cold_s'] * 1000:8.1f} ms  (camera samples + geometry + BSDF, eager)")
        if result["compiled"]:
            print(f"  first compiled call {result['compile_s']:.1f} s (compile; cached on disk)")
        print(f"  peak memory       {result['peak_mb']:8.1f} MB  (eager path: {result['eager_peak_mb']:.1f} MB;"
              f" process before rendering: {result['baseline_mb']:.1f} MB)")
    sys.stdout.flush()
    ledger.summary(result)
    return 0
