"""Peak memory of the work the model does: the device's peak allocation on CUDA, else the process's
peak resident set where the platform reports it (POSIX ``getrusage``; None on Windows)."""
from __future__ import annotations

import sys

import torch


def peak_memory_mb(device: torch.device | None = None) -> float | None:
    if device is not None and device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2**20
    try:
        import resource  # POSIX only
    except ImportError:
        return None
    scale = 1024 * 1024 if sys.platform == "darwin" else 1024  # ru_maxrss: bytes on macOS, KiB on Linux
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / scale
