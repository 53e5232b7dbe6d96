"""Photo cases: the base pair in one format (:data:`.images.ENCODINGS`), one of its photos mutated.

Mutations of the file's bytes: truncated at a random offset, bits flipped, a span overwritten, the
format's signature replaced (random bytes or another format's), bytes appended, the header's image
size made huge (a decompression bomb: a large declared size over a few kilobytes of data) or zero.
Mutations of the image: one pixel, a thin strip, a tiny image (both photos), a constant image, NaN / infinite /
negative / huge values (float formats), the same image given twice (the same file, or the same
pixels in two files), the two photos swapped.

Each case is the ``fit`` command on the pair with a rig file of film size :data:`.images.FILM` (the
loader's work stays small, every check of it runs), and the pair fed to ``load_pair`` directly.
"""
from __future__ import annotations

import struct

import numpy as np

from .cases import EITHER, REFUSE, Case
from .images import ENCODINGS, FILM, base_pair, png_chunk

_SIGNATURES = (b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff\xe0", b"II*\x00", b"MM\x00*", b"v/1\x01", b"GIF89a", b"BM",
               b"RIFF\x00\x00\x00\x00WEBP", b"\x00\x00\x00\x18ftypheic", b"%PDF-1.4", b"PK\x03\x04")
_FLOAT_FORMATS = ("exr", "tiff-float")
# (width, height) a bomb's header declares: a 30000 x 30000 RGB photo is 2.7 GB decoded (8-bit).
_BOMBS = ((30000, 30000), (65535, 65535), (65535, 16), (16, 65535), (20000, 15000))


class _Mutated:
    """What a mutation made: the photo's new bytes (or both photos'), the words, the expectation."""

    def __init__(self, label: str, expect: str = EITHER, data: bytes | None = None, both: tuple | None = None):
        self.label, self.expect, self.data, self.both = label, expect, data, both


def _truncate(data, encoding, rng):
    cut = int(rng.integers(0, len(data)))
    return _Mutated(f"truncated at byte {cut} of {len(data)}", REFUSE, data[:cut])  # a cut file is never a photo


