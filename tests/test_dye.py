"""Colour as dye and yarn-dyed patterns without Blender: the sett texts (core/sett.py), the dye's rules
(core/dye.py), and the standard-node fallback's colour program (core/shader_dye.py) against them,
evaluated on numpy arrays as its nodes compute it. The renders are in tests/test_material_blender.py."""
from __future__ import annotations

import colorsys
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from fallback_numpy import NumpyBuilder, fallback_env, hue_saturation_value, rig_points  # noqa: E402

from backend.core.params import FabricParams  # noqa: E402
from backend.core.rig import DEFAULT_RIG  # noqa: E402
from backend.core.weave import PRESETS  # noqa: E402
from backend.model.geometry import tile_coordinates  # noqa: E402
from backend.model.layers import WeaveLookup  # noqa: E402
from blender_addon.core import asset_catalogs, dye, sett, shader_fallback  # noqa: E402

# A twill fitted to a khaki photo: the colour in the specular albedos, the diffuse ones near zero.
KHAKI = FabricParams(pattern="twill0", tiles=(60.0, 30.0), roughness=(0.5, 0.2), thickness=(4.9, 5.0),
                     specular_albedo=((1.0, 1.0, 0.43), (0.63, 0.57, 0.23)), multiple_weight=1.08,
                     diffuse_reflection=(0.058, 0.030, 0.038), diffuse_transmission=(0.1, 0.049, 0.002)).to_dict()


def hue_deg(rgb) -> float:
    return colorsys.rgb_to_hsv(*rgb)[0] * 360.0


# -- setts -----------------------------------------------------------------------------------------

def test_a_sett_is_read_as_weavers_write_it():
    warp, weft = sett.parse_pair("W8 R8")
    assert [(s.code, s.threads) for s in warp] == [("W", 8), ("R", 8)] and weft == warp  # square sett
    red = sett.srgb_to_linear(0xC8 / 255.0)
    assert warp[1].colour[0] == pytest.approx(red)
    tartan = sett.parse("B/24 K4 G/24")  # symmetric: there and back, each pivot once
    assert [(s.code, s.threads) for s in tartan] == [("B", 24), ("K", 4), ("G", 24), ("K", 4)]
    assert [(s.code, s.threads) for s in sett.parse("K2 k3, #ff0000/1".replace("/", ""))] == [("K", 5), ("#FF0000", 1)]
    assert sett.parse("F24 W2")[0].colour is None  # the fitted colour
    assert sett.parse("") == ()
    for preset, (label, warp_text, weft_text) in sett.PRESETS.items():
        warp, weft = sett.parse_pair(warp_text, weft_text)
        assert 0 < len(warp) <= sett.STRIPES and 0 < len(weft) <= sett.STRIPES, preset


@pytest.mark.parametrize("text, message", [
    ("Q4", "unknown colour code 'Q'"), ("K", "is not a stripe"), ("K0", "1 to 9999 threads"),
    ("K/4 W4", "first and last"), (" ".join(f"{c}1" for c in "KWKWKWKWKWKWK"), "at most 12"),
])
def test_a_bad_sett_says_what_is_wrong(text, message):
    with pytest.raises(sett.SettError, match=message):
        sett.parse(text)
    with pytest.raises(sett.SettError, match="^weft sett: "):
        sett.parse_pair("W4", text)


def test_yarn_colours_repeat_with_the_sett():
    stripes = sett.parse("W2 R3")
    white, red = stripes[0].colour, stripes[1].colour
    assert sett.yarn_colours(stripes, range(-2, 7)) == [red, red, white, white, red, red, red, white, white]
    assert sett.yarn_colours((), [0, 5]) == [None, None]


# -- the dye's rules --------------------------------------------------------------------------------

def test_the_base_colour_is_the_rendered_colour_not_the_diffuse_albedo():
    """C0 weighs the specular albedos in: the khaki twill (diffuse albedo near zero, bluish-grey) is
    beige, as its renders are, and its asset is tagged so."""
    base = dye.base_colour(KHAKI)
    assert 35 < hue_deg(base) < 60 and 0.3 < max(base) < 0.6  # khaki (linear), as its renders are
    assert asset_catalogs.colour_name(KHAKI["diffuse_reflection"]) != "beige"
    assert asset_catalogs.tags(KHAKI)[-1] == asset_catalogs.colour_name(base) == "beige"


def test_painting_red_dyes_red_and_the_fitted_colour_changes_nothing():
    base = dye.base_colour(KHAKI)
    albedos = [*KHAKI["specular_albedo"], KHAKI["diffuse_reflection"], KHAKI["diffuse_transmission"]]
    red = dye.dye_factor((1.0, 0.0, 0.0), base, albedos)
    assert red[0] > 0 and red[1:] == (0.0, 0.0)
    assert max(red[0] * k[0] for k in albedos) <= 1.0 + 1e-12  # capped: no albedo past 1
    assert dye.dye_factor(base, base, albedos) == pytest.approx((1.0, 1.0, 1.0), abs=1e-12)
    assert dye.target_colour(None, base) == pytest.approx(base, abs=1e-12)  # undyed, no recolour, white map
    # A replacing map dyes to its colour, a multiplying one stains.
    assert dye.target_colour(None, base, colour_map=(0.2, 0.4, 0.6), replace=1.0) == pytest.approx((0.2, 0.4, 0.6))
    assert dye.target_colour(None, base, colour_map=(1.0, 0.5, 0.0)) == pytest.approx((base[0], base[1] / 2, 0.0))


