"""The fit report (report.png): what the fit found and how its re-renders compare with the photos.

- a header: pattern, tiles, the main parameters (warp / weft), the camera blur, sample rotation,
  photo light falloff and uneven yarn spacing the fit read (the re-renders show them; the material
  carries none), whether the photos were registered onto one framing
  (:mod:`backend.image.registration`), and every parameter that ended at a bound of its declared
  range (in red: the fit wanted a value beyond the range, or the images do not constrain it);
- per image (reflection, transmission): photo, re-render and |error| x 4 (inferno) at 320 px, with
  FLIP, 16 x 16 colour L1 and spectrum correlation; where only part of a photo was compared (a
  registered pair's moved photo: :meth:`backend.image.photos.PhotoPair.seen_boxes`), that part is
  outlined;
- a row of zoomed centre crops (``CROP`` x ``CROP`` photo pixels, enlarged without smoothing) of
  photo and re-render for both images, where the weave itself can be compared: dense weaves have
  2-3 pixels per yarn, which a downsampled overview cannot show.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..core.jsonfile import replacing
from ..core.params import FabricParams
from ..core.rig import CaptureRig
from ..model.photo_light import PhotoLight
from ..model.spacing_warp import SpacingWarp

PANEL = 320            # px: one photo, re-render or error map in the overview
CROP = 96              # photo px of the zoomed centre crops
CROP_PANEL = 240       # px a crop is enlarged to (without smoothing)
LINE = 24              # px per line of text
FONT_SCALE = 0.5
SEPARATOR = "   "      # between the items of a header line; lines wrap there
RED = (80, 80, 235)    # BGR: a parameter at a bound
GREEN = (80, 220, 80)  # BGR: the part of a photo that was compared
GREY = (235, 235, 235)  # BGR: text


def _to_bgr8(image: np.ndarray, size: int, interpolation=cv2.INTER_AREA) -> np.ndarray:
    rgb = np.clip(np.asarray(image, np.float32), 0, 1)
    rgb = cv2.resize(rgb, (size, size), interpolation=interpolation)
    return (rgb[..., ::-1] * 255 + 0.5).astype(np.uint8)


def _error_map(photo: np.ndarray, render: np.ndarray, size: int) -> np.ndarray:
    """Mean absolute difference over RGB, x4 so that 0.25 saturates, as an inferno colour map."""
    err = np.abs(np.asarray(photo, np.float32) - np.asarray(render, np.float32)).mean(-1)
    err = cv2.resize(err, (size, size), interpolation=cv2.INTER_AREA)
    return cv2.applyColorMap((np.clip(err * 4, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)


def centre_crop(image: np.ndarray) -> np.ndarray:
    """The centred CROP x CROP pixels of ``image``."""
    top = (image.shape[0] - CROP) // 2
    left = (image.shape[1] - CROP) // 2
    return image[top:top + CROP, left:left + CROP]


def _outline(panel: np.ndarray, box, scale: float):
    """A box (x, y, w, h, image px) drawn on a panel showing the image at ``scale``."""
    x, y, w, h = (round(v * scale) for v in box)
    cv2.rectangle(panel, (x, y), (x + w - 1, y + h - 1), GREEN, 1)


def _text(canvas, text: str, x: int, y: int, colour=GREY):
    cv2.putText(canvas, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, FONT_SCALE, colour, 1, cv2.LINE_AA)


def text_width(text: str) -> int:
    """Width in pixels of ``text`` as :func:`_text` draws it."""
    return cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, FONT_SCALE, 1)[0][0]


def wrapped(text: str, width: int) -> list[str]:
    """``text`` broken at SEPARATOR into lines no wider than ``width`` pixels (a single item wider
    than that stays whole on its own line)."""
    lines: list[str] = []
    for item in text.split(SEPARATOR):
        if lines and text_width(lines[-1] + SEPARATOR + item) <= width:
            lines[-1] += SEPARATOR + item
        else:
            lines.append(item)
    return lines


def _signed(values) -> str:
    return " ".join(f"{x:+.2f}" for x in values)


def _pairs(values, digits: int) -> str:
    return " / ".join(f"{x:.{digits}f}" for x in values)


def _header(params: FabricParams, rig: CaptureRig, wall_s: float, at_bounds: list[str], light: PhotoLight,
            registration: dict | None, warp: SpacingWarp | None) -> list[tuple[str, tuple | None]]:
    """The header's items as (text, colour; None: the default), before wrapping."""
    header = [(f"pattern {params.pattern}   tiles {params.tiles[0]:.1f} x {params.tiles[1]:.1f}   "
               f"camera blur {rig.camera_blur_px:.2f} px   sample rotation {rig.sample_rotation_deg:+.2f} deg   "
               f"skew {rig.sample_skew_deg:+.2f} deg   "
               f"fit {wall_s:.0f} s", None),
              (f"roughness {_pairs(params.roughness, 2)}   thickness {_pairs(params.thickness, 2)}   "
               f"height {_pairs(params.height_scale, 2)}   gap {_pairs(params.gap_scale, 2)}   "
               f"twist {_pairs(params.twist_deg, 1)}   (warp / weft)", None)]
    if not light.flat:
        header.append((f"photo light falloff (x, y, r): R {_signed(light.reflection)}   T {_signed(light.transmission)}"
                       "   (in the re-renders, not in the material)", None))
    if warp is not None:
        dx, dy = warp.sampled(rig.film_size)
        largest = float(np.sqrt(dx ** 2 + dy ** 2).max())
        header.append((f"uneven yarn spacing: the lattice warped by {warp.rms_px(rig.film_size):.2f} px rms, at most "
                       f"{largest:.2f} px   (in the re-renders, not in the material)", None))
    if registration is not None:
        header.append((f"photos registered: their lattices were {registration['magnification']:.3f}x and "
                       f"{registration['turn_deg']:+.2f} deg apart (the phone moved between the shots)   the "
                       f"{registration['moved']} photo is shown as taken, its re-render carried back into its "
                       "framing   compared inside the outline: what the fit saw", None))
    return header + ([(f"at a bound: {item}", RED) for item in at_bounds] or [("no parameter at a bound", None)])


