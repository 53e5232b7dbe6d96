"""The fuzz harness's photos: a small synthetic pair that the loader takes, and its encodings in every
format and variant the loader must handle (bytes, built here: OpenCV writes only some of them).

- :func:`base_pair`: a woven-looking pair (a lattice of cosines and a little noise) lit as the rig
  lights it, the reflection from the front light above the top edge, the transmission from the back
  light behind the centre, so that the pair checks pass it; linear RGB in [0, 1], ``SIDE`` pixels.
- :data:`ENCODINGS`: name -> function(linear RGB) -> file bytes: PNG 8/16-bit, grey, grey + alpha,
  RGBA, palette (written by :func:`png_bytes`), JPEG RGB and grey (OpenCV), CMYK JPEG
  (:func:`cmyk_jpeg_bytes`), TIFF 8/16-bit and float, OpenEXR (OpenCV), camera RAW as a minimal
  DNG (:func:`dng_bytes`).
"""
from __future__ import annotations

import os
import struct
import zlib

import cv2
import numpy as np

from backend.image.containers import PNG_SIGNATURE

SIDE = 96       # pixels of the base photos: above the working size the harness loads them at (FILM)
FILM = 64       # the rig file's film size in the photo cases: the loader's work is small, its checks all run
_EXR_SWITCH = "OPENCV_IO_ENABLE_OPENEXR"


def base_pair(side: int = SIDE, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(reflection, transmission): linear RGB float32 in [0, 1] of a synthetic fabric, lit as the rig lights it."""
    yy, xx = (np.mgrid[0:side, 0:side] + 0.5) / side
    rng = np.random.default_rng(seed)

    def fabric(phase):
        lattice = ((25, 0), (0, 27), (25, 27))  # cycles per image: over 16 in any 64-px crop (the pair checks' least)
        waves = sum(np.cos(2 * np.pi * (fx * xx + fy * yy) + phase) for fx, fy in lattice) / len(lattice)
        return np.clip(0.6 + 0.35 * waves + 0.03 * rng.standard_normal((side, side)), 0.05, 1)

    front = 2.25 / ((xx - 0.5) ** 2 + (yy + 1) ** 2 + 1)
    radius2 = (xx - 0.5) ** 2 + (yy - 0.5) ** 2
    back = 1 / (1 + radius2 / 0.6) + 0.5 * np.exp(-radius2 / 0.01)
    tint = np.array([0.9, 0.8, 0.6])
    reflection = 0.5 * (fabric(0.0) * front)[..., None] * tint
    transmission = 0.4 * (fabric(np.pi) * back)[..., None] * tint
    return reflection.astype(np.float32), transmission.astype(np.float32)


def encoded(linear: np.ndarray, dtype=np.uint8) -> np.ndarray:
    """Linear RGB as the renders' curve encodes it (1/2.2), in ``dtype``'s full range."""
    top = np.iinfo(dtype).max
    return np.round(np.clip(linear, 0, 1) ** (1 / 2.2) * top).astype(dtype)


def grey(pixels: np.ndarray) -> np.ndarray:
    """The mean of the colour channels, in the pixels' dtype."""
    return pixels.mean(axis=2).round().astype(pixels.dtype)


# -- PNG --------------------------------------------------------------------------------------------

def png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def png_bytes(pixels: np.ndarray, colour_type: int, palette: np.ndarray | None = None) -> bytes:
    """A PNG of ``pixels`` ((H, W) or (H, W, C), uint8 or uint16) with the given colour type (0 grey,
    2 RGB, 3 palette: ``pixels`` are indices into ``palette`` (N, 3), 4 grey + alpha, 6 RGBA)."""
    height, width = pixels.shape[:2]
    depth = 16 if pixels.dtype == np.uint16 else 8
    rows = np.ascontiguousarray(pixels.astype(">u2" if depth == 16 else np.uint8)).reshape(height, -1)
    scanlines = b"".join(b"\x00" + row.tobytes() for row in rows)
    chunks = [png_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, depth, colour_type, 0, 0, 0))]
    if palette is not None:
        chunks.append(png_chunk(b"PLTE", palette.astype(np.uint8).tobytes()))
    chunks += [png_chunk(b"IDAT", zlib.compress(scanlines)), png_chunk(b"IEND", b"")]
    return PNG_SIGNATURE + b"".join(chunks)


