"""Writing the project's images: RGB float in [0, 1] -> 8/16-bit PNG (re-renders, reports)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def to_numpy(image) -> np.ndarray:
    """(H, W, 3) float array from a tensor or array."""
    if hasattr(image, "detach"):
        image = image.detach().cpu().numpy()
    return np.asarray(image, dtype=np.float64)


def write_png(path: str | Path, image, bits: int = 16) -> Path:
    """Writes an RGB image in [0, 1] as an 8- or 16-bit PNG (values are clipped)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    rgb = np.clip(to_numpy(image), 0.0, 1.0)
    top = 65535 if bits == 16 else 255
    data = np.round(rgb * top).astype(np.uint16 if bits == 16 else np.uint8)
    if not cv2.imwrite(str(path), np.ascontiguousarray(data[..., ::-1])):
        raise OSError(f"{path}: could not write the image")
    return path
