"""The defects the fuzz harness (devtools/fuzz, tests/test_fuzz.py) found, each now refused with one
clear line naming the file or option and the problem (issue 91)."""
import json

import numpy as np
import pytest
import torch

from backend.app.cli.main import main
from backend.app.folder import EXAMPLE_PARAMS
from backend.core.fit_options import MIN_WORKING_SIZE
from backend.core.jsonfile import read_json
from backend.core.params import FabricParams, ParamError, load_params
from backend.core.protocol import EXIT_INPUT
from backend.core.rig import MAX_FILM_SIZE, MIN_FILM_SIZE, CaptureRig, RigError
from backend.image import decode
from backend.image.containers import MAX_SOURCE_PIXELS, check_structure
from backend.image.photos import PhotoError, load_pair
from devtools.fuzz.images import ENCODINGS, FILM, base_pair
from devtools.fuzz.photos import with_declared_size


@pytest.mark.parametrize("text, problem", [
    ('{"film_size": ' + "[" * 100_000 + "]" * 100_000 + "}", "not usable JSON (arrays or objects nested too deep)"),
    ('{"film_size": ' + "9" * 5000 + "}", "not usable JSON (Exceeds the limit (4300 digits) for integer string "
                                          "conversion: value has 5000 digits)"),
])
def test_json_python_cannot_hold_is_one_line_naming_the_file(tmp_path, text, problem):
    path = tmp_path / "rig.json"
    path.write_text(text)
    for read in (lambda: read_json(path, RigError), lambda: CaptureRig.load(path)):
        with pytest.raises(RigError) as error:
            read()
        assert str(error.value) == f"{path}: {problem}"
    (tmp_path / "params.json").write_text(text)
    with pytest.raises(ParamError, match=f"^{tmp_path / 'params.json'}: not usable JSON"):
        load_params(str(tmp_path / "params.json"))


def write_params(tmp_path, **changes) -> str:
    path = tmp_path / "params.json"
    path.write_text(json.dumps({**FabricParams().to_dict(), **changes}))
    return str(path)


def test_a_huge_value_is_shown_briefly_in_the_one_line(tmp_path):
    path = write_params(tmp_path, roughness=[0.5] * 1_000_000)
    with pytest.raises(ParamError) as error:
        load_params(path)
    assert str(error.value) == (f"{path}: roughness: expected a [warp, weft] pair, got [0.5, 0.5, 0.5, 0.5, 0.5, 0.5, "
                                "0.5, 0.5, 0.5, 0.5, 0.5, 0.5,... (list of 1000000)")


@pytest.mark.parametrize("pattern", [["plain"], {"name": "plain"}, None, 5])
def test_a_pattern_that_is_not_a_name_is_refused(tmp_path, pattern):
    path = write_params(tmp_path, pattern=pattern)
    with pytest.raises(ParamError, match=rf"^{path}: pattern: expected the name of a weave, got "):
        load_params(path)


@pytest.mark.parametrize("value, shown", [("0.5", "'0.5'"), (True, "True"), (None, "None"), ({"warp": 0.5}, "{")])
def test_a_parameter_that_is_not_numbers_is_refused(tmp_path, value, shown):
    path = write_params(tmp_path, roughness=[0.5, value])
    with pytest.raises(ParamError) as error:
        load_params(path)
    assert str(error.value).startswith(f"{path}: roughness: expected numbers, got {shown}")
    assert FabricParams.from_dict(FabricParams().to_dict()) == FabricParams()  # numbers and lists of them still do


def test_a_bad_custom_weave_names_the_file(tmp_path):
    path = write_params(tmp_path, pattern="custom", weave={"matrix": [[0, 2], [1, 0]]})
    with pytest.raises(ParamError, match=rf"^{path}: weave 'custom': row 0 \[0, 2\] must hold only 0 and 1$"):
        load_params(path)


@pytest.mark.parametrize("setting, value, problem", [
    ("fov_deg", "wide", "rig.fov_deg: expected a finite number, got 'wide'"),          # was a TypeError traceback
    ("camera_height", True, "rig.camera_height: expected a finite number, got True"),  # was taken as 1
    ("glow_strength", float("nan"), "rig.glow_strength: expected a finite number, got nan"),  # was taken
    ("front_light", "123", "rig.front_light: expected [x, y, z], three numbers, got '123'"),  # was (1, 2, 3)
    ("back_light", [0.5] * 1_000_000, "rig.back_light: expected [x, y, z], three numbers, got [0.5, 0.5, 0.5, 0.5, "
                                      "0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5,... (list of 1000000)"),
    ("film_size", 64.5, f"rig.film_size: must be a whole number of pixels from {MIN_FILM_SIZE} to {MAX_FILM_SIZE}, "
                        "got 64.5"),  # was taken as 64
    ("film_size", 100_000, "rig.film_size: must be a whole number of pixels from 32 to 4096, got 100000"),
    ("film_size", 16, "rig.film_size: must be a whole number of pixels from 32 to 4096, got 16"),  # the fit's least
])
def test_a_rig_setting_of_the_wrong_kind_is_refused_naming_it(tmp_path, setting, value, problem):
    path = tmp_path / "rig.json"
    path.write_text(json.dumps({setting: value}))
    with pytest.raises(RigError) as error:
        CaptureRig.load(path)
    assert str(error.value) == f"{path}: {problem}"


