"""Decoding a photo file into upright RGB pixels: :func:`read_image` -> :class:`SourceImage`.

- The format is recognised by content (PNG, JPEG, TIFF, OpenEXR signatures), camera RAW by file
  suffix (:func:`backend.core.formats.is_raw`); a few formats people will try (HEIC/HEIF/AVIF,
  WebP, GIF, BMP) are named in the error.
- PNG, JPEG, TIFF and OpenEXR are decoded by OpenCV (``imdecode`` of the bytes with
  ``IMREAD_UNCHANGED``, which keeps 16 bits and floats and reads non-ASCII paths on Windows), after
  :mod:`.containers` has checked for truncation and read the EXIF orientation, which is then applied.
  OpenCV decodes EXR only when ``OPENCV_IO_ENABLE_OPENEXR`` is set, and reads that variable once, at
  the first EXR decode of the process: it is set (unless already set) right before decoding an EXR.
  That is this module's own switch, not a user's setting: reading EXR is what :func:`read_image`
  promises every caller (the fit command, the tests, the developer tools), and only here is it sure
  to be set before OpenCV's first EXR decode; a value the user has set (``0``) is left alone.
- Camera RAW is decoded by rawpy (LibRaw) linearly: camera white balance, no auto-brightness,
  16 bits, gamma (1, 1), sRGB primaries (:data:`RAW_POSTPROCESS`); LibRaw applies the camera's
  orientation.
- Alpha channels are dropped; greyscale is expanded to RGB; float samples become float32.
- Float photos with NaN or infinite samples are refused, with their count (:func:`check_finite`):
  a camera gives none, so they mark a broken export (a failed HDR merge, a division by zero in an
  earlier correction) whose other pixels are suspect too, and any repair (0, the neighbours' mean)
  would invent fabric that the fit then matches. Negative samples (noise about the black level of
  a linear export) are clipped at 0 (:func:`.tone.to_linear`).
- Linear sources: float (EXR, float TIFF) and camera RAW. 8/16-bit PNG, JPEG and TIFF are encoded
  (:mod:`.tone`).
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import rawpy

from ..core.formats import RAW_SUFFIXES, is_raw
from .containers import PNG_SIGNATURE, apply_orientation, check_structure
from .errors import PhotoError

Box = tuple[int, int, int, int]  # x, y, width, height in pixels of the upright image

_JPEG_SIGNATURE = b"\xff\xd8\xff"
_TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
_EXR_SIGNATURE = b"v/1\x01"
_EXR_SWITCH = "OPENCV_IO_ENABLE_OPENEXR"

RAW_POSTPROCESS = dict(use_camera_wb=True, use_auto_wb=False, no_auto_bright=True, output_bps=16, gamma=(1, 1),
                       output_color=rawpy.ColorSpace.sRGB)


@dataclass
class SourceImage:
    """A decoded photo, upright, before any crop: (H, W, 3) RGB in its own dtype.

    ``pixels`` is uint8, uint16 or float32. ``linear``: the values are proportional to radiance
    (EXR, float TIFF, camera RAW as 16-bit integers); otherwise they are encoded (:mod:`.tone`).
    """

    path: Path
    pixels: np.ndarray
    format: str
    linear: bool

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.pixels.shape[1], self.pixels.shape[0]

    def crop(self, box: Box) -> np.ndarray:
        """The pixels inside ``box`` (a view)."""
        x, y, w, h = box
        return self.pixels[y:y + h, x:x + w]


def read_image(path: str | os.PathLike) -> SourceImage:
    """Reads a PNG, JPEG, TIFF, EXR or camera RAW file into an upright :class:`SourceImage`."""
    path = Path(path)
    if not path.exists():
        raise PhotoError(f"{path}: file not found")
    if not path.is_file():
        raise PhotoError(f"{path}: not a file")
    if is_raw(path.suffix):
        return _read_raw(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PhotoError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not data:
        raise PhotoError(f"{path}: the file is empty")
    kind = _sniff_format(data, path)
    orientation = check_structure(data, kind, path)
    pixels = _to_rgb(_decode(data, kind, path), path)
    check_finite(pixels, path)
    pixels = apply_orientation(pixels, orientation)
    depth = {np.dtype(np.uint8): "8-bit", np.dtype(np.uint16): "16-bit"}.get(pixels.dtype, "float")
    return SourceImage(path, np.ascontiguousarray(pixels), f"{kind} {depth}", linear=pixels.dtype.kind == "f")


def _sniff_format(data: bytes, path: Path) -> str:
    if data.startswith(PNG_SIGNATURE):
        return "png"
    if data.startswith(_JPEG_SIGNATURE):
        return "jpeg"
    if data[:4] in _TIFF_SIGNATURES:
        return "tiff"
    if data.startswith(_EXR_SIGNATURE):
        return "exr"
    hint = _name_unsupported(data)
    raise PhotoError(f"{path}: unsupported file format{hint} (expected PNG, JPEG, TIFF, OpenEXR or camera RAW "
                     f"with one of the extensions {', '.join(sorted(RAW_SUFFIXES))})")


def _name_unsupported(data: bytes) -> str:
    """A few formats people will try, named so the message says what to do."""
    if data[4:8] == b"ftyp" and data[8:12] in (b"heic", b"heix", b"mif1", b"msf1", b"hevc", b"avif"):
        return " (HEIC/HEIF/AVIF: export the photo as JPEG, PNG or TIFF)"
    if data.startswith(b"RIFF") and data[8:12] == b"WEBP":
        return " (WebP)"
    if data.startswith((b"GIF87a", b"GIF89a")):
        return " (GIF)"
    if data.startswith(b"BM"):
        return " (BMP)"
    return ""


def _decode(data: bytes, kind: str, path: Path) -> np.ndarray:
    if kind == "exr":
        # OpenCV's EXR codec is off unless this is set, and OpenCV reads it once, at the first EXR
        # decode: set here, where it is sure to come first (module docstring).
        os.environ.setdefault(_EXR_SWITCH, "1")
    buffer = np.frombuffer(data, dtype=np.uint8)  # imdecode, not imread: non-ASCII paths on Windows
    try:
        pixels = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise PhotoError(f"{path}: could not be decoded as {kind.upper()} ({_error_line(exc)})") from None
    if pixels is None or pixels.size == 0:
        raise PhotoError(f"{path}: could not be decoded as {kind.upper()} (corrupt or unsupported variant)")
    return pixels


def _error_line(exc: BaseException) -> str:
    """The line of a decoder's error that says what went wrong (OpenCV's last, rawpy's only)."""
    text = str(exc).strip().splitlines()
    return text[-1].strip() if text else type(exc).__name__


