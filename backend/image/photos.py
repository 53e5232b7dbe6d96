"""Photo input for the fit: reading, RAW decoding, crop/resize, flat-field and pair checks.

Turns a reflection photo (front light, ``_R``) and a transmission photo (back light, ``_T``) into
*working images*: what the renderer outputs (spec section 1), so that photos and renders compare
directly.

Conventions
    - Working image: ``(size, size, 3)`` float32 numpy array, RGB, values in [0, 1], encoded with the
      renders' transfer curve ``value = linear ** (1 / 2.2)`` (the renders clamp radiance at 1 first).
    - 8/16-bit PNG, JPEG and TIFF photos are taken as already encoded (a phone's sRGB output is close
      to this curve); their values are only scaled to [0, 1].
    - Linear sources (OpenEXR, float TIFF, camera RAW) are exposure-normalised, clipped at 1 and then
      encoded with the 1/2.2 power. ``exposure=None`` (auto) scales linear values so that the 99th
      percentile of linear luminance (Rec. 709 weights) over the crop becomes 0.5 (0.73 encoded, a
      level typical of the rig's renders and photos, with headroom for highlights); in
      :func:`load_pair` one scale serves both photos, taken from the brighter one, so their relative
      brightness (the fabric's transmittance) survives. A number multiplies the linear values as is.
    - Camera RAW (by file extension, :data:`RAW_EXTENSIONS`) is decoded by rawpy linearly: camera
      white balance, no auto-brightness, 16 bits, gamma (1, 1), sRGB primaries; LibRaw applies the
      camera's orientation.
    - EXIF orientation is applied: from JPEG APP1 and PNG eXIf here, because OpenCV's
      ``IMREAD_UNCHANGED`` ignores it there; OpenCV's TIFF decoder applies the TIFF tag itself.
      Crop boxes are in pixels of the upright (oriented) image.
    - Alpha channels are dropped; greyscale is expanded to RGB.
    - Crop: a square; the centred largest square by default, or an explicit box ``(x, y, w, h)``
      with ``w == h``. Resampling to the working size happens in linear light (the renderer averages
      its pixel samples in radiance): area interpolation when shrinking, bilinear when enlarging.
    - Flat-field: a photo of a uniform target, same camera and framing as the photo. It is cropped
      like the photo, taken to linear light, resized, smoothed (Gaussian, sigma = size / 32),
      normalised to a maximum of 1 per channel and floored at 0.05; the photo is divided by it in
      linear light and clipped at 1. Whatever the target shows is divided out: shot under the rig's
      own lamp that includes the lamp's falloff, which the renderer models, so shoot it under even
      light to remove only the lens vignetting.

Pair checks (:func:`load_pair`; computed on the working images before the flat-field division)
    - Framing: the two source images must have the same pixel size (else :class:`PhotoError`). The
      same fabric on the same stand shows the same yarn lattice, so the peaks of the two luminance
      power spectra (:func:`yarn_peaks`, lighting gradient removed) must coincide within 5 %. When
      they do not, the magnification that best aligns them (:func:`best_lattice_scale`) tells a
      framing difference: more than 20 %, with two peaks (or both photos' main peaks) agreeing on
      it, is refused; anything less certain is a warning (:func:`check_framing_frequency`). The two
      photos may emphasise different peaks of one lattice (a satin's diagonals in reflection, its
      yarn gaps in transmission), hence the comparison of peak sets, not of single peaks.
    - Order (:func:`order_cues`, :func:`check_order`): the front light sits above the top edge of the
      image, so a reflection photo is brighter towards the top; the back light sits behind the image
      centre, so a transmission photo is even from top to bottom, with a centred glow. See
      :func:`check_order` for the rule and thresholds. Doubts are warnings, or :class:`PhotoError`
      with ``strict=True``.

Errors are :class:`PhotoError` (a ``ValueError``) whose message names the file and the problem.
"""
from __future__ import annotations

import os

# OpenCV reads this once, at the first EXR decode of the process: set it before any decode happens.
os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")

import math  # noqa: E402
import struct  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Sequence, Union  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from ..core.formats import RAW_SUFFIXES  # noqa: E402

PathLike = Union[str, os.PathLike]
Box = tuple[int, int, int, int]

GAMMA = 2.2
DEFAULT_SIZE = 512
LUMA_WEIGHTS = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)

AUTO_EXPOSURE_PERCENTILE = 99.0
AUTO_EXPOSURE_LEVEL = 0.5

FLAT_FIELD_SMOOTHING = 1 / 32
FLAT_FIELD_FLOOR = 0.05

