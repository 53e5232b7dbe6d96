"""Photo input (backend/image): formats, RAW decoding, crop/resize, flat-field, errors, pair checks, spectrum.

Test images are written here, in tmp dirs. The swap check is also run on the real photo pairs and the
golden renders in ../shared (CI has it beside the checkout; where it is missing those tests fail
and say where it should be) and on a fresh render of the forward model.
"""
from __future__ import annotations

import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import rawpy
import torch
from conftest import ROOT, SHARED, golden_case_names, require_path

from backend.core.params import load_params
from backend.image import metrics, pair_checks
from backend.image.containers import apply_orientation
from backend.image.pair_checks import (
    check_order,
    check_weave_shown,
    lattice_match,
    order_cues,
    same_lattice_score,
    with_lattice_combinations,
)
from backend.image.photos import PhotoError, load_pair, load_photo, read_image
from backend.image.spectrum import windowed_highpass
from backend.image.tone import luminance
from backend.model.render import render_pair

REAL = SHARED / "data" / "real"
GOLDEN = SHARED / "data" / "golden"
REAL_PAIRS = ("satin1", "twill1", "twill2")
EXR_SWITCH = "OPENCV_IO_ENABLE_OPENEXR"


# -- helpers --------------------------------------------------------------------------------------

def write(path: Path, rgb: np.ndarray) -> Path:
    """Writes an RGB array (uint8/uint16/float32) with OpenCV, which wants BGR.

    TIFFs are written uncompressed: OpenCV would store float TIFFs as lossy SGI LogLuv. OpenCV's
    EXR codec is off unless OPENCV_IO_ENABLE_OPENEXR is set before its first use, for writing too.
    """
    if path.suffix == ".exr":
        os.environ.setdefault(EXR_SWITCH, "1")
    data = rgb[..., ::-1] if rgb.ndim == 3 else rgb
    options = [cv2.IMWRITE_TIFF_COMPRESSION, 1] if path.suffix == ".tif" else []
    assert cv2.imwrite(str(path), np.ascontiguousarray(data), options), path
    return path


def random_rgb(shape, dtype=np.uint8, seed=0) -> np.ndarray:
    top = np.iinfo(dtype).max
    return np.random.default_rng(seed).integers(0, top + 1, size=shape, dtype=np.int64).astype(dtype)


def blocks(height: int, width: int, cell: int = 16) -> np.ndarray:
    """An asymmetric 8-bit pattern of flat colour blocks (JPEG keeps flat blocks nearly exact)."""
    rows, cols = np.arange(height)[:, None] // cell, np.arange(width)[None, :] // cell
    rows, cols = np.broadcast_arrays(rows, cols)
    rgb = np.stack([(rows * 37 + cols * 11) % 200, (rows * 7 + cols * 53) % 200, (rows * 91) % 200], axis=2)
    return (rgb + 30).astype(np.uint8)


def exif_app1(orientation: int) -> bytes:
    """A minimal JPEG APP1 Exif segment: a little-endian TIFF header and one IFD0 entry, Orientation."""
    ifd = struct.pack("<H", 1) + struct.pack("<HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack("<I", 0)
    payload = b"Exif\x00\x00" + b"II*\x00" + struct.pack("<I", 8) + ifd
    return b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload


def jpeg_with_orientation(path: Path, rgb: np.ndarray, orientation: int) -> Path:
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 98])
    assert ok
    data = data.tobytes()
    path.write_bytes(data[:2] + exif_app1(orientation) + data[2:])  # right after SOI
    return path


def tiff_bytes(rgb: np.ndarray, orientation: int = 1) -> bytes:
    """A minimal uncompressed little-endian RGB TIFF (8 or 16 bits) with an Orientation tag."""
    height, width, _ = rgb.shape
    bits = rgb.dtype.itemsize * 8
    pixels = np.ascontiguousarray(rgb.astype(rgb.dtype.newbyteorder("<"))).tobytes()
    tags = [(256, 4, 1, width), (257, 4, 1, height), (258, 3, 3, None), (259, 3, 1, 1), (262, 3, 1, 2),
            (273, 4, 1, None), (274, 3, 1, orientation), (277, 3, 1, 3), (278, 4, 1, height),
            (279, 4, 1, len(pixels)), (284, 3, 1, 1)]
    ifd_offset = 8
    ifd_size = 2 + 12 * len(tags) + 4
    bits_offset = ifd_offset + ifd_size
    data_offset = bits_offset + 6
    entries = b""
    for tag, kind, count, value in tags:
        if tag == 258:
            value_field = struct.pack("<I", bits_offset)
        elif tag == 273:
            value_field = struct.pack("<I", data_offset)
        elif kind == 3:
            value_field = struct.pack("<HH", value, 0)
        else:
            value_field = struct.pack("<I", value)
        entries += struct.pack("<HHI", tag, kind, count) + value_field
    header = b"II*\x00" + struct.pack("<I", ifd_offset)
    ifd = struct.pack("<H", len(tags)) + entries + struct.pack("<I", 0)
    return header + ifd + struct.pack("<HHH", bits, bits, bits) + pixels


def encoded(linear: np.ndarray) -> np.ndarray:
    return np.clip(linear, 0, 1) ** (1 / 2.2)


def as_linear(image: np.ndarray) -> np.ndarray:
    return np.asarray(image, dtype=np.float64) ** 2.2