def _palette_png(linear: np.ndarray) -> bytes:
    """A palette PNG: the colours quantised to a 6 x 6 x 6 cube."""
    levels = np.round(encoded(linear).astype(np.float32) / 51).astype(np.uint8)  # 0..5 per channel
    indices = levels[..., 0] * 36 + levels[..., 1] * 6 + levels[..., 2]
    cube = np.stack(np.meshgrid(*(np.arange(6) * 51,) * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    return png_bytes(indices, 3, cube)


# -- JPEG -------------------------------------------------------------------------------------------

def _cv2_bytes(suffix: str, pixels: np.ndarray, params=()) -> bytes:
    if suffix == ".exr":
        os.environ.setdefault(_EXR_SWITCH, "1")  # OpenCV's EXR codec is off unless set before its first use
    data = pixels[..., ::-1] if pixels.ndim == 3 else pixels
    ok, buffer = cv2.imencode(suffix, np.ascontiguousarray(data), list(params))
    if not ok:
        raise RuntimeError(f"OpenCV could not encode {suffix}")
    return buffer.tobytes()


# Huffman tables of a DC-only baseline JPEG: the standard luminance DC table (categories 0-11) and an
# AC table holding only the end-of-block symbol.
_DC_COUNTS, _DC_SYMBOLS = (0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0), tuple(range(12))
_AC_COUNTS, _AC_SYMBOLS = (1,) + (0,) * 15, (0,)


def _huffman_codes(counts, symbols) -> dict[int, tuple[int, int]]:
    """symbol -> (code, length) of a canonical JPEG Huffman table."""
    codes, code, index = {}, 0, 0
    for length, count in enumerate(counts, 1):
        for _ in range(count):
            codes[symbols[index]] = (code, length)
            code, index = code + 1, index + 1
        code <<= 1
    return codes


def _segment(marker: int, body: bytes) -> bytes:
    return struct.pack(">BBH", 0xFF, marker, len(body) + 2) + body


def cmyk_jpeg_bytes(linear: np.ndarray) -> bytes:
    """A baseline 4-component (Adobe, inverted CMYK as Photoshop writes it) JPEG whose 8 x 8 blocks
    are flat: each block's mean colour, coded by its DC coefficient alone. OpenCV cannot write CMYK."""
    rgb = encoded(linear).astype(np.float32) / 255
    k = 1 - rgb.max(axis=2, keepdims=True)
    cmy = (1 - rgb - k) / np.maximum(1 - k, 1e-6)
    samples = np.round(255 * (1 - np.concatenate([cmy, k], axis=2))).astype(np.int32)  # inverted CMYK
    height, width = samples.shape[:2]
    blocks = samples[:height // 8 * 8, :width // 8 * 8].reshape(height // 8, 8, width // 8, 8, 4).mean(axis=(1, 3))
    dc_codes, ac_end = _huffman_codes(_DC_COUNTS, _DC_SYMBOLS), _huffman_codes(_AC_COUNTS, _AC_SYMBOLS)[0]
    bits, previous = [], [0, 0, 0, 0]
    for block in blocks.reshape(-1, 4):
        for channel in range(4):
            dc = int(round(8 * (block[channel] - 128)))  # the DC coefficient of a flat block, quantised by 1
            diff, previous[channel] = dc - previous[channel], dc
            size = abs(diff).bit_length()
            code, length = dc_codes[size]
            bits.append((code, length))
            if size:
                bits.append((diff if diff > 0 else diff + (1 << size) - 1, size))
            bits.append(ac_end)
    stream = "".join(format(code, f"0{length}b") for code, length in bits)
    stream += "1" * (-len(stream) % 8)
    entropy = bytes(int(stream[i:i + 8], 2) for i in range(0, len(stream), 8)).replace(b"\xff", b"\xff\x00")

    def table(kind_and_id, counts, symbols):
        return bytes([kind_and_id, *counts, *symbols])

    components = b"".join(bytes([c, 0x11, 0]) for c in range(1, 5))
    return b"".join([
        b"\xff\xd8",
        _segment(0xEE, b"Adobe" + struct.pack(">HHHB", 100, 0, 0, 0)),   # transform 0: CMYK as stored
        _segment(0xDB, bytes([0]) + bytes([1] * 64)),                      # quantisation table 0: all ones
        _segment(0xC0, struct.pack(">BHHB", 8, height // 8 * 8, width // 8 * 8, 4) + components),
        _segment(0xC4, table(0x00, _DC_COUNTS, _DC_SYMBOLS) + table(0x10, _AC_COUNTS, _AC_SYMBOLS)),
        _segment(0xDA, bytes([4]) + b"".join(bytes([c, 0x00]) for c in range(1, 5)) + bytes([0, 63, 0])),
        entropy, b"\xff\xd9"])


# -- TIFF and DNG -----------------------------------------------------------------------------------

_TIFF_TYPES = {1: "B", 2: "s", 3: "H", 4: "I", 5: "II", 10: "ii"}  # BYTE, ASCII, SHORT, LONG, (S)RATIONAL


def tiff_bytes(entries: list[tuple[int, int, list]], image: bytes) -> bytes:
    """A little-endian TIFF: one directory of ``entries`` (tag, type, values; rationals as
    (numerator, denominator) pairs) and ``image``, the strip that tag 273 (StripOffsets) points to."""
    entries = sorted(entries)
    ifd_size = 2 + 12 * len(entries) + 4
    data_at = 8 + ifd_size
    extra, fields = b"", []
    for tag, kind, values in entries:
        if kind == 2:
            packed = values.encode() + b"\x00"
        else:
            flat = [x for v in values for x in (v if isinstance(v, tuple) else (v,))]
            packed = struct.pack("<" + _TIFF_TYPES[kind][-1] * len(flat), *flat)
        count = len(packed) if kind == 2 else len(values)
        if tag == 273:
            packed = b"\x00" * 4  # the strip's offset, filled in below
        if len(packed) <= 4:
            fields.append((tag, kind, count, packed.ljust(4, b"\x00")))
        else:
            fields.append((tag, kind, count, struct.pack("<I", data_at + len(extra))))
            extra += packed + b"\x00" * (len(packed) % 2)
    strip_at = data_at + len(extra)
    body = b"".join(struct.pack("<HHI", tag, kind, count) + (struct.pack("<I", strip_at) if tag == 273 else value)
                    for tag, kind, count, value in fields)
    return b"II*\x00" + struct.pack("<I", 8) + struct.pack("<H", len(fields)) + body + b"\x00" * 4 + extra + image


def dng_bytes(linear: np.ndarray) -> bytes:
    """A minimal uncompressed DNG (16-bit RGGB Bayer mosaic of ``linear``) that LibRaw decodes."""
    height, width = linear.shape[0] // 2 * 2, linear.shape[1] // 2 * 2
    mosaic = np.empty((height, width), np.uint16)
    scaled = np.round(np.clip(linear[:height, :width], 0, 1) * 60000).astype(np.uint16)
    mosaic[0::2, 0::2], mosaic[0::2, 1::2] = scaled[0::2, 0::2, 0], scaled[0::2, 1::2, 1]
    mosaic[1::2, 0::2], mosaic[1::2, 1::2] = scaled[1::2, 0::2, 1], scaled[1::2, 1::2, 2]
    pixels = mosaic.astype("<u2").tobytes()
    identity = [(1, 1) if i % 4 == 0 else (0, 1) for i in range(9)]
    entries = [(254, 4, [0]), (256, 4, [width]), (257, 4, [height]), (258, 3, [16]), (259, 3, [1]),
               (262, 3, [32803]), (271, 2, "Fuzz"), (272, 2, "Fuzz DNG"), (273, 4, [0]), (274, 3, [1]),
               (277, 3, [1]), (278, 4, [height]), (279, 4, [len(pixels)]), (284, 3, [1]),
               (33421, 3, [2, 2]), (33422, 1, [0, 1, 1, 2]), (50706, 1, [1, 4, 0, 0]), (50708, 2, "Fuzz DNG"),
               (50717, 4, [65535]), (50721, 10, identity), (50728, 5, [(1, 1)] * 3), (50778, 3, [21])]
    return tiff_bytes(entries, pixels)


def _tiff(pixels: np.ndarray) -> bytes:
    return _cv2_bytes(".tif", pixels, (cv2.IMWRITE_TIFF_COMPRESSION, 1))  # float TIFFs would be lossy LogLuv


# name -> (file suffix, encoder of linear RGB)
ENCODINGS = {
    "png8": (".png", lambda linear: _cv2_bytes(".png", encoded(linear))),
    "png16": (".png", lambda linear: _cv2_bytes(".png", encoded(linear, np.uint16))),
    "png-grey": (".png", lambda linear: png_bytes(grey(encoded(linear)), 0)),
    "png-grey-alpha": (".png", lambda linear: png_bytes(
        np.stack([grey(encoded(linear)), np.full(linear.shape[:2], 255, np.uint8)], axis=2), 4)),
    "png-rgba16": (".png", lambda linear: png_bytes(
        np.concatenate([encoded(linear, np.uint16), np.full((*linear.shape[:2], 1), 65535, np.uint16)], axis=2), 6)),
    "png-palette": (".png", _palette_png),
    "jpeg": (".jpg", lambda linear: _cv2_bytes(".jpg", encoded(linear), (cv2.IMWRITE_JPEG_QUALITY, 92))),
    "jpeg-grey": (".jpg", lambda linear: _cv2_bytes(".jpg", grey(encoded(linear)))),
    "jpeg-cmyk": (".jpg", cmyk_jpeg_bytes),
    "tiff8": (".tif", lambda linear: _tiff(encoded(linear))),
    "tiff16": (".tif", lambda linear: _tiff(encoded(linear, np.uint16))),
    "tiff-float": (".tif", lambda linear: _tiff(linear.astype(np.float32))),
    "exr": (".exr", lambda linear: _cv2_bytes(".exr", linear.astype(np.float32))),
    "dng": (".dng", dng_bytes),
}