def test_the_rig_takes_whole_films_within_its_bounds_and_an_unknown_width():
    assert CaptureRig(film_size=64.0).film_size == 64
    assert CaptureRig(film_size=MIN_FILM_SIZE).film_size == MIN_FILM_SIZE == MIN_WORKING_SIZE
    assert CaptureRig(film_size=MAX_FILM_SIZE, width_cm=None).film_size == MAX_FILM_SIZE


@pytest.mark.parametrize("out, problem", [
    ("/proc/forbidden/out", "No such file or directory"),  # the example: was a FileNotFoundError traceback
    ("{tmp}/notes.txt/out", "Not a directory"),            # a file in the way: was a NotADirectoryError traceback
])
@pytest.mark.parametrize("command", ["fit", "render"])
def test_an_output_folder_that_cannot_be_made_is_one_line(tmp_path, capsys, out, problem, command):
    (tmp_path / "notes.txt").write_text("a file, not a folder")
    out = out.replace("{tmp}", str(tmp_path))
    words = ["fit", "R.png", "T.png"] if command == "fit" else ["render", EXAMPLE_PARAMS]
    assert main([*words, "--out", out]) == EXIT_INPUT
    assert capsys.readouterr().err.splitlines() == [f"error: {out}: cannot create the folder ({problem})"]


@pytest.mark.parametrize("command", ["fit", "render", "batch"])
def test_an_empty_output_folder_name_is_refused(capsys, command):
    words = {"fit": ["fit", "R.png", "T.png"], "render": ["render", EXAMPLE_PARAMS], "batch": ["batch", "P"]}[command]
    with pytest.raises(SystemExit) as exit_:
        main([*words, "--out", " "])  # was the current folder
    assert exit_.value.code == EXIT_INPUT
    assert capsys.readouterr().err.splitlines()[-1].endswith("error: argument --out: expected a folder, got an empty "
                                                             "name")


@pytest.mark.parametrize("name", ["tpu", "meta", "", "cpu:-1", "gpu"])
@pytest.mark.parametrize("command", ["fit", "render"])
def test_a_device_the_backend_does_not_run_on_is_refused_before_any_work(tmp_path, capsys, name, command):
    """Was taken by fit up to the fit itself (after the photos were loaded), where torch failed: an
    internal error, exit 1; render failed the same way at once."""
    words = ["fit", "R.png", "T.png"] if command == "fit" else ["render", EXAMPLE_PARAMS]
    assert main([*words, "--out", str(tmp_path / "out"), "--device", name]) == EXIT_INPUT
    assert capsys.readouterr().err.splitlines() == [
        f"error: --device {name!r}: not a device the backend runs on (expected cpu, cuda or cuda:N)"]
    assert not (tmp_path / "out").exists()


def test_a_cuda_device_this_machine_lacks_is_refused(tmp_path, capsys):
    missing = torch.cuda.device_count()  # the first index past this machine's devices (none: CUDA missing)
    assert main(["fit", "R.png", "T.png", "--out", str(tmp_path / "out"), "--device", f"cuda:{missing}"]) == EXIT_INPUT
    reason = f"this machine has {missing} CUDA device(s)" if torch.cuda.is_available() else "CUDA is not available"
    assert capsys.readouterr().err.startswith(f"error: --device cuda:{missing}: {reason}")


# -- photos -------------------------------------------------------------------------------------------

def photo_pair(tmp_path, encoding="png8", names=("cloth_R", "cloth_T")) -> tuple:
    """The fuzz harness's base pair (96 px) in ``encoding``."""
    suffix, encode = ENCODINGS[encoding]
    paths = tuple(tmp_path / f"{name}{suffix}" for name in names)
    for path, image in zip(paths, base_pair()):
        path.write_bytes(encode(image))
    return paths


@pytest.mark.parametrize("how", ["the same file twice", "a copy", "the same pixels as PNG and TIFF"])
def test_the_same_image_twice_is_refused(tmp_path, how):
    """Was fitted, exit 0, without a word (issue 91)."""
    reflection, transmission = photo_pair(tmp_path)
    if how == "a copy":
        transmission.write_bytes(reflection.read_bytes())
    elif how == "the same pixels as PNG and TIFF":
        transmission = tmp_path / "cloth_T.tif"
        transmission.write_bytes(ENCODINGS["tiff8"][1](base_pair()[0]))
    else:
        transmission = reflection
    with pytest.raises(PhotoError) as error:
        load_pair(reflection, transmission, size=FILM)
    assert str(error.value) == (f"{reflection} / {transmission}: the two photos are the same image (the same pixels "
                                "once decoded): give the reflection photo (front light) and the transmission photo "
                                "(back light)")


