"""The fit and the renderer on a CUDA device: the same images and gradients as on the CPU, every
tensor of a run on the device, few waits for it per step, and a fit end to end (library and command).

Every test here is marked ``gpu``: without a CUDA device they are deselected and the terminal summary
says how many were not run (tests/conftest.py); ``python -m devtools gpu-check`` runs them on a machine
with one, with the GPU benchmarks. Asked for explicitly (``-m gpu``) without a device, they fail.
"""
from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import torch

from backend.core.params import FabricParams
from backend.core.rig import DEFAULT_RIG, MAX_CAMERA_BLUR_PX
from backend.fit.objective import Objective, Target
from backend.fit.optimise import Run
from backend.fit.pipeline import _objective, fit
from backend.fit.search import BlurRange
from backend.fit.settings import OPTIMISED, FitSettings
from backend.model.param_tensors import ParamTensors
from backend.model.render import Renderer, render_pair

pytestmark = pytest.mark.gpu

ROOT = Path(__file__).resolve().parents[1]
TWILL = FabricParams.from_interchange(
    "twill1_R_0.72,0.55_S_1.3,1.6_T_2.4,2.9_N_0.0_UV_92.0,131.0_Kd_0.32,0.18,0.11,0.26,0.14,0.08"
    "_G_0.88,0.9_Rm_0.7,0.45_Tm_2.2,2.6_W_0.6,0.9_Ks_0.62,0.38,0.25,0.55,0.33,0.22_Psi_-30.0,-30.0")
START = TWILL.replace(roughness=(0.5, 0.7), thickness=(1.6, 1.3), height_scale=(0.8, 0.8))

# Display values of one render on the CPU and on CUDA: the same samples and the same sums, in another
# order (float32 rounding), and a sample on a yarn's very edge may land on the other side of it.
PIXEL_MEAN_TOLERANCE = 2e-4     # mean |CUDA - CPU| over the image
PIXEL_OUTLIER_VALUE = 1e-3      # a pixel that differs by more than this is an outlier...
PIXEL_OUTLIER_SHARE = 0.005     # ...and at most this share of the pixels are
# Gradients of the loss on the CPU and on CUDA: the quantile and alignment terms pick pixels and
# shifts by value, so rounding may move a little of the gradient between neighbours.
GRADIENT_COSINE_MIN = 0.999     # cosine between the two gradients over all optimised parameters
GRADIENT_NORM_TOLERANCE = 0.01  # relative difference of their norms, and of the camera blur's gradient
# Waits for the device in one Adam step at most: the loss (1), the light falloff's block means and its
# coefficients back (2), the camera blur's kernel radius (1) and, at a new best, its terms, parameters
# and blur (3); 1 to spare.
MAX_SYNCS_PER_STEP = 8


@pytest.fixture(scope="module")
def cuda() -> torch.device:
    if not torch.cuda.is_available():
        pytest.fail("no CUDA device: these tests need one (without it they are deselected; "
                    "see tests/conftest.py and `python -m devtools gpu-check`)")
    return torch.device("cuda")


@pytest.fixture(scope="module")
def photos():
    """A twill pair rendered on the CPU (display values, (128, 128, 3) arrays)."""
    pair = render_pair(TWILL, size=128, spp=4, seed=3)
    return pair.reflection.numpy(), pair.transmission.numpy()


def _settings(device: torch.device, **changes) -> FitSettings:
    values = dict(pattern="twill1", size=64, spp=4, iterations=6, first_search=3, search_every=3, compile=False,
                  device=str(device))
    values.update(changes)
    return FitSettings(**values)


@pytest.mark.parametrize("blur", [0.0, 1.3])
def test_a_render_on_cuda_matches_the_cpu(cuda, blur):
    renders = {}
    for device in ("cpu", cuda):
        renderer = Renderer(size=128, spp=4, seed=2, device=device)
        with torch.no_grad():
            pair = renderer.render(TWILL, camera_blur_px=blur)
        renders[str(device)] = torch.stack((pair.reflection, pair.transmission)).cpu()
        assert pair.reflection.device.type == torch.device(device).type
    assert torch.backends.cudnn.conv.fp32_precision == "ieee"  # the camera blur's convolution: no TF32
    diff = (renders["cpu"] - renders[str(cuda)]).abs()
    assert float(diff.mean()) < PIXEL_MEAN_TOLERANCE, float(diff.mean())
    assert float((diff > PIXEL_OUTLIER_VALUE).float().mean()) < PIXEL_OUTLIER_SHARE