ORIENTED = {  # EXIF orientation -> the upright image, as exiftool describes the display operation
    1: lambda a: a,
    2: lambda a: a[:, ::-1],  # mirror horizontal
    3: lambda a: np.rot90(a, 2),  # rotate 180
    4: lambda a: a[::-1],  # mirror vertical
    5: lambda a: np.rot90(a[:, ::-1], 1),  # mirror horizontal and rotate 270 CW
    6: lambda a: np.rot90(a, -1),  # rotate 90 CW
    7: lambda a: np.rot90(a[:, ::-1], -1),  # mirror horizontal and rotate 90 CW
    8: lambda a: np.rot90(a, 1),  # rotate 270 CW
}


# -- formats --------------------------------------------------------------------------------------

@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_png_8_and_16_bit_are_taken_as_encoded(tmp_path, dtype):
    rgb = random_rgb((48, 48, 3), dtype)
    photo = load_photo(write(tmp_path / "p.png", rgb), size=48)
    assert photo.image.dtype == np.float32 and photo.image.shape == (48, 48, 3)
    np.testing.assert_allclose(photo.image, rgb / np.iinfo(dtype).max, atol=1e-5)
    assert photo.format == f"png {'8' if dtype == np.uint8 else '16'}-bit"
    assert photo.exposure is None


def test_alpha_is_dropped_and_grey_expanded(tmp_path):
    rgba = random_rgb((32, 32, 4), seed=1)
    assert cv2.imwrite(str(tmp_path / "rgba.png"), np.ascontiguousarray(rgba[..., [2, 1, 0, 3]]))  # cv2: BGRA
    photo = load_photo(tmp_path / "rgba.png", size=32)
    np.testing.assert_allclose(photo.image, rgba[..., :3] / 255, atol=1e-5)
    grey = random_rgb((32, 32), seed=2)
    photo = load_photo(write(tmp_path / "grey.png", grey), size=32)
    for channel in range(3):
        np.testing.assert_allclose(photo.image[..., channel], grey / 255, atol=1e-5)


@pytest.mark.parametrize("orientation", [1, 3, 6, 8])
def test_jpeg_exif_orientation_is_applied(tmp_path, orientation):
    stored = blocks(64, 96)
    source = read_image(jpeg_with_orientation(tmp_path / "o.jpg", stored, orientation))
    upright = ORIENTED[orientation](stored)
    assert source.pixels.shape == upright.shape
    assert np.abs(source.pixels.astype(int) - upright).mean() < 3  # JPEG loss only


def test_crop_box_is_in_upright_pixels(tmp_path):
    stored = blocks(64, 96)  # a landscape sensor image, stored with "rotate 90 CW" (a portrait photo)
    path = jpeg_with_orientation(tmp_path / "portrait.jpg", stored, 6)
    photo = load_photo(path, size=64)
    assert photo.source_size == (64, 96) and photo.crop == (0, 16, 64, 64)
    upright = np.rot90(stored, -1)[16:80]
    assert np.abs(photo.image * 255 - upright).mean() < 3
    boxed = load_photo(path, size=32, crop=(32, 64, 32, 32))
    assert np.abs(boxed.image * 255 - np.rot90(stored, -1)[64:96, 32:64]).mean() < 3


@pytest.mark.parametrize("orientation", [2, 4, 5, 7])
def test_every_mirrored_orientation_is_applied(orientation):
    stored = blocks(8, 12, cell=1)
    np.testing.assert_array_equal(apply_orientation(stored, orientation), ORIENTED[orientation](stored))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_tiff_8_and_16_bit(tmp_path, dtype):
    rgb = random_rgb((40, 40, 3), dtype, seed=3)
    photo = load_photo(write(tmp_path / "t.tif", rgb), size=40)
    np.testing.assert_allclose(photo.image, rgb / np.iinfo(dtype).max, atol=1e-5)
    assert photo.format.startswith("tiff")


@pytest.mark.parametrize("orientation", range(1, 9))
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_tiff_orientation_tag_is_applied_once(tmp_path, dtype, orientation):
    """OpenCV's TIFF decoder applies the tag itself (unlike its JPEG and PNG decoders): not twice."""
    stored = random_rgb((20, 30, 3), dtype, seed=4)
    path = tmp_path / "o.tif"
    path.write_bytes(tiff_bytes(stored, orientation))
    np.testing.assert_array_equal(read_image(path).pixels, ORIENTED[orientation](stored))


def test_png_exif_orientation_is_applied(tmp_path):
    stored = random_rgb((20, 30, 3), seed=16)
    ok, data = cv2.imencode(".png", np.ascontiguousarray(stored[..., ::-1]))
    data = data.tobytes()
    exif = exif_app1(6)[10:]  # the TIFF structure inside the APP1 segment
    chunk = struct.pack(">I", len(exif)) + b"eXIf" + exif + struct.pack(">I", zlib.crc32(b"eXIf" + exif))
    at = data.index(b"IDAT") - 4
    (tmp_path / "o.png").write_bytes(data[:at] + chunk + data[at:])
    np.testing.assert_array_equal(read_image(tmp_path / "o.png").pixels, np.rot90(stored, -1))