@pytest.mark.parametrize("side", [0, 1])
def test_one_photo_saved_again_otherwise_reads_as_two_photos_in_one_light(tmp_path, side):
    """Not the same pixels (a JPEG of the PNG), so not refused as the same image: the order check
    flags it, as two photos lit from the front (or both from behind)."""
    paths = photo_pair(tmp_path)
    copy = tmp_path / "copy.jpg"
    copy.write_bytes(ENCODINGS["jpeg"][1](base_pair()[side]))
    pair = (paths[0], copy) if side == 0 else (copy, paths[1])
    with pytest.raises(PhotoError, match="the photos may be swapped"):
        load_pair(*pair, size=FILM, strict=True)
    assert load_pair(*photo_pair(tmp_path), size=FILM, strict=True).warnings == []  # the pair itself is fine


@pytest.mark.parametrize("encoding", ["exr", "tiff-float"])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_a_float_photo_with_non_finite_pixels_is_refused_with_their_count(tmp_path, encoding, value):
    """Was fitted without a word (issue 91: 300 NaN in an EXR reflection; FLIP 0.23 / 0.25): NaN
    became 0, infinities 1e6, which set the pair's exposure and left the other photo black."""
    reflection, transmission = photo_pair(tmp_path, encoding)
    image = base_pair()[0].copy()
    flat = image.reshape(-1, 3)
    flat[np.random.default_rng(1).choice(len(flat), 300, replace=False), 1] = value
    reflection.write_bytes(ENCODINGS[encoding][1](image))
    with pytest.raises(PhotoError) as error:
        load_pair(reflection, transmission, size=FILM)
    assert str(error.value) == (f"{reflection}: 300 of its {96 * 96} pixels hold NaN or infinite values, which no "
                                "camera gives (a broken export?): export the photo again")
    with pytest.raises(PhotoError, match="300 of its"):  # as a flat-field too
        load_pair(*photo_pair(tmp_path, "png8"), size=FILM, flat_field=reflection)


def test_negative_linear_values_are_clipped_not_refused(tmp_path):
    reflection, transmission = photo_pair(tmp_path, "exr")
    image = base_pair()[0].copy()
    image[:4, :4] = -0.01  # noise about the black level of a linear export
    reflection.write_bytes(ENCODINGS["exr"][1](image))
    pair = load_pair(reflection, transmission, size=FILM)
    assert pair.reflection.min() >= 0 and np.isfinite(pair.reflection).all()


@pytest.mark.parametrize("encoding", ["png8", "jpeg", "tiff16", "exr"])
@pytest.mark.parametrize("width, height", [(20000, 15000), (65535, 65535)])
def test_a_huge_declared_size_over_little_data_is_refused_before_decoding(tmp_path, monkeypatch, encoding, width,
                                                                          height):
    """A decompression bomb: OpenCV allocated what the header declared (2.7-12 GB) before finding the
    data short; some decoded, some failed for want of memory."""
    reflection, transmission = photo_pair(tmp_path, encoding)
    reflection.write_bytes(with_declared_size(reflection.read_bytes(), encoding, width, height))
    monkeypatch.setattr(decode.cv2, "imdecode", lambda *args: pytest.fail("decoded a bomb"))
    with pytest.raises(PhotoError) as error:
        load_pair(reflection, transmission, size=FILM)
    assert str(error.value) == (f"{reflection}: the file declares {width} x {height} pixels, more than any camera's "
                                f"photo (at most {MAX_SOURCE_PIXELS // 1_000_000} million): a damaged file?")


def test_the_largest_photos_cameras_take_pass_the_size_check(tmp_path):
    reflection, _ = photo_pair(tmp_path)
    phone = with_declared_size(reflection.read_bytes(), "png8", 16320, 12240)  # a 200-megapixel phone's photo
    assert check_structure(phone, "png", reflection) == 1


def test_thousands_of_unknown_keys_are_listed_in_one_line(tmp_path):
    """Each was listed: a rig file with 20000 of them gave a line of 250000 characters."""
    path = tmp_path / "rig.json"
    path.write_text(json.dumps({f"extra_{index:05d}": 1.0 for index in range(20000)}))
    with pytest.raises(RigError, match=rf"^{path}: rig: unknown setting\(s\) extra_00000, extra_00001, extra_00002, "
                                       r"extra_00003, extra_00004 and 19995 more; known: back_intensity, "):
        CaptureRig.load(path)
    params = write_params(tmp_path, pattern="custom", weave={"matrix": [[0, 1], [1, 0]], "x" * 100: 1, "y": 2})
    with pytest.raises(ParamError, match=rf"^{params}: weave: unknown key\(s\) 'xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx"
                                         r"\.\.\. \(str of 100\), y$"):
        load_params(params)
