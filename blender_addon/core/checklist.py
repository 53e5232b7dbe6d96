"""The first-run checklist the preferences show (no bpy): is the backend found, which PyTorch, which
device, can Cycles run the fitted OSL shader.

Each :class:`Item` is ``ok``, a ``problem`` or ``pending`` (not checked yet, or a check running),
with one line of words. The backend's items come from the last backend check
(backend_setup.BackendCheck, kept by check_job); OSL is Blender's side, which the caller asks
Cycles about (scene/cycles_osl.osl_problem) and passes in.
"""
from __future__ import annotations

from dataclasses import dataclass

from .backend_setup import BackendCheck

OK, PROBLEM, PENDING = "ok", "problem", "pending"


@dataclass(frozen=True)
class Item:
    state: str
    text: str


def _device(check: BackendCheck, chosen: str | None) -> Item:
    cuda = check.device.startswith("CUDA")
    if chosen == "cuda":
        return Item(OK, f"Device: {check.device}") if cuda else \
            Item(PROBLEM, "Device: CUDA is chosen, but PyTorch sees no CUDA GPU here (choose CPU)")
    if cuda:
        return Item(OK, f"Device: CPU (PyTorch also sees {check.device}: choose the CUDA device to use it)")
    return Item(OK, "Device: CPU")


def first_run_checklist(check: BackendCheck | None, checking: bool, chosen_device: str | None,
                        osl_problem: str) -> list[Item]:
    """The checklist's items in order: backend, PyTorch, device, OSL."""
    osl = Item(PROBLEM, f"OSL: {osl_problem}; materials render with the approximate fallback") if osl_problem else \
        Item(OK, "OSL: Cycles can run the fitted shader (Cycles on the CPU or OptiX, Open Shading Language on)")
    if check is None or checking:
        waiting = "checking ..." if checking else "not checked yet (press Check Backend)"
        return [Item(PENDING, f"Backend: {waiting}"), Item(PENDING, "PyTorch: -"), Item(PENDING, "Device: -"), osl]
    runs = bool(check.torch_version) or not any(
        problem.startswith(("No Python", "The Python interpreter", check.python)) for problem in check.problems)
    backend = Item(OK if runs else PROBLEM, f"Backend: {check.label or 'Python'}: {check.python}")
    if not check.torch_version:
        return [backend, Item(PROBLEM, "PyTorch: does not import (see below)"), Item(PENDING, "Device: -"), osl]
    torch = Item(OK, f"PyTorch {check.torch_version}")
    return [backend, torch, _device(check, chosen_device), osl]