def _bit_flips(data, encoding, rng):
    flipped = bytearray(data)
    count = int(rng.integers(1, 17))
    for position in rng.integers(0, 8 * len(data), count):
        flipped[position // 8] ^= 1 << int(position % 8)
    return _Mutated(f"{count} bit(s) flipped", EITHER, bytes(flipped))


def _overwrite(data, encoding, rng):
    length = int(rng.integers(1, 65))
    start = int(rng.integers(0, max(1, len(data) - length)))
    span = rng.integers(0, 256, length, dtype=np.uint8).tobytes()
    return _Mutated(f"bytes {start}-{start + length} overwritten", EITHER, data[:start] + span + data[start + length:])


def _wrong_magic(data, encoding, rng):
    if rng.random() < 0.5:
        signature = _SIGNATURES[int(rng.integers(len(_SIGNATURES)))]
        if data[:3] == signature[:3]:  # the format's own (a JPEG's APP0 for its APP14 is still a JPEG): not wrong
            signature = b"\x00" * len(signature)
        label = f"signature replaced by {signature[:8]!r}"
    else:
        signature = rng.integers(0, 256, int(rng.integers(1, 9)), dtype=np.uint8).tobytes()
        label = f"first {len(signature)} byte(s) random"
    expect = EITHER if encoding == "dng" else REFUSE  # RAW is told by its suffix: LibRaw has the last word
    return _Mutated(label, expect, signature + data[len(signature):])


def _appended(data, encoding, rng):
    tail = rng.integers(0, 256, int(rng.integers(1, 4096)), dtype=np.uint8).tobytes()
    return _Mutated(f"{len(tail)} bytes appended", EITHER, data + tail)


def _declared(width: int, height: int):
    """A mutation: the header says the image is ``width`` x ``height`` pixels, its data stays as it was."""
    def mutate(data, encoding, rng):
        changed = with_declared_size(data, encoding, width, height)
        if changed is None:
            return None
        what = "zero" if 0 in (width, height) else "huge"
        return _Mutated(f"{what} declared size {width} x {height}", REFUSE, changed)
    return mutate


def _bomb(data, encoding, rng):
    width, height = _BOMBS[int(rng.integers(len(_BOMBS)))]
    return _declared(width, height)(data, encoding, rng)


def _zero_size(data, encoding, rng):
    width, height = ((0, 96), (96, 0), (0, 0))[int(rng.integers(3))]
    return _declared(width, height)(data, encoding, rng)


def with_declared_size(data: bytes, encoding: str, width: int, height: int) -> bytes | None:
    """``data`` with its header's image size changed (PNG IHDR, JPEG SOF, TIFF/DNG tags 256 and 257,
    OpenEXR dataWindow); None for a format it does not know."""
    if data.startswith(b"\x89PNG"):
        header = data[12:16] + struct.pack(">II", width, height) + data[24:29]
        return data[:8] + png_chunk(b"IHDR", header[4:]) + data[33:]
    if data.startswith(b"\xff\xd8"):
        return _jpeg_size(data, width, height)
    if data[:4] == b"II*\x00":
        return _tiff_size(data, width, height)
    if data.startswith(b"v/1\x01"):
        at = data.find(b"dataWindow\x00box2i\x00")
        if at < 0:
            return None
        at += len(b"dataWindow\x00box2i\x00") + 4
        return data[:at] + struct.pack("<iiii", 0, 0, width - 1, height - 1) + data[at + 16:]
    return None


def _jpeg_size(data: bytes, width: int, height: int) -> bytes | None:
    pos = 2
    while pos + 4 <= len(data) and data[pos] == 0xFF:
        marker, length = data[pos + 1], struct.unpack(">H", data[pos + 2:pos + 4])[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            size = struct.pack(">HH", min(height, 65535), min(width, 65535))
            return data[:pos + 5] + size + data[pos + 9:]
        pos += 2 + length
    return None


def _tiff_size(data: bytes, width: int, height: int) -> bytes:
    changed = bytearray(data)
    ifd = struct.unpack("<I", data[4:8])[0]
    for i in range(struct.unpack("<H", data[ifd:ifd + 2])[0]):
        at = ifd + 2 + 12 * i
        tag, kind = struct.unpack("<HH", data[at:at + 4])
        if tag in (256, 257):
            value = width if tag == 256 else height
            value_field = struct.pack("<I", value) if kind == 4 else struct.pack("<HH", min(value, 65535), 0)
            changed[at + 8:at + 12] = value_field
    return bytes(changed)


# -- mutations of the image ---------------------------------------------------------------------------

def _resized(linear: np.ndarray, height: int, width: int) -> np.ndarray:
    rows = np.arange(height) * linear.shape[0] // max(height, 1)
    cols = np.arange(width) * linear.shape[1] // max(width, 1)
    return linear[rows][:, cols]


def _small(linear, encoding, rng):
    shape = ((1, 1), (1, 96), (96, 1), (2, 2), (8, 8))[int(rng.integers(5))]
    if rng.random() < 0.4:
        side = int(rng.integers(9, FILM))
        shape = (side, side)
    expect = REFUSE if min(shape) < FILM / 2 else EITHER  # under half the working size: too small
    return f"{shape[1]} x {shape[0]} pixels", expect, _resized(linear, *shape)


def _constant(linear, encoding, rng):
    value = float((0.0, 1.0, 0.5, 0.2)[int(rng.integers(4))])
    return f"every pixel {value}", REFUSE, np.full_like(linear, value)


def _non_finite(linear, encoding, rng):
    """NaN, infinite, negative or huge values at a few pixels (or every pixel) of a float photo."""
    if encoding not in _FLOAT_FORMATS:
        return None
    value = float((np.nan, np.inf, -np.inf, -0.5, 1e30)[int(rng.integers(5))])
    count = int(rng.choice([1, 3, 300, linear.shape[0] * linear.shape[1]]))
    out = linear.copy().reshape(-1, 3)
    where = rng.choice(out.shape[0], count, replace=False)
    out[where, int(rng.integers(3))] = value
    expect = REFUSE if not np.isfinite(value) else EITHER  # negatives are clipped at 0, huge values scaled
    return f"{count} pixel(s) set to {value}", expect, out.reshape(linear.shape)


BYTE_MUTATIONS = {"truncate": _truncate, "bit-flips": _bit_flips, "overwrite": _overwrite, "magic": _wrong_magic,
                  "append": _appended, "bomb": _bomb, "zero-size": _zero_size}
IMAGE_MUTATIONS = {"small": _small, "constant": _constant, "non-finite": _non_finite}
PAIR_MUTATIONS = ("same-file", "same-pixels", "swapped")
MUTATIONS = (*BYTE_MUTATIONS, *IMAGE_MUTATIONS, *PAIR_MUTATIONS)


def photo_cases(count: int, seed: int = 0) -> list[Case]:
    """``count`` photo cases, the same for the same seed: mutation and format in turn, the details drawn."""
    pair = base_pair()
    encoded = {name: (suffix, encode(pair[0]), encode(pair[1])) for name, (suffix, encode) in ENCODINGS.items()}
    names = list(ENCODINGS)
    cases = []
    for index in range(count):
        rng = np.random.default_rng((seed, index))
        mutation = MUTATIONS[index % len(MUTATIONS)]
        encoding = names[(index // len(MUTATIONS) + int(rng.integers(len(names)))) % len(names)]
        case = _photo_case(mutation, encoding, encoded[encoding], pair, rng)
        while case is None:  # a mutation that does not apply to the format: another format
            encoding = names[int(rng.integers(len(names)))]
            case = _photo_case(mutation, encoding, encoded[encoding], pair, rng)
        cases.append(case)
    return cases


def _photo_case(mutation, encoding, encoded, pair, rng) -> Case | None:
    suffix, reflection, transmission = encoded
    names = (f"cloth_R{suffix}", f"cloth_T{suffix}")
    side = int(rng.integers(2))
    files = [reflection, transmission]
    if mutation in BYTE_MUTATIONS:
        made = BYTE_MUTATIONS[mutation](files[side], encoding, rng)
        if made is None:
            return None
        files[side], label, expect = made.data, made.label, made.expect
    elif mutation in IMAGE_MUTATIONS:
        made = IMAGE_MUTATIONS[mutation](pair[side], encoding, rng)
        if made is None:
            return None
        label, expect, image = made
        files[side] = ENCODINGS[encoding][1](image)
        if mutation == "small":  # both photos: one small photo alone is a pair of two sizes
            files[1 - side] = ENCODINGS[encoding][1](_resized(pair[1 - side], *image.shape[:2]))
            side = None
    else:
        label, expect, files, names = _pair_mutation(mutation, encoding, files, names, pair, rng)
        side = None
    which = "" if side is None else (" (reflection)", " (transmission)")[side]
    suspects = names if side is None else (names[side],)
    if mutation == "non-finite" and expect == EITHER:  # a linear pair shares one exposure: the other may go black
        suspects = names
    command = ("fit", f"{{dir}}/{names[0]}", f"{{dir}}/{names[1]}", "--out", "{dir}/out", "--rig", "{dir}/rig.json",
               "--json-progress")
    rig = f'{{"film_size": {FILM}}}'.encode()
    return Case("photo", f"{encoding} {mutation}: {label}{which}", (*zip(names, files), ("rig.json", rig)),
                command, suspects, expect, loader=names)


def _pair_mutation(mutation, encoding, files, names, pair, rng):
    if mutation == "same-file":
        first = int(rng.integers(2))
        return "one photo given twice", REFUSE, [files[first], files[first]], names
    if mutation == "same-pixels":  # the same pixels in two files that differ (8-bit PNG and TIFF hold them exactly)
        first = int(rng.integers(2))
        png, tiff = ENCODINGS["png8"][1](pair[first]), ENCODINGS["tiff8"][1](pair[first])
        return "the same pixels as PNG and TIFF", REFUSE, [png, tiff], ("cloth_R.png", "cloth_T.tif")
    return "the photos swapped", EITHER, files[::-1], names

