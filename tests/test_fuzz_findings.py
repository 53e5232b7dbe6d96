"""The defects the fuzz harness (devtools/fuzz, tests/test_fuzz.py) found, each now refused with one
clear line naming the file or option and the problem (issue 91)."""
import json

import pytest

from backend.core.jsonfile import read_json
from backend.core.params import FabricParams, ParamError, load_params
from backend.core.rig import CaptureRig, RigError


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
