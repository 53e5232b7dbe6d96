"""Shared fixtures. ``../shared`` (beside the checkout) holds the golden renders, the real photo
pairs and the team's checkers; CI has it. Tests that need it fail with a clear message when it is
missing (the product never reads it)."""
from __future__ import annotations

import importlib.util
import json
import os
import sys
from pathlib import Path

import pytest

# Under pytest-xdist (pyproject's addopts: one worker per core) each worker runs torch on its share of
# the cores instead of all of them: two torch threads on two cores rendered the golden cases only
# 1.4x as fast as one thread, so two one-thread workers get more done (the suite: 706 s against
# 1080 s). Set before torch is imported, so that the tests' subprocesses (fits, Blender) inherit it.
_WORKERS = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
if _WORKERS > 1:
    _CORES = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    os.environ.setdefault("OMP_NUM_THREADS", str(max(1, _CORES // _WORKERS)))

# No fit in the tests compiles the renderer or starts a background compile of its kernels
# (backend.app.environment): the tests that compile build their renderer so, and say so.
os.environ.setdefault("WFC_COMPILE", "0")

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def _require_shared(*parts: str) -> Path:
    return require_path(SHARED.joinpath(*parts))


def require_path(path: Path) -> Path:
    """A shared file or folder, or a failure that says where it should be."""
    if not path.exists():
        pytest.fail(f"{path} is missing: the shared data must sit beside the checkout (../shared)")
    return path


def golden_case_names() -> list[str]:
    """The golden cases' names, for parametrising at collection time; without the shared data, one
    placeholder name whose test then fails on the missing file (never an empty, silently passing set)."""
    cases = SHARED / "data" / "golden" / "cases.json"
    if not cases.exists():
        return ["<golden cases missing>"]
    return [case["name"] for case in json.loads(cases.read_text())]


@pytest.fixture(scope="session")
def golden_dir() -> Path:
    return _require_shared("data", "golden")


@pytest.fixture(scope="session")
def golden_cases(golden_dir) -> list[dict]:
    return json.loads((golden_dir / "cases.json").read_text())


@pytest.fixture(scope="session")
def shared_tools() -> Path:
    return _require_shared("tools")


@pytest.fixture(scope="session")
def real_dir() -> Path:
    return _require_shared("data", "real")


@pytest.fixture(scope="session")
def build_module():
    """build.py, loaded as a module (it is a script beside the packages, not one of them)."""
    spec = importlib.util.spec_from_file_location("woven_fabric_build", ROOT / "build.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def pytest_collection_modifyitems(config, items):
    """Tests marked ``slow`` run first (in their collected order), the rest after them: pytest-xdist
    hands out tests in list order, so a minute-long test collected late would run alone at the end
    while the other workers wait for it. Under ``-n 0`` a module's slow tests leave its other tests
    apart, so its module-scoped fixtures are built twice (a render or two: cheaper than the idle tail).

    Tests marked ``gpu`` are deselected where no CUDA device is present, unless the marker expression
    names them (``-m gpu``: then they run and fail, saying there is no device); the terminal summary
    says how many were not run (:func:`pytest_terminal_summary`)."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
    if cuda_present() or gpu_requested(config):
        return
    gpu = [item for item in items if item.get_closest_marker("gpu") is not None]
    if gpu:
        config.hook.pytest_deselected(items=gpu)
        items[:] = [item for item in items if item.get_closest_marker("gpu") is None]
    _GPU_NOT_RUN["count"] = max(_GPU_NOT_RUN["count"], len(gpu))
    if hasattr(config, "workeroutput"):  # a pytest-xdist worker: the controller prints the summary
        config.workeroutput[GPU_NOT_RUN_KEY] = len(gpu)


GPU_NOT_RUN_KEY = "gpu_tests_not_run"  # the count a pytest-xdist worker hands its controller
_GPU_NOT_RUN = {"count": 0}  # GPU tests deselected in this session (the most any worker collected)
GPU_CHECK = "python -m devtools gpu-check"  # runs them, with the GPU benchmarks, on a machine with CUDA


def cuda_present() -> bool:
    import torch  # here, not at the top: OMP_NUM_THREADS is set above before torch is first imported

    return torch.cuda.is_available()


def gpu_requested(config) -> bool:
    """Whether the marker expression (``-m``) names the ``gpu`` marker: the caller asked for them."""
    return "gpu" in (config.getoption("markexpr", default="") or "")


def gpu_not_run_line(count: int) -> str:
    return (f"{count} GPU test(s) NOT RUN: no CUDA device is present (deselected; tests marked gpu). "
            f"On a machine with CUDA run them with `{GPU_CHECK}` (or `pytest -m gpu`).")


def pytest_testnodedown(node, error):
    """pytest-xdist, on the controller: a worker's count of GPU tests it deselected."""
    count = getattr(node, "workeroutput", {}).get(GPU_NOT_RUN_KEY, 0)
    _GPU_NOT_RUN["count"] = max(_GPU_NOT_RUN["count"], count)


def pytest_terminal_summary(terminalreporter):
    if _GPU_NOT_RUN["count"]:
        terminalreporter.write_sep("=", gpu_not_run_line(_GPU_NOT_RUN["count"]), yellow=True, bold=True)