def _draw_images(canvas: np.ndarray, top: int, photos, renders, metrics: dict[str, dict[str, float]],
                 compared) -> None:
    """Per image from ``top`` down: its metrics, then photo, re-render and error map, the compared
    box outlined where it is not the whole photo."""
    for row, name in enumerate(("reflection", "transmission")):
        y = top + row * (PANEL + LINE)
        m = metrics[name]
        _text(canvas, f"{name}: FLIP {m['flip']:.3f}   colour L1 {m['colour_l1']:.4f}   "
                      f"spectrum corr {m['spectrum_corr']:.3f}", 10, y + 17)
        panels = [_to_bgr8(photos[row], PANEL), _to_bgr8(renders[row], PANEL),
                  _error_map(photos[row], renders[row], PANEL)]
        box = None if compared is None else compared[row]
        for col, (panel, label) in enumerate(zip(panels, ("photo", "render", "|error| x4"))):
            if box is not None and tuple(box) != (0, 0, *photos[row].shape[1::-1]):
                _outline(panel, box, PANEL / photos[row].shape[1])
            canvas[y + LINE: y + LINE + PANEL, col * PANEL:(col + 1) * PANEL] = panel
            _text(canvas, label, col * PANEL + 8, y + LINE + PANEL - 10)


def _draw_crops(canvas: np.ndarray, top: int, photos, renders) -> None:
    """The row of enlarged centre crops from ``top``: photo and re-render, reflection then transmission."""
    _text(canvas, f"centre {CROP} x {CROP} px, enlarged", 10, top + 17)
    crops = [(photos[0], "photo R"), (renders[0], "render R"), (photos[1], "photo T"), (renders[1], "render T")]
    for col, (image, label) in enumerate(crops):
        x = col * CROP_PANEL
        panel = _to_bgr8(centre_crop(np.asarray(image)), CROP_PANEL, cv2.INTER_NEAREST)
        canvas[top + LINE: top + LINE + CROP_PANEL, x:x + CROP_PANEL] = panel
        _text(canvas, label, x + 8, top + LINE + CROP_PANEL - 10)


def write_report(path: str | Path, photos: tuple[np.ndarray, np.ndarray], renders: tuple[np.ndarray, np.ndarray],
                 metrics: dict[str, dict[str, float]], params: FabricParams, rig: CaptureRig, wall_s: float,
                 at_bounds: list[str], light: PhotoLight = PhotoLight(), registration: dict | None = None,
                 compared: tuple[tuple[int, int, int, int], ...] | None = None, warp: SpacingWarp | None = None
                 ) -> Path:
    """Writes report.png (see the module docstring); ``compared``: per image the (x, y, w, h) box the
    metrics cover, None for the whole images."""
    width = 3 * PANEL
    header = [(line, colour) for text, colour in _header(params, rig, wall_s, at_bounds, light, registration, warp)
              for line in wrapped(text, width - 20)]
    top = LINE * (len(header) + 1)
    crop_top = top + 2 * (PANEL + LINE)
    canvas = np.full((crop_top + LINE + CROP_PANEL, width, 3), 32, np.uint8)
    for index, (line, colour) in enumerate(header):
        _text(canvas, line, 10, LINE * (index + 1) - 4, colour or GREY)
    _draw_images(canvas, top, photos, renders, metrics, compared)
    _draw_crops(canvas, crop_top, photos, renders)
    path = Path(path)
    with replacing(path) as temporary:
        if not cv2.imwrite(str(temporary), canvas):
            raise OSError(f"{path}: could not write the report")
    return path