def test_the_recolour_is_blenders_hue_saturation_value_node():
    rng = np.random.default_rng(5)
    colours = rng.uniform(0, 1, (3, 200))
    for hue, saturation, value in ((0.0, 1.0, 1.0), (120.0, 0.5, 1.5), (-75.0, 2.0, 0.3)):
        mine = np.array([dye.recolour(tuple(c), hue, saturation, value) for c in colours.T]).T
        node = hue_saturation_value(colours, 0.5 + hue / 360.0, saturation, value)
        np.testing.assert_allclose(mine, node, atol=1e-12)
    assert hue_deg(dye.recolour((0.46, 0.42, 0.2), 180.0)) == pytest.approx(hue_deg((0.46, 0.42, 0.2)) + 180.0)


# -- the fallback's colour program ----------------------------------------------------------------

def _program_at(params: dict, extra: dict, S: int = 3000, seed: int = 3):
    rng = np.random.default_rng(seed)
    x, y, wi = rig_points(rng, S)
    return x, y, shader_fallback.run(NumpyBuilder(), fallback_env(params, x, y, wi, extra))


def test_yarn_indices_count_the_weaves_columns_and_rows():
    """The program's global yarn indices fall on the backend's columns and rows of the weave (so a
    stripe changes colour exactly between two yarns) for every preset."""
    for name, weave in PRESETS.items():
        params = dict(KHAKI, pattern=name, tiles=[23.0, 17.0])
        x, y, out = _program_at(params, {})
        lookup = WeaveLookup(weave)
        X, Y, _, _ = tile_coordinates(torch.tensor(x), torch.tensor(y), DEFAULT_RIG, (23.0, 17.0), lookup)
        bands = lookup.bands(X, Y)
        assert (np.mod(out["warp_index"], weave.cols) == bands.warp["index"].numpy()).all(), name
        assert (np.mod(out["weft_index"], weave.rows) == bands.weft["index"].numpy()).all(), name


def test_the_fallback_dyes_each_yarn_as_the_rules_say():
    """Gingham stripes, a hue shift and a half-replacing colour map: each point's dyed k_s, k_m of
    both yarn directions and its front yarn's diffuse albedo are core/dye.py's."""
    warp, weft = sett.parse_pair("W3 R2 F1", "G2 F3")
    base = dye.base_colour(KHAKI)
    extra = dict(sett.socket_values(warp, weft, base), **{"recolour hue": 30.0, "recolour saturation": 0.8,
                                                          "recolour value": 1.1, "colour map": (0.9, 0.6, 0.3),
                                                          "colour map replace": 0.5})
    x, y, out = _program_at(KHAKI, extra)
    km = [dye.multiple_albedo(k, KHAKI["multiple_weight"]) for k in KHAKI["specular_albedo"]]
    kd_max = np.maximum(KHAKI["diffuse_reflection"], KHAKI["diffuse_transmission"])
    for yarn, stripes, name in ((0, warp, "warp"), (1, weft, "weft")):
        indices = out[f"{name}_index"].astype(int)
        for i in np.unique(indices)[:40]:
            colour = sett.yarn_colours(stripes, [i])[0]
            target = dye.target_colour(colour, base, (30.0, 0.8, 1.1), (0.9, 0.6, 0.3), 0.5)
            albedo = np.maximum(np.maximum(KHAKI["specular_albedo"][yarn], km[yarn]), kd_max)
            factor = dye.dye_factor(target, base, [albedo])
            at = np.flatnonzero(indices == i)[0]
            np.testing.assert_allclose(out[f"ks_{name}"][:, at], dye.dyed(KHAKI["specular_albedo"][yarn], factor),
                                       rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(out[f"km_{name}"][:, at], dye.dyed(km[yarn], factor), rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(out[f"{name}_dye"][:, at], factor, rtol=1e-9, atol=1e-12)
    front_warp = out["y0w"] > 0.5
    np.testing.assert_allclose(out["kd_r"][:, front_warp],
                               np.asarray(KHAKI["diffuse_reflection"])[:, None] * out["warp_dye"][:, front_warp])


def test_without_a_dye_the_fallback_keeps_the_fitted_albedos():
    """The default sockets (no stripes, no recolour, white map) dye nothing: every albedo as fitted,
    to float precision."""
    _, _, out = _program_at(KHAKI, {})
    for name, yarn in (("warp", 0), ("weft", 1)):
        np.testing.assert_allclose(out[f"{name}_dye"], 1.0, rtol=1e-12)
        np.testing.assert_allclose(out[f"ks_{name}"][:, 0], KHAKI["specular_albedo"][yarn], rtol=1e-12)