def test_exr_is_linear_and_encoded_with_the_render_curve(tmp_path):
    rng = np.random.default_rng(5)
    linear = rng.uniform(0, 1.5, size=(32, 32, 3)).astype(np.float32)
    write(tmp_path / "l.exr", linear)
    photo = load_photo(tmp_path / "l.exr", size=32, exposure=0.5)
    np.testing.assert_allclose(photo.image, encoded(linear * 0.5), atol=1e-5)
    assert photo.exposure == 0.5 and photo.format == "exr float"


def test_exr_auto_exposure_puts_the_99th_percentile_at_half(tmp_path):
    rng = np.random.default_rng(6)
    linear = rng.uniform(0, 40.0, size=(64, 64, 3)).astype(np.float32)  # an HDR scale
    photo = load_photo(write(tmp_path / "hdr.exr", linear), size=64)
    lum = luminance(as_linear(photo.image).astype(np.float32))
    assert np.percentile(lum, 99) == pytest.approx(0.5, rel=1e-3)
    np.testing.assert_allclose(photo.image, encoded(linear * photo.exposure), atol=1e-5)


def test_exr_decodes_in_a_fresh_process_and_no_import_sets_the_environment(tmp_path):
    """OpenCV reads OPENCV_IO_ENABLE_OPENEXR once per process: here no test has set it before."""
    linear = np.random.default_rng(17).uniform(0, 1.5, size=(32, 32, 3)).astype(np.float32)
    write(tmp_path / "l.exr", linear)
    script = f"""
import os, sys
import numpy as np
import backend.image.camera_blur, backend.image.metrics, backend.image.photos, backend.image.png
assert "{EXR_SWITCH}" not in os.environ, "importing the image package set {EXR_SWITCH}"
photo = backend.image.photos.load_photo(sys.argv[1], size=32, exposure=0.5)
np.save(sys.argv[2], photo.image)
"""
    env = {k: v for k, v in os.environ.items() if k != EXR_SWITCH}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + [p for p in [env.get("PYTHONPATH")] if p])
    done = subprocess.run([sys.executable, "-c", script, str(tmp_path / "l.exr"), str(tmp_path / "out.npy")],
                          cwd=ROOT, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    np.testing.assert_allclose(np.load(tmp_path / "out.npy"), encoded(linear * 0.5), atol=1e-5)


def test_float_tiff_is_treated_as_linear(tmp_path):
    linear = np.random.default_rng(7).uniform(0, 1, size=(24, 24, 3)).astype(np.float32)
    photo = load_photo(write(tmp_path / "f.tif", linear), size=24, exposure=1.0)
    np.testing.assert_allclose(photo.image, encoded(linear), atol=1e-5)


def test_linear_pair_keeps_its_relative_brightness(tmp_path):
    """One exposure for both photos: a transmission 4x darker stays 4x darker."""
    rng = np.random.default_rng(8)
    yarns = 1 + 0.5 * np.sin(2 * np.pi * 20 * np.arange(64) / 64)[None, :, None]  # a weave, or the pair is refused
    reflection = (rng.uniform(0.1, 3.0, size=(64, 64, 3)) * yarns).astype(np.float32)
    transmission = reflection / 4
    pair = load_pair(write(tmp_path / "r.exr", reflection), write(tmp_path / "t.exr", transmission), size=64)
    assert pair.info["reflection"]["exposure"] == pair.info["transmission"]["exposure"]
    ratio = as_linear(pair.transmission).mean() / as_linear(pair.reflection).mean()
    assert ratio == pytest.approx(0.25, rel=1e-3)


# -- camera RAW ------------------------------------------------------------------------------------

class FakeRaw:
    """Stands in for rawpy.RawPy: records the postprocess arguments, returns a known 16-bit image."""

    def __init__(self, result):
        self.result, self.kwargs = result, None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def postprocess(self, params=None, **kwargs):
        self.kwargs = kwargs
        return self.result


def test_raw_is_decoded_linearly_through_rawpy(tmp_path, monkeypatch):
    linear16 = random_rgb((40, 40, 3), np.uint16, seed=9)
    fake = FakeRaw(linear16)
    opened = []
    monkeypatch.setattr(rawpy, "imread", lambda path: opened.append(path) or fake)
    path = tmp_path / "IMG_0001.CR2"
    path.write_bytes(b"not really raw")
    photo = load_photo(path, size=40, exposure=2.0)
    assert opened == [str(path)]
    kwargs = fake.kwargs
    assert kwargs["gamma"] == (1, 1)
    assert kwargs["no_auto_bright"] is True
    assert kwargs["output_bps"] == 16
    assert kwargs["use_camera_wb"] is True and not kwargs.get("use_auto_wb", False)
    assert kwargs["output_color"] == rawpy.ColorSpace.sRGB
    np.testing.assert_allclose(photo.image, encoded(linear16 / 65535 * 2.0), atol=1e-5)
    assert photo.format == "camera raw"


def test_raw_decoder_failure_is_a_photo_error(tmp_path, monkeypatch):

    def broken(path):
        raise rawpy.LibRawIOError("Input/output error")

    monkeypatch.setattr(rawpy, "imread", broken)
    path = tmp_path / "cut.nef"
    path.write_bytes(b"\x00" * 100)
    with pytest.raises(PhotoError, match=r"cut\.nef: could not be decoded as camera RAW \(LibRawIOError"):
        load_photo(path)


def test_garbage_raw_file_is_a_photo_error_with_the_real_decoder(tmp_path):
    path = tmp_path / "garbage.dng"
    path.write_bytes(b"this is not a DNG file at all" * 10)
    with pytest.raises(PhotoError, match=r"garbage\.dng: could not be decoded as camera RAW"):
        load_photo(path)


# -- crop, resize, flat-field ------------------------------------------------------------------------

def test_centre_crop_of_a_wide_image(tmp_path):
    rgb = random_rgb((60, 100, 3), seed=10)
    photo = load_photo(write(tmp_path / "wide.png", rgb), size=60)
    assert photo.crop == (20, 0, 60, 60) and photo.source_size == (100, 60)
    np.testing.assert_allclose(photo.image, rgb[:, 20:80] / 255, atol=1e-5)


def test_explicit_crop_box(tmp_path):
    rgb = random_rgb((80, 90, 3), seed=11)
    photo = load_photo(write(tmp_path / "box.png", rgb), size=40, crop=(10, 5, 40, 40))
    np.testing.assert_allclose(photo.image, rgb[5:45, 10:50] / 255, atol=1e-5)


def test_shrinking_averages_areas_in_linear_light(tmp_path):
    checker = ((np.indices((64, 64)).sum(axis=0) % 2) * 255).astype(np.uint8)
    photo = load_photo(write(tmp_path / "checker.png", np.repeat(checker[..., None], 3, axis=2)), size=32)
    # every output pixel is half black, half white: 0.5 in linear light, 0.5 ** (1 / 2.2) encoded
    np.testing.assert_allclose(photo.image, 0.5 ** (1 / 2.2), atol=1e-4)


def test_small_crop_is_upscaled_with_a_warning(tmp_path):
    photo = load_photo(write(tmp_path / "small.png", random_rgb((40, 40, 3))), size=64)
    assert photo.image.shape == (64, 64, 3)
    assert len(photo.warnings) == 1 and "small.png" in photo.warnings[0] and "upscaled" in photo.warnings[0]


def test_large_enough_crop_has_no_warning(tmp_path):
    assert load_photo(write(tmp_path / "ok.png", random_rgb((64, 64, 3))), size=64).warnings == []


def vignette(n: int, strength: float = 0.5) -> np.ndarray:
    yy, xx = np.mgrid[0:n, 0:n] + 0.5
    radius2 = ((yy - n / 2) ** 2 + (xx - n / 2) ** 2) / (n / 2) ** 2
    return (1 - strength * radius2 / 2)[..., None] * np.ones(3)


def test_flat_field_divides_out_vignetting(tmp_path):
    n = 96
    rng = np.random.default_rng(12)
    scene = 0.3 * vignette(n)
    target = np.clip(0.6 * vignette(n) * (1 + 0.05 * rng.standard_normal((n, n, 3))), 0, 1)  # noisy target
    photo_path = write(tmp_path / "photo.png", (encoded(scene) * 65535).round().astype(np.uint16))
    flat_path = write(tmp_path / "flat.png", (encoded(target) * 65535).round().astype(np.uint16))
    before = as_linear(load_photo(photo_path, size=n).image)
    after = as_linear(load_photo(photo_path, size=n, flat_field=flat_path).image)
    assert before[n // 2, n // 2, 1] / before[2, 2, 1] > 1.5  # corners much darker before
    assert after[6:-6, 6:-6].std() / after[6:-6, 6:-6].mean() < 0.03  # flat after (smoothed, noise gone)
    assert np.all(np.isfinite(after)) and after.max() <= 1.0


def test_flat_field_guards_against_division_by_zero(tmp_path):
    n = 64
    target = np.full((n, n, 3), 0.8)
    target[:, : n // 3] = 0.0  # a third of the target is black
    photo_path = write(tmp_path / "photo.png", random_rgb((n, n, 3), seed=13))
    flat_path = write(tmp_path / "flat.png", (encoded(target) * 255).round().astype(np.uint8))
    photo = load_photo(photo_path, size=n, flat_field=flat_path)
    assert np.all(np.isfinite(photo.image)) and photo.image.min() >= 0 and photo.image.max() <= 1
    assert any("flat.png" in w and "falls below 5%" in w for w in photo.warnings)


def test_flat_field_of_another_size_is_refused(tmp_path):
    photo_path = write(tmp_path / "photo.png", random_rgb((64, 64, 3)))
    flat_path = write(tmp_path / "flat.png", random_rgb((64, 80, 3)))
    with pytest.raises(PhotoError, match=r"flat\.png: the flat-field is 80 x 64 pixels but the photo .*photo\.png"):
        load_photo(photo_path, size=64, flat_field=flat_path)


def test_black_flat_field_is_refused(tmp_path):
    photo_path = write(tmp_path / "photo.png", random_rgb((64, 64, 3)))
    flat_path = write(tmp_path / "black.png", np.zeros((64, 64, 3), np.uint8))
    with pytest.raises(PhotoError, match=r"black\.png: the flat-field image is black"):
        load_photo(photo_path, size=64, flat_field=flat_path)


# -- errors --------------------------------------------------------------------------------------------

def test_missing_file(tmp_path):
    with pytest.raises(PhotoError, match=r"nowhere\.png: file not found"):
        load_photo(tmp_path / "nowhere.png")


def test_empty_file(tmp_path):
    (tmp_path / "empty.jpg").write_bytes(b"")
    with pytest.raises(PhotoError, match=r"empty\.jpg: the file is empty"):
        load_photo(tmp_path / "empty.jpg")


def test_unsupported_file(tmp_path):
    (tmp_path / "notes.png").write_text("hello, not an image")
    with pytest.raises(PhotoError, match=r"notes\.png: unsupported file format \(expected PNG, JPEG"):
        load_photo(tmp_path / "notes.png")


def test_heic_is_named_in_the_error(tmp_path):
    (tmp_path / "IMG_1.HEIC").write_bytes(b"\x00\x00\x00\x18ftypheic" + b"\x00" * 64)
    with pytest.raises(PhotoError, match=r"IMG_1\.HEIC: unsupported file format \(HEIC/HEIF/AVIF: export"):
        load_photo(tmp_path / "IMG_1.HEIC")


@pytest.mark.parametrize("suffix", [".jpg", ".png", ".tif"])
def test_truncated_files(tmp_path, suffix):
    whole = tmp_path / f"whole{suffix}"
    write(whole, random_rgb((64, 64, 3), seed=14))
    data = whole.read_bytes()
    cut = tmp_path / f"cut{suffix}"
    cut.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(PhotoError, match=rf"cut\{suffix}: the file is truncated"):
        load_photo(cut, size=64)
    load_photo(whole, size=64)  # the whole file is fine


def test_jpeg_with_bytes_after_the_end_marker_is_fine(tmp_path):
    path = write(tmp_path / "x.jpg", blocks(64, 64))
    path.write_bytes(path.read_bytes() + b"trailing data some phones append")
    assert load_photo(path, size=64).image.shape == (64, 64, 3)


def test_corrupt_png_data_is_a_photo_error(tmp_path):
    path = write(tmp_path / "bad.png", random_rgb((64, 64, 3), seed=15))
    data = bytearray(path.read_bytes())
    start = data.index(b"IDAT") + 4
    data[start + 10:start + 60] = b"\x00" * 50  # same length, broken deflate stream and CRC
    path.write_bytes(bytes(data))
    with pytest.raises(PhotoError, match=r"bad\.png: could not be decoded as PNG"):
        load_photo(path, size=64)


def test_image_too_small(tmp_path):
    path = write(tmp_path / "tiny.png", random_rgb((100, 300, 3)))
    with pytest.raises(PhotoError, match=r"tiny\.png: image too small: the square crop is 100 x 100 pixels, at "
                                         r"least 256 are needed for a 512 x 512"):
        load_photo(path)


@pytest.mark.parametrize("box, problem", [
    ((50, 0, 64, 64), "lies outside the 100 x 80 image"),
    ((0, 20, 64, 64), "lies outside the 100 x 80 image"),
    ((-1, 0, 64, 64), "lies outside the 100 x 80 image"),
    ((0, 0, 64, 48), "is not square"),
    ((0, 0, 0, 0), "has no area"),
    ((0, 0, 64), "must be four whole numbers"),
    ((0.5, 0, 64, 64), "must be four whole numbers"),
])
def test_bad_crop_boxes(tmp_path, box, problem):
    path = write(tmp_path / "frame.png", random_rgb((80, 100, 3)))
    with pytest.raises(PhotoError, match=r"frame\.png: crop box") as error:
        load_photo(path, size=64, crop=box)
    assert problem in str(error.value)


def test_tiff_directory_beyond_the_end_is_truncated(tmp_path):
    (tmp_path / "x.tif").write_bytes(b"II*\x00" + b"\xff" * 4)
    with pytest.raises(PhotoError, match=r"x\.tif: the file is truncated \(the TIFF directory"):
        load_photo(tmp_path / "x.tif")


# -- pair checks: synthetic pairs -------------------------------------------------------------------

def fabric(n: int, scale: float = 1.0, seed: int = 0) -> np.ndarray:
    """A woven-looking texture in [0.25, 1]: a lattice of cosines (cycles per image) plus a little noise."""
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5) / n
    lattice = ((37, 0), (0, 53), (37, 53))
    waves = sum(np.cos(2 * np.pi * scale * (fx * xx + fy * yy)) for fx, fy in lattice) / len(lattice)
    noise = 0.03 * np.random.default_rng(seed).standard_normal((n, n))
    return np.clip(0.6 + 0.35 * waves + noise, 0.05, 1)[..., None] * np.array([0.9, 0.8, 0.6])


def front_lit(n: int) -> np.ndarray:
    """Irradiance of a point light above the top edge (rig geometry in image-width units)."""
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5) / n
    return (2.25 / ((xx - 0.5) ** 2 + (yy + 1) ** 2 + 1))[..., None]


def back_lit(n: int) -> np.ndarray:
    """Irradiance of a point light behind the centre, plus a centred glow."""
    yy, xx = (np.mgrid[0:n, 0:n] + 0.5) / n
    radius2 = (xx - 0.5) ** 2 + (yy - 0.5) ** 2
    return (1 / (1 + radius2 / 0.6) + 0.5 * np.exp(-radius2 / 0.01))[..., None]


def synthetic_pair(tmp_path: Path, n: int = 256, transmission_scale: float = 1.0) -> tuple[Path, Path]:
    reflection = 0.5 * fabric(n, seed=1) * front_lit(n)
    transmission = 0.4 * fabric(n, transmission_scale, seed=2) * back_lit(n)
    to16 = lambda linear: (encoded(linear) * 65535).round().astype(np.uint16)  # noqa: E731
    return write(tmp_path / "fab_R.png", to16(reflection)), write(tmp_path / "fab_T.png", to16(transmission))


def test_synthetic_pair_in_order_passes(tmp_path):
    r, t = synthetic_pair(tmp_path)
    pair = load_pair(r, t, size=256, strict=True)
    assert pair.warnings == []
    assert pair.reflection.shape == pair.transmission.shape == (256, 256, 3)
    assert pair.info["reflection"]["source_size"] == [256, 256]
    assert pair.info["order"]["score"] > 0.5
    assert pair.info["yarn_frequency"]["mismatch"] < 0.02


def test_synthetic_pair_swapped_is_flagged_or_refused(tmp_path):
    r, t = synthetic_pair(tmp_path)
    pair = load_pair(t, r, size=256)
    [warning] = pair.warnings
    assert "fab_T.png / " in warning and "may be swapped" in warning
    assert "brighter at the top" in warning and "opposite order" in warning
    with pytest.raises(PhotoError, match=r"fab_T\.png / .*fab_R\.png: the photos may be swapped"):
        load_pair(t, r, size=256, strict=True)


def test_pair_of_different_sizes_is_refused(tmp_path):
    r = write(tmp_path / "a_R.png", random_rgb((300, 400, 3)))
    t = write(tmp_path / "a_T.png", random_rgb((400, 300, 3)))
    with pytest.raises(PhotoError, match=r"a_R\.png / .*a_T\.png: the photos are framed differently: 400 x 300 vs "
                                         r"300 x 400 pixels"):
        load_pair(r, t, size=256)


def test_pair_framed_at_another_scale_is_refused(tmp_path):
    r, t = synthetic_pair(tmp_path, transmission_scale=1 / 1.4)  # transmission zoomed in 1.4x
    with pytest.raises(PhotoError, match=r"framed differently: the transmission photo's yarn lattice matches the "
                                         r"reflection's magnified 1\.4\dx \(3 matching peaks;"):
        load_pair(r, t, size=256)


def test_pair_framed_at_a_slightly_different_scale_is_a_warning(tmp_path):
    r, t = synthetic_pair(tmp_path, transmission_scale=1 / 1.1)
    pair = load_pair(r, t, size=256)
    warning, registered = pair.warnings  # the framing check's doubt, then what registration did about it
    assert "magnified 1.1" in warning and "slightly different scales" in warning
    assert pair.info["yarn_frequency"]["scale"] == pytest.approx(1.1, rel=0.03)
    assert "the reflection photo was magnified 1.1" in registered
    assert pair.info["registration"]["magnification"] == pytest.approx(1.1, rel=0.01)


def test_a_pair_without_any_yarn_pattern_is_refused_and_one_without_is_a_warning(tmp_path):
    n = 256
    flat = np.ones((n, n, 3)) * np.array([0.8, 0.7, 0.6])
    noise = np.random.default_rng(3).normal(0.0, 0.004, (n, n, 3))  # a camera's noise, no yarns
    to16 = lambda linear: (encoded(np.clip(linear, 0, 1)) * 65535).round().astype(np.uint16)  # noqa: E731
    r = write(tmp_path / "plain_R.png", to16(0.4 * flat * front_lit(n) + noise))
    t = write(tmp_path / "plain_T.png", to16(0.4 * flat * back_lit(n) + noise))
    with pytest.raises(PhotoError, match="plain_R.png / .*plain_T.png: neither photo shows a yarn pattern"):
        load_pair(r, t, size=n)
    textured, _ = synthetic_pair(tmp_path, n)
    pair = load_pair(textured, t, size=n)
    [warning] = pair.warnings
    assert warning.startswith(f"{t}: shows no yarn pattern above the noise (sharpest spectral peak ")
    assert warning.endswith(f"read from {textured} alone, and the framing check was skipped")
    assert pair.info["weave_peakness"]["transmission"] < pair.info["weave_peakness"]["noise_level"]
    assert pair.info["weave_peakness"]["reflection"] > pair.info["weave_peakness"]["noise_level"]
    assert pair.info["yarn_frequency"]["scale"] is None  # nothing compared, nothing registered
    # neither photo above the noise (each alone passes the content checks): the lattice is a guess
    noisy = np.clip(0.5 + noise, 0, 1)
    [warning], info = check_weave_shown(noisy, noisy[::-1], (Path("a_R.png"), Path("a_T.png")))
    assert warning.startswith("a_R.png / a_T.png: neither photo shows its yarns above the noise")
    assert "photograph the fabric closer" in warning
    assert max(info["reflection"], info["transmission"]) < info["noise_level"]


@pytest.mark.parametrize("problem", ["black", "overexposed", "featureless"])
def test_a_black_overexposed_or_featureless_photo_is_refused_and_named(tmp_path, problem):
    r, t = synthetic_pair(tmp_path)
    value = {"black": 0, "overexposed": 65535, "featureless": 32768}[problem]
    bad = write(tmp_path / "bad_R.png", np.full((256, 256, 3), value, np.uint16))
    with pytest.raises(PhotoError, match=f"bad_R.png: the photo is {problem}"):
        load_pair(bad, t, size=128)


def test_a_flat_but_noisy_photo_is_not_featureless(tmp_path):
    """Sensor noise alone (1 % of the level, as a phone's at mid-grey) is something the featureless
    check lets through: its refusal is for images with nothing in them."""
    r, t = synthetic_pair(tmp_path)
    noisy = 0.5 * (1 + 0.01 * np.random.default_rng(3).standard_normal((256, 256, 1)))
    flat = write(tmp_path / "flat_R.png", (np.repeat(noisy, 3, axis=2) * 65535).round().astype(np.uint16))
    pair = load_pair(flat, t, size=128)
    assert pair.reflection.shape == (128, 128, 3)


def test_pair_shared_crop_and_flat_fields(tmp_path):
    r, t = synthetic_pair(tmp_path)
    flat = write(tmp_path / "flat.png", (encoded(0.7 * vignette(256)) * 65535).round().astype(np.uint16))
    pair = load_pair(r, t, size=128, crop=(64, 64, 128, 128), flat_field=(None, flat))
    assert pair.info["transmission"]["crop"] == [64, 64, 128, 128]
    plain = load_pair(r, t, size=128, crop=(64, 64, 128, 128))
    np.testing.assert_array_equal(pair.reflection, plain.reflection)  # no flat-field for the reflection
    assert not np.allclose(pair.transmission, plain.transmission)


# -- pair checks: real photos, golden renders, a fresh render -----------------------------------------

need = require_path  # the shared file, or a failure (see conftest)


@pytest.mark.parametrize("name", REAL_PAIRS)
def test_real_pairs_in_order_pass_the_swap_check(name):
    r, t = need(REAL / f"{name}_R.png"), need(REAL / f"{name}_T.png")
    pair = load_pair(r, t, strict=True)  # strict: a swap doubt would raise
    assert not any("swapped" in w for w in pair.warnings)
    assert pair.info["order"]["score"] > 0.5


@pytest.mark.parametrize("name", REAL_PAIRS)
def test_real_pairs_swapped_are_flagged(name):
    r, t = need(REAL / f"{name}_R.png"), need(REAL / f"{name}_T.png")
    pair = load_pair(t, r)
    assert any("may be swapped" in w and f"{name}_T.png" in w for w in pair.warnings)
    assert pair.info["order"]["score"] < -0.5
    with pytest.raises(PhotoError, match="may be swapped"):
        load_pair(t, r, strict=True)


@pytest.mark.parametrize("name", REAL_PAIRS)
def test_real_pairs_pass_the_framing_check(name):
    pair = load_pair(need(REAL / f"{name}_R.png"), need(REAL / f"{name}_T.png"))
    scale = pair.info["yarn_frequency"]["scale"]
    assert abs(np.log(scale)) < np.log(1.2)  # twill1's photos differ by about 15 %: a warning, not an error


@pytest.mark.parametrize("name", golden_case_names())
def test_golden_renders_swap_check(name):
    r, t = need(GOLDEN / f"{name}_R.png"), need(GOLDEN / f"{name}_T.png")
    cues_r = order_cues(load_photo(r).image)
    cues_t = order_cues(load_photo(t).image)
    assert check_order(cues_r, cues_t) == []
    swapped = check_order(cues_t, cues_r)
    assert len(swapped) == 3  # all three tests fire on the swapped order


def test_fresh_render_swap_check():
    """The forward model itself (spec example parameters, default rig), rendered small."""
    params = load_params("twill1_R_0.6,0.66_S_0.75,1.53_T_1.33,1.39_N_0.0_UV_121.8,168.9_Kd_0.456,0.398,0.089,"
                         "0.286,0.279,0.0_G_0.99,1.0_Rm_0.65,0.62_Tm_2.66,0.79_W_0.71,1.29_Ks_0.325,0.37,0.0,"
                         "0.351,0.883,0.0_Psi_-30.5,-29.5")
    with torch.no_grad():
        pair = render_pair(params, size=96, spp=1, seed=0)
    cues_r = order_cues(pair.reflection.numpy())
    cues_t = order_cues(pair.transmission.numpy())
    assert check_order(cues_r, cues_t) == []
    assert check_order(cues_t, cues_r) != []
    assert cues_r["top_bias"] > 0.5 and abs(cues_t["top_bias"]) < 0.1



# -- spectrum and metrics ---------------------------------------------------------------------------

def test_windowed_highpass_is_the_yarn_lattices_input():
    """Bit for bit texture/lattice.py's _highpassed_luminance (as of the layout change), sigma = N / 64."""
    rng = np.random.default_rng(18)
    for shape in ((96, 96, 3), (128, 80, 3)):
        for image in (rng.random(shape), rng.random(shape).astype(np.float32)):
            y = np.asarray(image, dtype=np.float64) @ np.array([0.2126, 0.7152, 0.0722])
            y = y - cv2.GaussianBlur(y, (0, 0), y.shape[0] / 64)
            expected = y * np.outer(np.hanning(y.shape[0]), np.hanning(y.shape[1]))
            got = windowed_highpass(image, image.shape[0] / 64)
            assert got.dtype == np.float64
            np.testing.assert_array_equal(got, expected)


def test_metrics_match_the_team_checker(shared_tools):
    """backend.image.metrics against shared/tools/imagemetrics.py, on a real photo and a changed copy."""
    sys.path.insert(0, str(shared_tools))
    try:
        import imagemetrics
    finally:
        sys.path.remove(str(shared_tools))
    photo = load_photo(need(REAL / "twill1_R.png")).image.astype(np.float64)
    render = np.clip(photo * 0.9 + 0.03, 0, 1)
    assert metrics.spectrum_corr(photo, render) == imagemetrics.spectrum_corr(photo, render)
    assert metrics.colour_l1(photo, render) == imagemetrics.downsample_l1(photo, render)
    assert metrics.flip(photo, render) == pytest.approx(imagemetrics.flip_mean(photo, render), rel=1e-6)


def seed_31_photo_like_pair(tmp_path, index: int):
    """Item ``index`` of the photo-like set of seed 31, made in ``tmp_path`` and loaded as the fit loads it."""
    from devtools.bench.photolike import make_item
    name = make_item(tmp_path, seed=31, index=index)["name"]
    return load_pair(tmp_path / f"{name}_R.png", tmp_path / f"{name}_T.png")


def test_a_photo_like_plain_weave_whose_reflection_shows_no_yarns_is_named_without_a_framing_doubt(tmp_path):
    # A dense plain weave (2-4 px per yarn) behind the phone's blur: the reflection's sharpest peak stays
    # under what noise alone shows. Its noise peaks were once matched to the transmission's at a chance
    # ratio (1.49x, one peak) and called a framing doubt; now the photo is named and nothing compared.
    pair = seed_31_photo_like_pair(tmp_path, 55)
    assert pair.info["weave_peakness"]["reflection"] < pair.info["weave_peakness"]["noise_level"]
    assert [w for w in pair.warnings if w.startswith(str(tmp_path / "plain_055_R.png"))] == [
        f"{tmp_path / 'plain_055_R.png'}: shows no yarn pattern above the noise (sharpest spectral peak "
        f"{pair.info['weave_peakness']['reflection']:.1f}; noise alone reaches 3.8): the yarn density and the "
        f"sample's turn are read from {tmp_path / 'plain_055_T.png'} alone, and the framing check was skipped"]
    assert not [w for w in pair.warnings if "framed" in w or "scales" in w], pair.warnings
    assert pair.info["yarn_frequency"]["scale"] is None


@pytest.mark.parametrize("index", [30, 35])
def test_photo_like_plain_weaves_showing_other_harmonics_of_their_lattice_pass_the_framing_check(tmp_path, index):
    # Seed 31's dense plain weaves: the reflection shows the checkerboard's diagonals, the transmission
    # the yarn gaps (their sum and difference) and aliased harmonics. They got "the yarn patterns share
    # no spectral peak" (30; also 80 and 100) or "magnified 0.50x, the evidence is weak" (35) for photos
    # of the same fabric, framed the same.
    pair = seed_31_photo_like_pair(tmp_path, index)
    assert pair.info["yarn_frequency"]["reflection"] and pair.info["yarn_frequency"]["transmission"]
    assert not [w for w in pair.warnings if "spectral peak" in w or "framed" in w or "scales" in w], pair.warnings


def test_the_framing_check_knows_a_lattice_by_its_other_harmonics():
    # A lattice of 40 x 30 cycles: the reflection shows (1, 1) and (-1, 1), the transmission (2, 0) and
    # (0, 2), the same lattice; a transmission framed 1.3x closer shows them at 1.3 times the frequency.
    reflection = [(40.0, 30.0, 1.0), (-40.0, 30.0, 0.8)]
    transmission = [(80.0, 0.0, 1.0), (0.0, 60.0, 0.7)]
    assert lattice_match(transmission, reflection, 1.0) == (0.0, 0)  # no peak in common
    assert same_lattice_score(reflection, transmission) == pytest.approx(0.8 + 0.7)
    assert same_lattice_score(transmission, reflection) == pytest.approx(0.8 + 0.7)
    closer = [(1.3 * fx, 1.3 * fy, power) for fx, fy, power in transmission]
    assert same_lattice_score(reflection, closer) == 0.0
    assert with_lattice_combinations(reflection[:1]) == reflection[:1]  # one peak: no second direction
    parallel = [(40.0, 30.0, 1.0), (80.5, 60.0, 0.5)]  # a harmonic of the first: not a second direction
    assert with_lattice_combinations(parallel) == parallel


@pytest.mark.parametrize("matching", [2, 3])
def test_a_framing_ratio_is_refused_only_where_three_peaks_agree_on_it(monkeypatch, matching):
    """Two peaks agreeing on a ratio far from 1 can be a harmonic of the lattice moved with the phone
    (photo-like seed 137 --moved plain_005: 0.54x = 0.5 x its 1.076x move): a warning. Three are a
    framing the same stand cannot give: refused."""
    reflection = [(80.0, 60.0, 1.0), (-60.0, 80.0, 0.8), (0.0, 150.0, 0.6)][:matching]
    transmission = [(fx / 1.4, fy / 1.4, power) for fx, fy, power in reflection]
    monkeypatch.setattr(pair_checks, "yarn_peaks", lambda image: reflection if image == "R" else transmission)
    names = (Path("a_R.png"), Path("a_T.png"))
    if matching < pair_checks.REFUSE_MATCHES:
        [warning], info = pair_checks.check_framing_frequency("R", "T", names)
        assert "magnified 1.40x (2 matching peaks" in warning and "the evidence is weak" in warning
        assert info["scale"] == pytest.approx(1.4)
    else:
        with pytest.raises(PhotoError, match=r"a_R\.png / a_T\.png: the photos are framed differently: .* "
                                             r"magnified 1\.40x \(3 matching peaks"):
            pair_checks.check_framing_frequency("R", "T", names)
