"""Parameters: the declaration, validation, clamping, JSON and the interchange string."""
import json

import pytest
import torch

from backend.core.params import PARAMETERS, SPECS, FabricParams, ParamError, load_params
from backend.core.weave import Weave
from backend.model.param_tensors import ParamTensors

EXAMPLE = ("twill1_R_0.6,0.66_S_0.75,1.53_T_1.33,1.39_N_0.0_UV_121.8,168.9_Kd_0.456,0.398,0.089,0.286,0.279,0.0"
           "_G_0.99,1.0_Rm_0.65,0.62_Tm_2.66,0.79_W_0.71,1.29_Ks_0.325,0.37,0.0,0.351,0.883,0.0_Psi_-30.5,-29.5")


def test_interchange_string_maps_to_the_spec_names():
    p = FabricParams.from_interchange(EXAMPLE)
    assert p.pattern == "twill1"
    assert p.roughness == (0.6, 0.66)
    assert p.height_scale == (0.75, 1.53)
    assert p.thickness == (1.33, 1.39)
    assert p.tiles == (121.8, 168.9)
    assert p.diffuse_reflection == (0.456, 0.398, 0.089)
    assert p.diffuse_transmission == (0.286, 0.279, 0.0)
    assert p.gap_scale == (0.99, 1.0)
    assert p.roughness_multiple == (0.65, 0.62)
    assert p.thickness_multiple == (2.66, 0.79)
    assert (p.diffuse_normal_weight, p.multiple_weight) == (0.71, 1.29)
    assert p.specular_albedo == ((0.325, 0.37, 0.0), (0.351, 0.883, 0.0))
    assert p.twist_deg == (-30.5, -29.5)
    assert p.noise == 0.0


def test_interchange_round_trip_is_exact():
    p = FabricParams.from_interchange(EXAMPLE)
    assert p.to_interchange() == EXAMPLE
    assert FabricParams.from_interchange(p.to_interchange()) == p


def test_every_golden_case_parses(golden_cases):
    for case in golden_cases:
        p = FabricParams.from_interchange(case["params"])
        assert FabricParams.from_interchange(p.to_interchange()) == p


def test_json_round_trip_and_extra_keys():
    p = FabricParams.from_interchange(EXAMPLE)
    data = json.loads(p.to_json(units="scene", version=1))
    assert data["specular_albedo"] == [[0.325, 0.37, 0.0], [0.351, 0.883, 0.0]]
    assert data["tiles"] == [121.8, 168.9]
    assert FabricParams.from_dict(data) == p


def test_custom_weave_round_trips_through_json():
    weave = Weave("basket", ((1, 1, 0, 0), (1, 1, 0, 0), (0, 0, 1, 1), (0, 0, 1, 1)))
    p = FabricParams(pattern="custom", weave=weave)
    back = FabricParams.from_dict(json.loads(p.to_json()))
    assert back.resolved_weave.matrix == weave.matrix
    assert back == p


@pytest.mark.parametrize("field,value", [("roughness", (0.0, 0.5)), ("thickness", (1.0, 9.0)),
                                         ("tiles", (0.5, 100.0)), ("multiple_weight", 3.0),
                                         ("diffuse_reflection", (0.2, 1.5, 0.1)), ("noise", -1.0)])
def test_out_of_range_values_name_the_field_and_range(field, value):
    with pytest.raises(ParamError) as err:
        FabricParams(**{field: value})
    assert field in str(err.value)
    spec = SPECS[field]
    assert f"[{spec.lo:g}, {spec.hi:g}]" in str(err.value)


@pytest.mark.parametrize("field,value,needle", [("roughness", 0.5, "pair"), ("specular_albedo", (0.1, 0.2), "RGB"),
                                                ("diffuse_reflection", "red", "triple"),
                                                ("thickness", (1.0, None), "not a number"),
                                                ("multiple_weight", float("nan"), "outside")])
def test_malformed_values_raise_clear_errors(field, value, needle):
    with pytest.raises(ParamError, match=needle):
        FabricParams(**{field: value})


def test_unknown_pattern_and_missing_custom_weave():
    with pytest.raises(ParamError, match="unknown weave 'satin9'"):
        FabricParams(pattern="satin9")
    with pytest.raises(ParamError, match="custom"):
        FabricParams(pattern="custom")


def test_interchange_errors_name_the_key():
    with pytest.raises(ParamError, match="missing key"):
        FabricParams.from_interchange("plain_R_0.5,0.5")
    with pytest.raises(ParamError, match="key UV needs 2 numbers"):
        FabricParams.from_interchange(EXAMPLE.replace("UV_121.8,168.9", "UV_121.8"))
    with pytest.raises(ParamError, match="key R: 'a,b' is not a list of numbers"):
        FabricParams.from_interchange(EXAMPLE.replace("R_0.6,0.66", "R_a,b"))
    with pytest.raises(ParamError, match="unknown key 'Q'"):
        FabricParams.from_interchange(EXAMPLE + "_Q_1")


