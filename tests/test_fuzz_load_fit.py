"""The add-on's half of the fuzz harness (issue 91): the fuzz harness's params.json cases read as the
add-on reads a fit (Load Fit, a cancelled fit, the batch's ``--from-results``), without bpy.

Every crafted file is either a fit the shader can draw (its socket values finite and in the declared
ranges) or a ValueError that names the file and the problem, raised before anything is made from it.
"""
import json
import math

import pytest

from blender_addon.core import captures, shader_params
from devtools.fuzz.cases import REFUSE
from devtools.fuzz.documents import params_cases

SEED = 91  # any fixed seed gives a fixed set of cases
COUNT = 160


def _socket_numbers(values: dict) -> list[float]:
    return [float(x) for v in values.values() for x in (v if isinstance(v, tuple) else (v,))]


def test_a_crafted_params_json_is_a_drawable_fit_or_one_error_naming_the_file(tmp_path):
    outcomes = {"read": 0, "refused": 0}
    for index, case in enumerate(params_cases(COUNT, SEED)):
        folder = tmp_path / str(index)
        folder.mkdir()
        (name, data), = case.files
        path = folder / name
        path.write_bytes(data)
        try:
            params = captures.read_fit_params({"params": str(path)})
        except ValueError as exc:
            assert str(exc).startswith(f"{path}: ") and "\n" not in str(exc), (case.label, exc)
            outcomes["refused"] += 1
            continue
        assert case.expect != REFUSE, f"{case.label}: read, but the backend refuses it"
        numbers = _socket_numbers(shader_params.socket_values(params))
        assert all(math.isfinite(x) for x in numbers), case.label
        outcomes["read"] += 1
    assert outcomes["read"] and outcomes["refused"], outcomes  # both ends are reached


@pytest.mark.parametrize("change, named", [
    ({"roughness": [float("nan"), 0.5]}, "roughness"),
    ({"roughness": [7.0, 0.5]}, "roughness"),               # out of range: refused, not clamped
    ({"tiles": "many"}, "tiles"),
    ({"pattern": "satin9"}, "pattern"),
    ({"pattern": "custom", "weave": {"matrix": [[0, 1], [1, 0]]}}, "pattern"),  # the shader draws presets
    ({"rig": "the paper's"}, "rig"),
    ({"rig": {"film_size": -4}}, "film_size"),
])
def test_load_fit_refuses_what_the_shader_cannot_draw(tmp_path, change, named):
    from fake_backend import fake_params

    path = tmp_path / "params.json"
    path.write_text(json.dumps({**fake_params("linen"), **change}))
    with pytest.raises(ValueError) as refused:
        captures.read_fit_params({"params": str(path)})
    assert str(refused.value).startswith(f"{path}: not a fit's parameters: ") and named in str(refused.value)
