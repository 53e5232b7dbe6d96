"""The structure of JPEG, PNG and TIFF files: truncation and EXIF orientation, before decoding.

OpenCV decodes a cut-off file without complaint (the missing rows come out grey), so the structure
is walked first and a truncated file raises :class:`PhotoError`:

- JPEG: the marker segments up to the first scan, then an end-of-image marker (FF D9) after it;
- PNG: the chunks up to IEND;
- TIFF (classic): the first directory (IFD) and the strip or tile data it points to lie inside the
  file; BigTIFF is left to the decoder.

The image size the header declares (PNG IHDR, JPEG SOF, TIFF ImageWidth / ImageLength, OpenEXR
dataWindow) is checked on the way: above :data:`MAX_SOURCE_PIXELS` the file is refused before the
decoder allocates it (a damaged or crafted header over a few kilobytes of data: a decompression bomb).

EXIF orientation (1 = upright .. 8) is read from a JPEG's APP1 ``Exif`` segment and a PNG's eXIf
chunk, because OpenCV's ``IMREAD_UNCHANGED`` ignores it there; OpenCV's TIFF decoder applies the
TIFF Orientation tag itself, so TIFF reports 1 (the tests check all three).
:func:`apply_orientation` turns stored pixels upright.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from .errors import PhotoError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_ORIENTATION_TAG = 0x0112
# More pixels than any camera's photo (phones reach 200 million): a header declaring more is damaged or
# crafted, and decoding it would take gigabytes (tens of bytes a pixel on the way to the working image).
MAX_SOURCE_PIXELS = 250_000_000
_JPEG_FRAMES = set(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}  # SOF0-SOF15 markers (C4, C8, CC are not frames)


def check_structure(data: bytes, kind: str, path: Path) -> int:
    """Raises on a truncated file of ``kind`` ("jpeg", "png", "tiff"), or one declaring more than
    MAX_SOURCE_PIXELS ("exr" too); returns the EXIF orientation to apply after decoding (1 = upright,
    also for any other kind)."""
    if kind == "jpeg":
        return _jpeg_structure(data, path)
    if kind == "png":
        return _png_structure(data, path)
    if kind == "tiff":
        return _tiff_structure(data, path)
    if kind == "exr":
        _exr_header(data, path)
    return 1


def _check_declared_size(path: Path, width: int, height: int) -> None:
    if width * height > MAX_SOURCE_PIXELS:
        raise PhotoError(f"{path}: the file declares {width} x {height} pixels, more than any camera's photo (at most "
                         f"{MAX_SOURCE_PIXELS // 1_000_000} million): a damaged file?")


def _truncated(path: Path, what: str) -> PhotoError:
    return PhotoError(f"{path}: the file is truncated ({what}); copy it again from the camera")


def _jpeg_structure(data: bytes, path: Path) -> int:
    """Walks the marker segments up to the first scan, then looks for the end-of-image marker.

    Inside entropy-coded data 0xFF is always followed by 0x00 or a restart marker, so FF D9 after
    the first scan is the real EOI (a thumbnail's EOI sits inside APP1, which is skipped whole).
    """
    orientation, pos = 1, 2
    while True:
        while data[pos + 1:pos + 2] == b"\xff":
            pos += 1  # fill bytes before a marker
        if pos + 4 > len(data):
            raise _truncated(path, "it ends inside the JPEG header")
        if data[pos] != 0xFF:
            raise PhotoError(f"{path}: not a valid JPEG (bad marker at byte {pos})")
        marker = data[pos + 1]
        length = struct.unpack(">H", data[pos + 2:pos + 4])[0]
        segment = data[pos + 4:pos + 2 + length]
        if pos + 2 + length > len(data):
            raise _truncated(path, "it ends inside the JPEG header")
        if marker == 0xE1 and segment.startswith(b"Exif\x00\x00"):
            orientation = _tiff_orientation(segment[6:]) or orientation
        if marker in _JPEG_FRAMES and len(segment) >= 5:
            height, width = struct.unpack(">HH", segment[1:5])
            _check_declared_size(path, width, height)
        if marker == 0xDA:  # start of scan
            break
        pos += 2 + length
    if data.find(b"\xff\xd9", pos + 2 + length) < 0:
        raise _truncated(path, "no JPEG end-of-image marker")
    return orientation


def _png_structure(data: bytes, path: Path) -> int:
    """Walks the chunks to IEND; an eXIf chunk may carry an orientation."""
    orientation, pos = 1, len(PNG_SIGNATURE)
    while pos + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if pos + 12 + length > len(data):
            break
        if kind == b"IEND":
            return orientation
        if kind == b"IHDR" and length >= 8:
            _check_declared_size(path, *struct.unpack(">II", data[pos + 8:pos + 16]))
        if kind == b"eXIf":
            orientation = _tiff_orientation(data[pos + 8:pos + 8 + length]) or orientation
        pos += 12 + length
    raise _truncated(path, "no PNG IEND chunk")


def _tiff_structure(data: bytes, path: Path) -> int:
    """Checks that the first IFD and its image data lie inside the file; returns 1 (see the module
    docstring: OpenCV applies a TIFF's orientation itself)."""
    if data[2:4] in (b"+\x00", b"\x00+"):  # BigTIFF: no structural check, the decoder has the last word
        return 1
    entries = _tiff_ifd0(data)
    if entries is None:
        raise _truncated(path, "the TIFF directory lies beyond the end of the file")
    _check_declared_size(path, entries.get(256, [0])[0], entries.get(257, [0])[0])
    for offsets_tag, counts_tag in ((273, 279), (324, 325)):  # strips, tiles
        offsets, counts = entries.get(offsets_tag), entries.get(counts_tag)
        if offsets and counts and max(o + c for o, c in zip(offsets, counts)) > len(data):
            raise _truncated(path, "the TIFF image data runs past the end of the file")
    return 1


def _exr_header(data: bytes, path: Path) -> None:
    """Walks the attributes of an OpenEXR header (name, type, size, value; an empty name ends it) and
    checks the image size its dataWindow (box2i: x min, y min, x max, y max) declares."""
    pos = 8  # after the magic number and the version field
    while pos < len(data) and data[pos] != 0:
        name_end = data.find(b"\x00", pos)
        type_end = data.find(b"\x00", name_end + 1) if name_end >= 0 else -1
        if type_end < 0 or type_end + 5 > len(data):
            raise _truncated(path, "it ends inside the OpenEXR header")
        size = struct.unpack("<i", data[type_end + 1:type_end + 5])[0]
        if size < 0:
            raise PhotoError(f"{path}: not a valid OpenEXR file (an attribute of negative size at byte {pos})")
        if data[pos:name_end] == b"dataWindow" and size == 16 and type_end + 21 <= len(data):
            x_min, y_min, x_max, y_max = struct.unpack("<iiii", data[type_end + 5:type_end + 21])
            _check_declared_size(path, x_max - x_min + 1, y_max - y_min + 1)
        pos = type_end + 5 + size


def _tiff_ifd0(data: bytes) -> dict[int, list[int]] | None:
    """Integer-valued entries of a classic TIFF structure's first directory; None when cut off."""
    if len(data) < 8 or data[:2] not in (b"II", b"MM"):
        return {}
    order = "<" if data[:2] == b"II" else ">"
    ifd = struct.unpack(order + "I", data[4:8])[0]
    if ifd + 2 > len(data):
        return None
    count = struct.unpack(order + "H", data[ifd:ifd + 2])[0]
    if ifd + 2 + 12 * count > len(data):
        return None
    sizes = {1: ("B", 1), 3: ("H", 2), 4: ("I", 4)}  # BYTE, SHORT, LONG
    entries: dict[int, list[int]] = {}
    for i in range(count):
        start = ifd + 2 + 12 * i
        tag, kind, n = struct.unpack(order + "HHI", data[start:start + 8])
        if kind not in sizes or n == 0:
            continue
        code, width = sizes[kind]
        where = start + 8 if n * width <= 4 else struct.unpack(order + "I", data[start + 8:start + 12])[0]
        if where + n * width > len(data):
            return None
        entries[tag] = list(struct.unpack(f"{order}{n}{code}", data[where:where + n * width]))
    return entries


def _tiff_orientation(data: bytes) -> int:
    """The Orientation tag of an EXIF (TIFF-structured) block; 1 when absent or out of range."""
    values = (_tiff_ifd0(data) or {}).get(_ORIENTATION_TAG)
    return values[0] if values and 1 <= values[0] <= 8 else 1


def apply_orientation(pixels: np.ndarray, orientation: int) -> np.ndarray:
    """Turns stored pixels upright according to the EXIF orientation value (1..8)."""
    ops = {
        1: lambda a: a,
        2: lambda a: a[:, ::-1],
        3: lambda a: a[::-1, ::-1],
        4: lambda a: a[::-1],
        5: lambda a: a.swapaxes(0, 1),
        6: lambda a: np.rot90(a, -1),
        7: lambda a: a[::-1, ::-1].swapaxes(0, 1),
        8: lambda a: np.rot90(a, 1),
    }
    return ops.get(orientation, ops[1])(pixels)