def _gradients(photos, device, compile: bool) -> tuple[torch.Tensor, float, float]:
    """The loss's gradient (all optimised parameters, flattened), the camera blur's, and the loss."""
    target = Target.from_arrays(*photos, size=64, device=device)
    renderer = Renderer(size=64, spp=4, seed=1, device=device, compile=compile, gradient_inputs=OPTIMISED)
    objective = Objective(target, renderer, renderer.rig)
    fabric = ParamTensors.from_params(START, device, requires_grad=OPTIMISED)
    blur = torch.tensor(0.8, dtype=torch.float64, device=device, requires_grad=True)
    loss = objective.terms(fabric, blur)["loss"]
    loss.backward()
    grads = torch.cat([fabric.values[n].grad.reshape(-1) for n in OPTIMISED]).double().cpu()
    return grads, float(blur.grad), float(loss.detach())


@pytest.mark.parametrize("compile", [False, True], ids=["eager", "compiled"])
def test_gradients_on_cuda_match_the_cpu(cuda, photos, compile):
    cpu, cpu_blur, cpu_loss = _gradients(photos, torch.device("cpu"), compile=False)
    gpu, gpu_blur, gpu_loss = _gradients(photos, cuda, compile=compile)
    assert gpu_loss == pytest.approx(cpu_loss, rel=1e-3)
    cosine = float(torch.dot(cpu, gpu) / (cpu.norm() * gpu.norm()))
    assert cosine > GRADIENT_COSINE_MIN, cosine
    assert float(abs(gpu.norm() / cpu.norm() - 1)) < GRADIENT_NORM_TOLERANCE
    assert gpu_blur == pytest.approx(cpu_blur, rel=GRADIENT_NORM_TOLERANCE, abs=1e-6)


def _on_device(run: Run, device: torch.device) -> list[str]:
    """What of a run is not on ``device``: its parameters, the camera blur, Adam's moments."""
    wrong = [f"parameter {n}" for n, v in run.fabric.values.items() if v.device.type != device.type]
    if run._blur.device.type != device.type:
        wrong.append("camera blur")
    for state in run.optimiser.state.values():
        wrong += [f"Adam's {k}" for k, v in state.items()
                  if isinstance(v, torch.Tensor) and k != "step" and v.device.type != device.type]
    return wrong


def test_a_run_on_cuda_keeps_every_tensor_on_the_device(cuda, photos):
    settings = _settings(cuda)
    objective = _objective(*photos, DEFAULT_RIG, settings)
    run = Run(START, objective, settings, total=6, camera_blur_px=0.8,
              blur_range=BlurRange(0.3, MAX_CAMERA_BLUR_PX))
    losses = [run.step() for _ in range(3)]
    run.discrete_search(0)
    losses += [run.step() for _ in range(2)]
    assert _on_device(run, cuda) == []
    assert objective.target.reflection.device.type == cuda.type
    assert all(map(torch.isfinite, map(torch.tensor, losses)))
    assert run.best_loss <= losses[0]


def test_an_adam_step_waits_for_the_device_only_a_few_times(cuda, photos):
    settings = _settings(cuda)
    run = Run(START, _objective(*photos, DEFAULT_RIG, settings), settings, total=20, camera_blur_px=0.8,
              blur_range=BlurRange(0.3, MAX_CAMERA_BLUR_PX))
    run.step()  # the first step makes the camera samples, geometry and lattice probe
    steps = 4
    torch.cuda.synchronize()
    previous = torch.cuda.get_sync_debug_mode()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torch.cuda.set_sync_debug_mode("warn")
        try:
            for _ in range(steps):
                run.step()
        finally:
            torch.cuda.set_sync_debug_mode(previous)
    syncs = [f"{w.filename}:{w.lineno}: {str(w.message)[:80]}" for w in caught if "synchroniz" in str(w.message)]
    assert len(syncs) <= MAX_SYNCS_PER_STEP * steps, "\n".join(syncs)


def test_a_tiny_fit_runs_on_cuda_end_to_end(cuda, photos):
    result = fit(*photos, settings=_settings(cuda))
    losses = [value for _, value in result.history]
    assert all(map(torch.isfinite, map(torch.tensor, losses)))
    assert min(losses) < losses[0]
    assert result.params.pattern == "twill1"
    cpu = fit(*photos, settings=_settings(torch.device("cpu")))
    # not the same trajectory (rounding moves the discrete steps), but a fit of the same quality
    assert result.loss == pytest.approx(cpu.loss, rel=0.25)


def test_the_fit_command_runs_on_cuda(cuda, tmp_path):
    """``python -m backend fit --example --device cuda``: the whole command, its re-renders and report."""
    out = tmp_path / "fit"
    done = subprocess.run([sys.executable, "-m", "backend", "fit", "--example", "--device", "cuda", "--size", "64",
                           "--iterations", "4", "--output-spp", "4", "--out", str(out)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "WFC_COMPILE": "0"})
    assert done.returncode == 0, done.stderr[-2000:]
    for name in ("params.json", "metrics.json", "reflection.png", "transmission.png", "report.png"):
        assert (out / name).exists(), name