def _to_rgb(pixels: np.ndarray, path: Path) -> np.ndarray:
    """OpenCV's BGR(A)/grey in any supported dtype -> RGB; float sources become float32."""
    if pixels.dtype not in (np.uint8, np.uint16) and pixels.dtype.kind != "f":
        raise PhotoError(f"{path}: unsupported sample format {pixels.dtype} (use 8/16-bit integers or float)")
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    channels = pixels.shape[2]
    if channels in (1, 2):  # grey, grey + alpha
        pixels = np.repeat(pixels[..., :1], 3, axis=2)
    elif channels in (3, 4):  # BGR, BGRA
        pixels = pixels[..., 2::-1]
    else:
        raise PhotoError(f"{path}: {channels} colour channels are not supported (expected grey, RGB or RGBA)")
    if pixels.dtype.kind == "f":
        pixels = pixels.astype(np.float32, copy=False)
    return pixels


def check_finite(pixels: np.ndarray, path: Path) -> None:
    """Refuses float pixels (H, W, 3) of which any sample is NaN or infinite, with their count."""
    if pixels.dtype.kind != "f":
        return
    broken = int((~np.isfinite(pixels)).any(axis=2).sum())
    if broken:
        raise PhotoError(f"{path}: {broken} of its {pixels.shape[0] * pixels.shape[1]} pixels hold NaN or infinite "
                         "values, which no camera gives (a broken export?): export the photo again")


def _read_raw(path: Path) -> SourceImage:
    try:
        with rawpy.imread(str(path)) as raw:
            pixels = raw.postprocess(**RAW_POSTPROCESS)
    except Exception as exc:  # LibRaw's error classes vary by version; any failure is a bad file
        raise PhotoError(f"{path}: could not be decoded as camera RAW ({type(exc).__name__}: "
                         f"{_error_line(exc)})") from None
    pixels = np.asarray(pixels)
    if pixels.ndim != 3 or pixels.shape[2] != 3 or pixels.dtype != np.uint16:
        raise PhotoError(f"{path}: the RAW decoder returned {pixels.dtype} {pixels.shape}, expected 16-bit RGB")
    return SourceImage(path, pixels, "camera raw", linear=True)