# Pair checks: the rules and the values measured on real and rendered pairs are in check_order,
# check_framing_frequency and yarn_peaks.
TOP_BIAS_THRESHOLD = 0.35
FREQUENCY_TOLERANCE = 0.05
FRAMING_REFUSE = 0.20
MIN_YARN_CYCLES = 16
MAX_PEAKS = 8
MIN_PEAK_POWER = 0.05
MIN_PEAK_PROMINENCE = 10.0
HARMONIC_RATIOS = (2.0, 1.5, 4 / 3, 3 / 4, 2 / 3, 0.5)

RAW_EXTENSIONS = frozenset(RAW_SUFFIXES)

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_SIGNATURE = b"\xff\xd8\xff"
_TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")
_EXR_SIGNATURE = b"v/1\x01"
_ORIENTATION_TAG = 0x0112


class PhotoError(ValueError):
    """A photo cannot be used; the message names the file and the problem."""


# -- data ---------------------------------------------------------------------------------------

@dataclass
class SourceImage:
    """A decoded photo, upright, before any crop: (H, W, 3) RGB in its own dtype.

    ``pixels`` is uint8, uint16 or float32. ``linear``: the values are proportional to radiance
    (EXR, float TIFF, camera RAW as 16-bit integers); otherwise they are encoded (module docstring).
    """

    path: Path
    pixels: np.ndarray
    format: str
    linear: bool

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.pixels.shape[1], self.pixels.shape[0]


@dataclass
class Photo:
    """One working image and how it was made."""

    image: np.ndarray
    path: Path
    format: str
    source_size: tuple[int, int]
    crop: Box
    exposure: float | None
    warnings: list[str] = field(default_factory=list)


@dataclass
class PhotoPair:
    """Both working images, the warnings raised while making them, and facts about them.

    ``info`` is JSON-friendly: ``reflection`` / ``transmission`` (path, format, source_size as
    [width, height], crop as [x, y, w, h], exposure: the linear scale applied, None for encoded
    photos), ``size``, ``order`` (the cues of :func:`order_cues` for both images and the order
    score) and ``yarn_frequency`` (each image's spectral peaks as [fx, fy] in cycles per image,
    strongest first; ``mismatch``, see :func:`frequency_mismatch`; ``scale``, the magnification of
    the transmission lattice that best aligns it with the reflection's; None where either image
    shows no clear yarn pattern).
    """

    reflection: np.ndarray
    transmission: np.ndarray
    warnings: list[str]
    info: dict


# -- reading ------------------------------------------------------------------------------------

