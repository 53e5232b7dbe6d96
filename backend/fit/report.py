"""The fit report: photo, re-render and error map side by side for both images, with the figures."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..core.params import FabricParams

PANEL = 320
HEADER = 96


def _to_bgr8(image: np.ndarray, size: int) -> np.ndarray:
    rgb = np.clip(np.asarray(image, np.float32), 0, 1)
    rgb = cv2.resize(rgb, (size, size), interpolation=cv2.INTER_AREA)
    return (rgb[..., ::-1] * 255 + 0.5).astype(np.uint8)


def _error_map(photo: np.ndarray, render: np.ndarray, size: int) -> np.ndarray:
    """Mean absolute difference over RGB, x4 so that 0.25 saturates, as an inferno colour map."""
    err = np.abs(np.asarray(photo, np.float32) - np.asarray(render, np.float32)).mean(-1)
    err = cv2.resize(err, (size, size), interpolation=cv2.INTER_AREA)
    return cv2.applyColorMap((np.clip(err * 4, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)


def _text(canvas, text: str, x: int, y: int, scale: float = 0.5, colour=(235, 235, 235)):
    cv2.putText(canvas, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def write_report(path: str | Path, photos: tuple[np.ndarray, np.ndarray], renders: tuple[np.ndarray, np.ndarray],
                 metrics: dict[str, dict[str, float]], params: FabricParams, wall_s: float) -> Path:
    """Writes report.png: rows reflection and transmission; columns photo, render, |error| x 4."""
    width = 3 * PANEL
    canvas = np.full((HEADER + 2 * (PANEL + 24), width, 3), 32, np.uint8)
    _text(canvas, f"pattern {params.pattern}   tiles {params.tiles[0]:.1f} x {params.tiles[1]:.1f}   "
                  f"fit {wall_s:.0f} s", 10, 24, 0.6)
    _text(canvas, "roughness " + " / ".join(f"{x:.2f}" for x in params.roughness)
          + "   thickness " + " / ".join(f"{x:.2f}" for x in params.thickness)
          + "   height " + " / ".join(f"{x:.2f}" for x in params.height_scale)
          + "   gap " + " / ".join(f"{x:.2f}" for x in params.gap_scale), 10, 50)
    _text(canvas, "twist " + " / ".join(f"{x:.1f}" for x in params.twist_deg)
          + "   (warp / weft)", 10, 74)
    for row, (tag, name) in enumerate((("R", "reflection"), ("T", "transmission"))):
        top = HEADER + row * (PANEL + 24)
        m = metrics[name]
        _text(canvas, f"{name}: FLIP {m['flip']:.3f}   colour L1 {m['colour_l1']:.4f}   "
                      f"spectrum corr {m['spectrum_corr']:.3f}", 10, top + 17)
        panels = [_to_bgr8(photos[row], PANEL), _to_bgr8(renders[row], PANEL),
                  _error_map(photos[row], renders[row], PANEL)]
        for col, (panel, label) in enumerate(zip(panels, ("photo", "render", "|error| x4"))):
            canvas[top + 24: top + 24 + PANEL, col * PANEL:(col + 1) * PANEL] = panel
            _text(canvas, label, col * PANEL + 8, top + 24 + PANEL - 10, 0.5)
    path = Path(path)
    if not cv2.imwrite(str(path), canvas):
        raise OSError(f"{path}: could not write the report")
    return path