def test_clamped_pulls_values_into_range():
    p = FabricParams.clamped_from(pattern="plain", roughness=(-1.0, 0.3), tiles=(900.0, 0.1),
                                  specular_albedo=((1.2, 0.5, -0.1), (0.2, 0.2, 0.2)))
    assert p.roughness == (0.01, 0.3)
    assert p.tiles == (400.0, 1.0)
    assert p.specular_albedo[0] == (1.0, 0.5, 0.0)
    with pytest.raises(ParamError, match="non-finite"):
        FabricParams.clamped_from(pattern="plain", thickness=(float("inf"), 1.0))


def test_load_params_reads_files_and_reports_bad_ones(tmp_path):
    good = tmp_path / "p.json"
    good.write_text(FabricParams().to_json())
    assert load_params(str(good)) == FabricParams()
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ParamError, match="bad.json: not valid JSON"):
        load_params(str(bad))
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps({"pattern": "plain", "roughness": [2, 2]}))
    with pytest.raises(ParamError, match="wrong.json: roughness"):
        load_params(str(wrong))
    with pytest.raises(ParamError, match="missing.json: cannot read"):
        load_params(str(tmp_path / "missing.json"))


def test_tensors_clamp_with_the_declared_ranges():
    t = ParamTensors.from_params(FabricParams(), requires_grad=["roughness", "specular_albedo"])
    with torch.no_grad():
        t.roughness.fill_(5.0)
        t.specular_albedo[0, 0] = -2.0
    t.clamp_()
    assert t.roughness.tolist() == [1.0, 1.0]
    assert t.specular_albedo[0, 0].item() == 0.0
    assert t.to_params().roughness == (1.0, 1.0)


def test_declaration_shapes_match_the_dataclass():
    p = FabricParams()
    for spec in PARAMETERS:
        assert len(p.flat(spec.name)) == spec.size, spec.name
        assert spec.lo < spec.hi


def test_load_params_reads_a_full_precision_interchange_string_longer_than_a_file_name():
    # A fit's interchange string carries float32 values at full precision: well over the 255 bytes a
    # file name may have, so asking the file system about it must not be an error.
    p = FabricParams.clamped_from(pattern="twill0", roughness=(0.6742228865623474, 0.1234567890123),
                                  tiles=(125.31483459472656, 63.829593658447266),
                                  thickness=(2.3999743461608887, 1.2345678901234),
                                  diffuse_reflection=(0.3424746096134186, 0.31826329231262207, 0.1652661710))
    text = p.to_interchange()
    assert len(text) > 255
    assert load_params(text) == p


def test_parameters_at_a_bound_are_named_by_component():
    params = FabricParams(roughness=(1.0, 0.3), thickness=(0.01, 2.0),
                          specular_albedo=((0.0, 0.5, 0.2), (0.3, 0.3, 0.3)))
    assert params.at_bounds(["roughness", "thickness", "specular_albedo", "gap_scale"]) == [
        "roughness (warp) = 1 (upper bound)", "thickness (warp) = 0.01 (lower bound)",
        "specular_albedo (warp, r) = 0 (lower bound)"]
    assert FabricParams().at_bounds([s.name for s in PARAMETERS if s.optimised]) == []


def test_a_parameter_at_its_neutral_bound_is_not_at_a_bound():
    """The forward scattering's 0 is the paper's lobe (ParamSpec.neutral): a fit that ends there has not
    run into the range; its other bound is listed like any other."""
    assert FabricParams(forward_scattering=(0.0, 0.9)).at_bounds(["forward_scattering"]) == [
        "forward_scattering (weft) = 0.9 (upper bound)"]



def _read_afresh(t: ParamTensors) -> FabricParams:
    """What to_params gave before it kept host copies: every tensor read now."""
    return FabricParams.clamped_from(pattern=t.pattern, weave=t.weave,
                                     **{n: v.detach().tolist() for n, v in t.values.items()})


def test_host_values_follow_every_in_place_change_of_the_tensors():
    """ParamTensors keeps host copies of the values it read (a GPU fit reads the discrete parameters at
    every step), by tensor version: an optimiser step, a copy_ or an item set is seen at the next read."""
    t = ParamTensors.from_params(FabricParams.from_interchange(EXAMPLE), requires_grad=["roughness"])
    assert t.to_params() == _read_afresh(t) and t.scalar("tiles") == tuple(t.values["tiles"].tolist())
    with torch.no_grad():
        t.values["tiles"].copy_(torch.tensor([50.0, 60.0]))
        t.values["gap_scale"][1] = 0.5
        t.values["noise"].fill_(1.0)
    assert t.scalar("tiles") == (50.0, 60.0) and t.scalar("gap_scale")[1] == 0.5 and t.scalar("noise") == 1.0
    before = t.scalar("roughness")
    optimiser = torch.optim.SGD([t.values["roughness"]], lr=0.1)
    t.values["roughness"].sum().backward()
    optimiser.step()
    assert t.scalar("roughness") != before and t.scalar("roughness") == tuple(t.values["roughness"].tolist())
    assert t.to_params() == _read_afresh(t)  # nested (2, 3) values keep their shape
    other = t.with_values(tiles=torch.tensor([70.0, 80.0]))
    assert other.scalar("tiles") == (70.0, 80.0) and t.scalar("tiles") == (50.0, 60.0)