def read_image(path: PathLike) -> SourceImage:
    """Reads a PNG, JPEG, TIFF, EXR or camera RAW file into an upright :class:`SourceImage`."""
    path = Path(path)
    if not path.exists():
        raise PhotoError(f"{path}: file not found")
    if not path.is_file():
        raise PhotoError(f"{path}: not a file")
    if path.suffix.lower() in RAW_EXTENSIONS:
        return _read_raw(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PhotoError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not data:
        raise PhotoError(f"{path}: the file is empty")
    kind = _sniff_format(data, path)
    orientation = _check_structure(data, kind, path)
    pixels = _decode(data, kind, path)
    pixels = _to_rgb(pixels, path)
    pixels = apply_orientation(pixels, orientation)
    depth = {np.dtype(np.uint8): "8-bit", np.dtype(np.uint16): "16-bit"}.get(pixels.dtype, "float")
    return SourceImage(path, np.ascontiguousarray(pixels), f"{kind} {depth}", linear=pixels.dtype.kind == "f")


def _sniff_format(data: bytes, path: Path) -> str:
    if data.startswith(_PNG_SIGNATURE):
        return "png"
    if data.startswith(_JPEG_SIGNATURE):
        return "jpeg"
    if data[:4] in _TIFF_SIGNATURES:
        return "tiff"
    if data.startswith(_EXR_SIGNATURE):
        return "exr"
    hint = _name_unsupported(data)
    raise PhotoError(f"{path}: unsupported file format{hint} (expected PNG, JPEG, TIFF, OpenEXR or camera RAW "
                     f"with one of the extensions {', '.join(sorted(RAW_EXTENSIONS))})")


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
    buffer = np.frombuffer(data, dtype=np.uint8)  # imdecode, not imread: non-ASCII paths on Windows
    try:
        pixels = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise PhotoError(f"{path}: could not be decoded as {kind.upper()} ({_first_line(exc)})") from None
    if pixels is None or pixels.size == 0:
        raise PhotoError(f"{path}: could not be decoded as {kind.upper()} (corrupt or unsupported variant)")
    return pixels


def _first_line(exc: BaseException) -> str:
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


def _read_raw(path: Path) -> SourceImage:
    try:
        import rawpy
    except ImportError:  # pragma: no cover - rawpy is a declared dependency
        raise PhotoError(f"{path}: camera RAW files need the rawpy package") from None
    try:
        with rawpy.imread(str(path)) as raw:
            pixels = raw.postprocess(**raw_postprocess_options(rawpy))
    except Exception as exc:  # LibRaw's error classes vary by version; any failure is a bad file
        raise PhotoError(f"{path}: could not be decoded as camera RAW ({type(exc).__name__}: "
                         f"{_first_line(exc)})") from None
    pixels = np.asarray(pixels)
    if pixels.ndim != 3 or pixels.shape[2] != 3 or pixels.dtype != np.uint16:
        raise PhotoError(f"{path}: the RAW decoder returned {pixels.dtype} {pixels.shape}, expected 16-bit RGB")
    return SourceImage(path, pixels, "camera raw", linear=True)


def raw_postprocess_options(rawpy) -> dict:
    """rawpy ``postprocess`` arguments for linear output in sRGB primaries with the camera's white balance."""
    return dict(use_camera_wb=True, use_auto_wb=False, no_auto_bright=True, output_bps=16, gamma=(1, 1),
                output_color=rawpy.ColorSpace.sRGB)


# -- file structure: truncation and orientation ------------------------------------------------

def _check_structure(data: bytes, kind: str, path: Path) -> int:
    """Raises on a truncated file; returns the EXIF orientation (1 = upright)."""
    if kind == "jpeg":
        return _jpeg_structure(data, path)
    if kind == "png":
        return _png_structure(data, path)
    if kind == "tiff":
        return _tiff_structure(data, path)
    return 1


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
        if marker == 0xDA:  # start of scan
            break
        pos += 2 + length
    if data.find(b"\xff\xd9", pos + 2 + length) < 0:
        raise _truncated(path, "no JPEG end-of-image marker")
    return orientation


def _png_structure(data: bytes, path: Path) -> int:
    """Walks the chunks to IEND; an eXIf chunk may carry an orientation."""
    orientation, pos = 1, len(_PNG_SIGNATURE)
    while pos + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        if pos + 12 + length > len(data):
            break
        if kind == b"IEND":
            return orientation
        if kind == b"eXIf":
            orientation = _tiff_orientation(data[pos + 8:pos + 8 + length]) or orientation
        pos += 12 + length
    raise _truncated(path, "no PNG IEND chunk")


def _tiff_structure(data: bytes, path: Path) -> int:
    """Checks that the first IFD and its image data lie inside the file.

    Returns 1: OpenCV's TIFF decoder applies the Orientation tag itself (unlike its JPEG and PNG
    decoders under IMREAD_UNCHANGED; the tests check both).
    """
    if data[2:4] in (b"+\x00", b"\x00+"):  # BigTIFF: no structural check, the decoder has the last word
        return 1
    entries = _tiff_ifd0(data)
    if entries is None:
        raise _truncated(path, "the TIFF directory lies beyond the end of the file")
    for offsets_tag, counts_tag in ((273, 279), (324, 325)):  # strips, tiles
        offsets, counts = entries.get(offsets_tag), entries.get(counts_tag)
        if offsets and counts and max(o + c for o, c in zip(offsets, counts)) > len(data):
            raise _truncated(path, "the TIFF image data runs past the end of the file")
    return 1


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
    entries = _tiff_ifd0(data) or {}
    return _valid_orientation(entries.get(_ORIENTATION_TAG))


def _valid_orientation(values: list[int] | None) -> int:
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


# -- crop, exposure, resize ---------------------------------------------------------------------

def crop_box(image_size: tuple[int, int], crop: Sequence[int] | None, path: Path | str) -> Box:
    """The square box (x, y, w, h) to use: the centred largest square, or ``crop`` validated."""
    width, height = image_size
    if crop is None:
        side = min(width, height)
        return (width - side) // 2, (height - side) // 2, side, side
    try:
        x, y, w, h = (int(v) for v in crop)
        if any(int(v) != v for v in crop):
            raise ValueError
    except (TypeError, ValueError):
        raise PhotoError(f"{path}: crop box must be four whole numbers (x, y, w, h), got {crop!r}") from None
    if w <= 0 or h <= 0:
        raise PhotoError(f"{path}: crop box {(x, y, w, h)} has no area")
    if w != h:
        raise PhotoError(f"{path}: crop box {(x, y, w, h)} is not square ({w} x {h}); the working image is square")
    if x < 0 or y < 0 or x + w > width or y + h > height:
        raise PhotoError(f"{path}: crop box {(x, y, w, h)} lies outside the {width} x {height} image")
    return x, y, w, h


def check_crop_size(box: Box, size: int, path: Path | str) -> list[str]:
    """Refuses crops under half the working size; warns about (and allows) upscaling."""
    side = box[2]
    if side < size / 2:
        raise PhotoError(f"{path}: image too small: the square crop is {side} x {side} pixels, at least "
                         f"{math.ceil(size / 2)} are needed for a {size} x {size} working image")
    if side < size:
        return [f"{path}: the square crop is only {side} x {side} pixels; upscaled to {size} x {size}, "
                "fine yarn detail will be soft"]
    return []


def to_linear(region: np.ndarray, linear: bool) -> np.ndarray:
    """Float32 linear values. Integers are scaled to [0, 1] first, and raised to 2.2 unless linear;
    floats (always linear) lose NaNs, infinities and negatives."""
    if region.dtype.kind == "f":
        return np.nan_to_num(region.astype(np.float32), nan=0.0, posinf=1e6, neginf=0.0).clip(0.0, None)
    values = region.astype(np.float32) / np.float32(255.0 if region.dtype == np.uint8 else 65535.0)
    return values if linear else values ** np.float32(GAMMA)


def luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb @ LUMA_WEIGHTS


def auto_exposure(*linear_regions: np.ndarray) -> float:
    """Scale putting the 99th percentile of linear luminance of the brightest region at 0.5."""
    level = max(float(np.percentile(luminance(r), AUTO_EXPOSURE_PERCENTILE)) for r in linear_regions)
    return AUTO_EXPOSURE_LEVEL / level if level > 0 else 1.0


def resize_linear(linear: np.ndarray, size: int) -> np.ndarray:
    """Area interpolation when shrinking, bilinear when enlarging (in linear light)."""
    if linear.shape[:2] == (size, size):
        return linear
    shrink = linear.shape[0] > size
    out = cv2.resize(linear, (size, size), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return out.clip(0.0, None)


def encode(linear: np.ndarray) -> np.ndarray:
    """The renders' output curve: clamp at 1, then the 1/2.2 power."""
    return np.clip(linear, 0.0, 1.0) ** np.float32(1 / GAMMA)


def _crop(source: SourceImage, box: Box) -> np.ndarray:
    x, y, w, h = box
    return source.pixels[y:y + h, x:x + w]


# -- flat-field ---------------------------------------------------------------------------------

def flat_field_gain(flat: SourceImage, box: Box, size: int) -> tuple[np.ndarray, list[str]]:
    """Smoothed, max-normalised (per channel) and floored linear flat-field at the working size."""
    linear = resize_linear(to_linear(_crop(flat, box), flat.linear), size)
    sigma = max(size * FLAT_FIELD_SMOOTHING, 0.5)
    smooth = cv2.GaussianBlur(linear, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    peak = smooth.reshape(-1, 3).max(axis=0)
    if not np.all(peak > 1e-6):
        raise PhotoError(f"{flat.path}: the flat-field image is black in at least one colour channel")
    gain = smooth / peak
    low = gain < FLAT_FIELD_FLOOR
    warnings = []
    if low.any():
        warnings.append(f"{flat.path}: the flat-field falls below {FLAT_FIELD_FLOOR:.0%} of its maximum on "
                        f"{low.any(axis=2).mean():.1%} of the image; corrected there as if at {FLAT_FIELD_FLOOR:.0%}")
    return np.maximum(gain, FLAT_FIELD_FLOOR), warnings


def apply_flat_field(image: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """Divides an encoded working image by a linear gain, in linear light."""
    return encode((image ** np.float32(GAMMA)) / gain).astype(np.float32)


def _read_flat(flat_field: PathLike, photo: SourceImage) -> SourceImage:
    flat = read_image(flat_field)
    if flat.size != photo.size:
        raise PhotoError(f"{flat.path}: the flat-field is {flat.size[0]} x {flat.size[1]} pixels but the photo "
                         f"{photo.path} is {photo.size[0]} x {photo.size[1]}; take both with the same camera framing")
    return flat


# -- one photo ----------------------------------------------------------------------------------

def _check_size_arg(size: int) -> int:
    if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or size < 8:
        raise PhotoError(f"working size must be an integer of at least 8, got {size!r}")
    return int(size)


def _check_exposure(exposure: float | None) -> float | None:
    if exposure is not None and not (isinstance(exposure, (int, float)) and math.isfinite(exposure) and exposure > 0):
        raise PhotoError(f"exposure must be a positive number (a multiplier on linear values), got {exposure!r}")
    return exposure


def _working_image(source: SourceImage, box: Box, size: int, scale: float | None) -> np.ndarray:
    linear = to_linear(_crop(source, box), source.linear)
    if source.linear:
        linear = np.minimum(linear * np.float32(scale), 1.0)
    return encode(resize_linear(linear, size)).astype(np.float32)


def load_photo(path: PathLike, size: int = DEFAULT_SIZE, crop: Sequence[int] | None = None,
               flat_field: PathLike | None = None, exposure: float | None = None) -> Photo:
    """Reads one photo into a working image (see the module docstring for every convention)."""
    size, exposure = _check_size_arg(size), _check_exposure(exposure)
    source = read_image(path)
    box = crop_box(source.size, crop, source.path)
    warnings = check_crop_size(box, size, source.path)
    scale = None
    if source.linear:
        scale = exposure if exposure is not None else auto_exposure(to_linear(_crop(source, box), source.linear))
    image = _flat_corrected(_working_image(source, box, size, scale), flat_field, source, box, size, warnings)
    return Photo(image, source.path, source.format, source.size, box, scale, warnings)


# -- pair checks --------------------------------------------------------------------------------

def order_cues(image: np.ndarray) -> dict[str, float]:
    """Lighting cues of a working image, from its linear luminance.

    top_bias: log(mean of the top quarter of rows / mean of the bottom quarter). The front light
        above the top edge makes reflection photos brighter at the top (default rig: about 1/d^2 =
        2.6x from the bottom to the top edge); the back light behind the centre leaves transmission
        photos symmetric (about 0).
    centre_glow: log(mean within 0.08 size of the centre / mean of the ring 0.2 .. 0.3 size). The
        back light, and its out-of-focus glow through the gaps, peak at the centre; vignetting, the
        same in both photos, adds the same amount to both.
    """
    lum = luminance(np.asarray(image, dtype=np.float32) ** np.float32(GAMMA))
    n = lum.shape[0]
    quarter = max(n // 4, 1)
    eps = 1e-6
    top_bias = math.log((lum[:quarter].mean() + eps) / (lum[-quarter:].mean() + eps))
    yy, xx = np.mgrid[0:n, 0:n] + 0.5
    radius = np.hypot(yy - n / 2, xx - n / 2) / n
    centre = lum[radius < 0.08].mean()
    ring = lum[(radius >= 0.2) & (radius < 0.3)].mean()
    centre_glow = math.log((centre + eps) / (ring + eps))
    return {"top_bias": top_bias, "centre_glow": centre_glow}


def order_score(reflection_cues: dict, transmission_cues: dict) -> float:
    """Positive when the pair reads as given: (top_bias_R - top_bias_T) + (centre_glow_T - centre_glow_R)."""
    return ((reflection_cues["top_bias"] - transmission_cues["top_bias"])
            + (transmission_cues["centre_glow"] - reflection_cues["centre_glow"]))


def check_order(reflection_cues: dict, transmission_cues: dict) -> list[str]:
    """Reasons to believe the photos are swapped (or mislabelled); empty when the order looks right.

    Three tests, each from the rig's geometry:
    - the transmission photo has top_bias >= 0.35 (top quarter 1.4x brighter than the bottom): it
      looks lit by the front light;
    - the reflection photo has top_bias < 0.35: it does not look lit by the front light;
    - the order score (:func:`order_score`) is negative: the pair reads better the other way round.
    Measured (working images): the 3 real pairs, top_bias R 0.66 .. 1.09, T -0.14 .. -0.03, score
    >= 0.92; the 17 golden renders (512 px), R 0.70 .. 1.96, |T| <= 0.002, score >= 0.95; the golden
    cases and 40 draws of the dataset prior (spec 5.4) rendered at 256 px, 4 spp: R >= 0.69,
    |T| <= 0.007, score >= 0.68. No pair in order was flagged; every swapped one was, by all three.
    """
    reasons = []
    ratio_t = math.exp(transmission_cues["top_bias"])
    ratio_r = math.exp(reflection_cues["top_bias"])
    limit = math.exp(TOP_BIAS_THRESHOLD)
    if transmission_cues["top_bias"] >= TOP_BIAS_THRESHOLD:
        reasons.append(f"the transmission photo is {ratio_t:.2f}x brighter at the top than at the bottom, like a "
                       "photo lit by the front light above the top edge "
                       f"(a back-lit photo is even: below {limit:.2f}x)")
    if reflection_cues["top_bias"] < TOP_BIAS_THRESHOLD:
        reasons.append(f"the reflection photo is only {ratio_r:.2f}x brighter at the top than at the bottom; "
                       f"the front light above the top edge makes it at least {limit:.2f}x")
    score = order_score(reflection_cues, transmission_cues)
    if score < 0:
        reasons.append(f"the lighting cues favour the opposite order (score {score:+.2f}: top brightness and "
                       "centred glow of the two photos)")
    return reasons


def yarn_peaks(image: np.ndarray) -> list[tuple[float, float, float]]:
    """Dominant peaks of the luminance power spectrum: (fx, fy, power relative to the strongest).

    Frequencies are in cycles per image width (fx, to the right) and height (fy, downwards), one of
    each +-f pair (fy > 0, or fy == 0 and fx > 0). The lighting gradient, glow and vignetting are
    removed first (minus a Gaussian blur of sigma size / 64, so under about 16 cycles), the detail is
    normalised by its local contrast (so the bright centre does not dominate) and windowed (Hann).
    Peaks are local maxima of the lightly smoothed spectrum above 16 cycles, at most 8, each at least
    5 % of the strongest. Empty when the strongest stands less than 10x above the median power: no
    clear yarn pattern.
    """
    n = image.shape[0]
    lum = luminance(np.asarray(image, dtype=np.float32))
    detail = lum - cv2.GaussianBlur(lum, (0, 0), n / 64, borderType=cv2.BORDER_REFLECT)
    contrast = np.sqrt(cv2.GaussianBlur(detail * detail, (0, 0), n / 16, borderType=cv2.BORDER_REFLECT))
    detail = detail / (contrast + 1e-4)
    window = np.outer(np.hanning(n), np.hanning(n)).astype(np.float32)
    power = np.abs(np.fft.fftshift(np.fft.fft2(detail * window))) ** 2
    freqs = np.fft.fftshift(np.fft.fftfreq(n, 1.0 / n))
    fy, fx = np.meshgrid(freqs, freqs, indexing="ij")
    usable = np.hypot(fx, fy) >= MIN_YARN_CYCLES
    power = np.where(usable, power, 0.0).astype(np.float32)
    smooth = cv2.GaussianBlur(power, (0, 0), 1.0)
    if not usable.any() or smooth.max() <= 0:
        return []
    if smooth.max() < MIN_PEAK_PROMINENCE * np.median(smooth[usable]):
        return []
    is_max = smooth == cv2.dilate(smooth, np.ones((7, 7), np.uint8))
    half = (fy > 0) | ((fy == 0) & (fx > 0))
    rows, cols = np.nonzero(is_max & half & usable & (smooth >= MIN_PEAK_POWER * smooth.max()))
    order = np.argsort(-smooth[rows, cols])[:MAX_PEAKS]
    top = smooth[rows[order[0]], cols[order[0]]]
    return [(float(fx[rows[i], cols[i]]), float(fy[rows[i], cols[i]]), float(smooth[rows[i], cols[i]] / top))
            for i in order]


def frequency_mismatch(peaks_a: Sequence, peaks_b: Sequence) -> float | None:
    """Relative distance from one image's strongest peak to the nearest peak (+-f) of the other.

    Taken both ways round, the smaller wins: the two photos light the same yarn lattice differently
    (a reflection photo of a satin shows its diagonals, the transmission photo its yarn gaps), so it
    is enough that one strongest peak appears in the other spectrum. None when either has no peaks.
    """
    if not peaks_a or not peaks_b:
        return None
    return float(min(_nearest_peak(peaks_a[0], peaks_b), _nearest_peak(peaks_b[0], peaks_a)))


def _nearest_peak(peak: Sequence[float], others: Sequence, scale: float = 1.0) -> float:
    """Relative distance |p - s q| / |p| from ``peak`` to the nearest of ``others`` (either sign)."""
    p = np.asarray(peak[:2], dtype=float)
    q = scale * np.asarray([o[:2] for o in others], dtype=float)
    distances = np.minimum(np.hypot(*(q - p).T), np.hypot(*(q + p).T))
    return float(distances.min() / max(np.hypot(*p), 1e-9))


def lattice_match(peaks_a: Sequence, peaks_b: Sequence, scale: float) -> tuple[float, int]:
    """How well ``peaks_a`` and ``peaks_b`` magnified by ``scale`` coincide: (score, peaks matched).

    A peak of a is matched by a peak of b within 5 % (relative); the score adds min(power a, power b)
    over the matched peaks of a, so two dominant peaks agreeing count 1.
    """
    score, matched = 0.0, 0
    for peak in peaks_a:
        hits = [min(peak[2], other[2]) for other in peaks_b
                if _nearest_peak(peak, [other], scale) <= FREQUENCY_TOLERANCE]
        if hits:
            score, matched = score + max(hits), matched + 1
    return score, matched


def best_lattice_scale(peaks_a: Sequence, peaks_b: Sequence) -> tuple[float, float, int]:
    """The magnification of b's lattice that best matches a's: (scale, score, peaks matched).

    Candidates are the length ratios of peak pairs pointing the same way (within 3 degrees, the stand
    does not rotate the camera), between 0.5 and 2.
    """
    best = (1.0, *lattice_match(peaks_a, peaks_b, 1.0))
    for p in peaks_a:
        for q in peaks_b:
            angle = abs(math.atan2(p[1], p[0]) - math.atan2(q[1], q[0])) % math.pi
            if min(angle, math.pi - angle) > math.radians(3):
                continue
            scale = math.hypot(p[0], p[1]) / max(math.hypot(q[0], q[1]), 1e-9)
            if 0.5 <= scale <= 2.0:
                candidate = (scale, *lattice_match(peaks_a, peaks_b, scale))
                if candidate[1] > best[1] + 1e-9:
                    best = candidate
    return best


def _harmonic(scale: float) -> bool:
    """Whether ``scale`` is within 3 % of a ratio of small harmonics (2, 3/2, 4/3 or their inverses)."""
    return any(abs(math.log(scale / ratio)) < 0.03 for ratio in HARMONIC_RATIOS)


def _describe_peak(peak) -> str:
    return f"{math.hypot(peak[0], peak[1]):.0f} cycles per image at ({peak[0]:+.0f}, {peak[1]:+.0f})"


def check_framing_frequency(reflection: np.ndarray, transmission: np.ndarray, names: tuple[Path, Path]
                            ) -> tuple[list[str], dict]:
    """Compares the yarn lattices of the two working images.

    The photos agree when their peaks coincide at scale 1 at least half as well as at the best scale
    (:func:`best_lattice_scale`). Otherwise: when the best scale is more than 20 % away from 1 and
    at least two peaks agree on it (or one peak with at least half the strongest power in both
    photos, at a ratio that is not harmonic: 2, 3/2, 4/3 or their inverses, within 3 %), the photos
    were framed at different scales (or show different fabrics):
    :class:`PhotoError`; within 20 %, or with less evidence, a warning.
    """
    peaks_r, peaks_t = yarn_peaks(reflection), yarn_peaks(transmission)
    info = {"reflection": [list(p[:2]) for p in peaks_r], "transmission": [list(p[:2]) for p in peaks_t],
            "mismatch": frequency_mismatch(peaks_r, peaks_t), "scale": None}
    label = f"{names[0]} / {names[1]}"
    if not peaks_r or not peaks_t:
        missing = [str(n) for n, p in zip(names, (peaks_r, peaks_t)) if not p]
        return [f"{', '.join(missing)}: no clear yarn pattern in the spectrum; the framing check was skipped"], info
    score_at_one, _ = lattice_match(peaks_r, peaks_t, 1.0)
    scale, score, matched = best_lattice_scale(peaks_r, peaks_t)
    info["scale"] = scale
    if score_at_one >= 0.5 * score and score_at_one > 0:
        return [], info
    dominant = (f"dominant yarn frequencies {_describe_peak(peaks_r[0])} (reflection) and "
                f"{_describe_peak(peaks_t[0])} (transmission)")
    if matched == 0:
        return [f"{label}: the yarn patterns share no spectral peak ({dominant}): check that both photos show the "
                "same fabric at the same scale"], info
    zoom = f"the transmission photo's yarn lattice matches the reflection's magnified {scale:.2f}x"
    agree = f"{matched} matching peak{'s' if matched != 1 else ''}"
    # Two peaks agreeing on the scale, or one with half the strongest power in both photos unless the
    # ratio is harmonic (a photo may show 2f where the other shows f: same lattice, same framing).
    strong = matched >= 2 or (score >= 0.5 and not _harmonic(scale))
    if abs(math.log(scale)) <= math.log(1 + FRAMING_REFUSE) or not strong:
        return [f"{label}: {zoom} ({agree}; {dominant}): the photos may be framed at slightly "
                "different scales"], info
    raise PhotoError(f"{label}: the photos are framed differently: {zoom} ({agree}; {dominant}), more "
                     f"than {FRAMING_REFUSE:.0%} off; the same fabric on the same stand shows the same yarn density "
                     "in both photos")


# -- the pair -----------------------------------------------------------------------------------

def _flat_paths(flat_field) -> tuple[PathLike | None, PathLike | None]:
    if flat_field is None or isinstance(flat_field, (str, os.PathLike)):
        return flat_field, flat_field
    try:
        reflection_flat, transmission_flat = flat_field
    except (TypeError, ValueError):
        raise PhotoError(f"flat_field must be a path or a (reflection, transmission) pair of paths, got "
                         f"{flat_field!r}") from None
    return reflection_flat, transmission_flat


def _flat_corrected(image: np.ndarray, flat_path: PathLike | None, source: SourceImage, box: Box, size: int,
                    warnings: list[str]) -> np.ndarray:
    """``image`` divided by the flat-field at ``flat_path`` (if any); its warnings join ``warnings``."""
    if flat_path is None:
        return image
    gain, flat_warnings = flat_field_gain(_read_flat(flat_path, source), box, size)
    warnings += [w for w in flat_warnings if w not in warnings]
    return apply_flat_field(image, gain)


def _pair_exposure(reflection: SourceImage, transmission: SourceImage, box: Box,
                   exposure: float | None) -> tuple[float | None, float | None, list[str]]:
    sources = (reflection, transmission)
    linear = [s for s in sources if s.linear]
    if not linear:
        return None, None, []
    if exposure is not None:
        scales = [exposure if s.linear else None for s in sources]
        return scales[0], scales[1], []
    if len(linear) == 2:
        scale = auto_exposure(*(to_linear(_crop(s, box), s.linear) for s in sources))
        return scale, scale, []
    scales = [auto_exposure(to_linear(_crop(s, box), s.linear)) if s.linear else None for s in sources]
    note = (f"{linear[0].path}: a linear source paired with an encoded photo: exposed on its own, so the "
            "relative brightness of the two photos is not preserved")
    return scales[0], scales[1], [note]


def load_pair(reflection_path: PathLike, transmission_path: PathLike, size: int = DEFAULT_SIZE,
              crop: Sequence[int] | None = None, flat_field=None, strict: bool = False,
              exposure: float | None = None) -> PhotoPair:
    """Reads, checks and prepares a reflection/transmission photo pair.

    ``crop`` applies to both photos (same camera, same stand). ``flat_field`` is one path for both,
    or a (reflection, transmission) pair of paths. Framing problems raise :class:`PhotoError`;
    doubts about the order are warnings, or :class:`PhotoError` when ``strict``.
    """
    size, exposure = _check_size_arg(size), _check_exposure(exposure)
    reflection, transmission = read_image(reflection_path), read_image(transmission_path)
    label = f"{reflection.path} / {transmission.path}"
    if reflection.size != transmission.size:
        raise PhotoError(f"{label}: the photos are framed differently: {reflection.size[0]} x {reflection.size[1]} "
                         f"vs {transmission.size[0]} x {transmission.size[1]} pixels; take both from the same "
                         "stand with the same camera settings")
    box = crop_box(reflection.size, crop, label)
    warnings = check_crop_size(box, size, label)
    scale_r, scale_t, notes = _pair_exposure(reflection, transmission, box, exposure)
    warnings += notes
    image_r = _working_image(reflection, box, size, scale_r)
    image_t = _working_image(transmission, box, size, scale_t)

    frequency_warnings, frequency_info = check_framing_frequency(image_r, image_t, (reflection.path,
                                                                                    transmission.path))
    warnings += frequency_warnings
    cues_r, cues_t = order_cues(image_r), order_cues(image_t)
    reasons = check_order(cues_r, cues_t)
    if reasons:
        message = (f"{label}: the photos may be swapped (reflection = front light, transmission = back light): "
                   + "; ".join(reasons))
        if strict:
            raise PhotoError(message)
        warnings.append(message)

    flat_r, flat_t = _flat_paths(flat_field)
    image_r = _flat_corrected(image_r, flat_r, reflection, box, size, warnings)
    image_t = _flat_corrected(image_t, flat_t, transmission, box, size, warnings)

    def describe(source: SourceImage, scale):
        return {"path": str(source.path), "format": source.format, "source_size": list(source.size),
                "crop": list(box), "exposure": scale}

    info = {"reflection": describe(reflection, scale_r), "transmission": describe(transmission, scale_t),
            "size": size,
            "order": {"reflection": cues_r, "transmission": cues_t, "score": order_score(cues_r, cues_t)},
            "yarn_frequency": frequency_info}
    return PhotoPair(image_r, image_t, warnings, info)
