"""A running fit's progress for the panels and the batch's lines (no bpy): a fraction of the bar,
the protocol's stages weighted by how long they take, and one line in words."""
from __future__ import annotations

# Share of the progress bar per stage, in the protocol's stage order; optimisation dominates a fit.
STAGE_WEIGHTS = {"load": 0.02, "init": 0.05, "search": 0.15, "optimise": 0.68, "render": 0.05, "report": 0.05}
STAGE_NAMES = {"load": "Loading photos", "init": "Initial guess", "search": "Searching the weave",
               "optimise": "Optimising", "render": "Rendering", "report": "Writing the report"}


def progress_fraction(stage: str, iteration: int, total: int) -> float:
    """Overall progress in [0, 1] for an iteration of a stage."""
    done = 0.0
    for name, weight in STAGE_WEIGHTS.items():
        if name == stage:
            within = min(max(iteration / total, 0.0), 1.0) if total and total > 0 else 0.0
            return min(done + weight * within, 1.0)
        done += weight
    return 0.0


def describe_progress(event: dict) -> str:
    """One line for the UI: 'Optimising 120/300, loss 0.0312, about 41 s left'."""
    text = f"{STAGE_NAMES.get(event.get('stage'), str(event.get('stage', 'Working')))}"
    if event.get("total"):
        text += f" {event.get('iteration', 0)}/{event['total']}"
    if isinstance(event.get("loss"), (int, float)):
        text += f", loss {event['loss']:.4g}"
    if isinstance(event.get("eta_s"), (int, float)):
        text += f", about {event['eta_s']:.0f} s left"
    return text
