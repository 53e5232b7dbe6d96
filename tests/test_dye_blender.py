"""Colour as dye and yarn-dyed patterns in Blender (the installed extension, bpy subprocesses, small
renders of the capture rig): a painted colour layer dyes the cloth in Cycles with OSL, in Cycles'
standard-node fallback and in EEVEE; the recolour turns the cloth's hue; the sett presets and texts
weave checks and plaids, the same in OSL and the fallback; the node group builds without warnings.
The rules themselves are tested without Blender in tests/test_dye.py."""
from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from addon_support import extension_zip_for_tests, require_bpy  # noqa: E402
from test_addon_blender import run_bpy  # noqa: E402
from test_dye import KHAKI  # noqa: E402

pytestmark = pytest.mark.blender

HUE_TOLERANCE_DEG = 10  # the bound on a painted colour's rendered hue
# The fitted colour painted back on a Replace layer changes a channel by at most this share: the
# 8-bit layer's rounding in Cycles (measured 0.1 %); EEVEE measured 2.0 % in the khaki's dark blue
# channel (its lowest). Most of that is the painted half's edge: EEVEE's filtering of the 512-px layer
# carries the unpainted half past the margin at this size (the whole layer painted back: 0.5 % at a
# 24-px render, 0.7 % at 96 px; the left half: 2.0 % and 1.3 %); the whole layer's 0.5 % is not explained.
PAINTED_BACK_CHANGE = {"osl": 0.01, "fallback": 0.01, "eevee": 0.03}

def _scene(size: int) -> str:
    """The rig scene (``size`` pixels) with the khaki fabric, and helpers to render and read hues."""
    return f"""
import colorsys
import numpy as np
SIZE = {size}
node_group = ext.scene.node_group
rig_scene = importlib.import_module(ext.__name__ + ".scene.rig_scene")
colour_layer = importlib.import_module(ext.__name__ + ".scene.colour_layer")
material = node_group.create_material("khaki", {KHAKI!r})
scene = rig_scene.build_scene(material, size=SIZE, samples=4, scene=bpy.context.scene, threads=1)
fabric = rig_scene.rig_object(scene, "fabric")
bpy.context.view_layer.objects.active = fabric
fabric.select_set(True)

def render(engine):
    rig_scene.set_engine(scene, engine, 4 if engine != "eevee" else 2)
    return rig_scene.render_linear(scene, "front")[..., :3].astype(np.float64)

def hue(rgb):
    h, s, v = colorsys.rgb_to_hsv(*(float(c) for c in rgb))
    return h * 360.0, s

def srgb(linear):
    return [c * 12.92 if c <= 0.0031308 else 1.055 * c ** (1 / 2.4) - 0.055 for c in linear]
"""


@pytest.fixture(scope="module")
def extension_zip(tmp_path_factory) -> Path:
    return extension_zip_for_tests(tmp_path_factory.mktemp("dist"))


def run(tmp_path, extension_zip, body: str, size: int = 24) -> dict:
    """``body`` after the rig scene with the khaki fabric (``size`` pixels) is built; returns what it
    printed as ``RESULT <json>``."""
    output = run_bpy(tmp_path, extension_zip, _scene(size) + textwrap.dedent(body), timeout=1800)
    return json.loads(next(line[7:] for line in output.splitlines() if line.startswith("RESULT ")))


@pytest.mark.slow
def test_painted_red_dyes_the_cloth_red_and_the_fitted_colour_changes_nothing(tmp_path, extension_zip):
    """A Replace colour layer painted pure red on the left half renders red cloth there (hue within
    HUE_TOLERANCE_DEG of the paint's, saturated) in Cycles with OSL, the fallback and EEVEE, and the
    right half as it was; painted with the fabric's base colour instead, the render does not change
    (within the 8-bit layer's rounding). A Multiply layer of pure red dyes red too."""
    result = run(tmp_path, extension_zip, """
        unlayered = render("osl")
        assert bpy.ops.fabric.add_colour_layer(mode="REPLACE", paint=False) == {"FINISHED"}
        layer = next(im for im in bpy.data.images if im.get("woven_fabric_colour_layer") == "REPLACE")
        out = {"new_layer_change": float(np.abs(render("osl") - unlayered).max() / unlayered.max())}
        w, h = layer.size
        base = colour_layer.base_colour(material)
        def paint(rgb):
            px = np.zeros((h, w, 4), np.float32)
            px[:, : w // 2] = (*srgb(rgb), 1.0)  # the left half of the UV square, opaque
            layer.pixels.foreach_set(px.ravel())
        # u < 0.5 is the left 15 of 24 columns; two columns each side of the edge hold the camera blur
        left, right = slice(0, SIZE // 2 - 2), slice(SIZE // 2 + 5, SIZE)
        for engine in ("osl", "fallback", "eevee"):
            layer.pixels.foreach_set(np.zeros(w * h * 4, np.float32))  # unpainted: transparent
            plain = render(engine)
            paint((1.0, 0.0, 0.0))
            red = render(engine)
            paint(base)
            back = render(engine)
            plain_left, red_left, back_left = (img[:, left].mean((0, 1)) for img in (plain, red, back))
            out[engine] = {"plain": plain_left.tolist(), "red": red_left.tolist(), "red_hue": hue(red_left),
                           "right_change": float(np.abs(red[:, right] - plain[:, right]).max() / plain.max()),
                           "back_change": np.abs(back_left / plain_left - 1).tolist()}
        layer.pixels.foreach_set(np.zeros(w * h * 4, np.float32))
        assert bpy.ops.fabric.add_colour_layer(mode="MULTIPLY", paint=False) == {"FINISHED"}
        stain = next(im for im in bpy.data.images if im.get("woven_fabric_colour_layer") == "MULTIPLY")
        px = np.ones((h, w, 4), np.float32); px[..., 1:3] = 0.0
        stain.pixels.foreach_set(px.ravel())
        out["multiply_hue"] = hue(render("osl").mean((0, 1)))
        print("RESULT " + json.dumps(out))
    """)
    assert result["new_layer_change"] < 1e-3, result  # a new, transparent Replace layer changes nothing
    for engine in ("osl", "fallback", "eevee"):
        figures = result[engine]
        (red_hue, saturation) = figures["red_hue"]
        assert min(red_hue, 360 - red_hue) <= HUE_TOLERANCE_DEG and saturation > 0.95, (engine, figures)
        assert figures["red"][0] > 0.3 * sum(figures["plain"]) / 3, (engine, figures)  # red cloth, not black
        assert figures["right_change"] < 1e-3, (engine, figures)
        assert max(figures["back_change"]) < PAINTED_BACK_CHANGE[engine], (engine, figures)
    multiply_hue, saturation = result["multiply_hue"]
    assert min(multiply_hue, 360 - multiply_hue) <= HUE_TOLERANCE_DEG and saturation > 0.95, result


def test_recolour_and_yarn_dyed_setts(tmp_path, extension_zip):
    """The panel's controls on the khaki fabric: the hue shift turns the rendered hue by as much (OSL);
    the gingham preset writes its sett, and a gingham sett weaves a check (red and white blocks) that
    the OSL shader and the fallback draw alike; a bad sett text is refused with its reason and changes
    nothing; the panel draws."""
    result = run(tmp_path, extension_zip, """
        from types import SimpleNamespace
        inputs = ext.scene.group_interface.input_sockets(node_group.group_node(material))
        out = {"plain_hue": hue(render("osl").mean((0, 1)))[0]}
        inputs["recolour hue"].default_value = 120.0
        out["turned_hue"] = hue(render("osl").mean((0, 1)))[0]
        inputs["recolour hue"].default_value = 0.0

        assert bpy.ops.fabric.sett_preset(preset="GINGHAM") == {"FINISHED"}
        pattern = material.woven_fabric_pattern
        out["texts"] = [pattern.warp, pattern.weft, pattern.problem]
        out["threads"] = [inputs[f"warp stripe {k} threads"].default_value for k in (1, 2, 3)]
        pattern.warp = "W40 R40"  # a check of 13 x 27 pixels here (240 warps, 120 wefts per UV unit)
        check = {engine: render(engine) for engine in ("osl", "fallback")}
        blocks = {e: img.reshape(SIZE // 4, 4, SIZE // 4, 4, 3).mean((1, 3)) for e, img in check.items()}
        reddish = {e: float((b[..., 0] > 1.6 * b[..., 1]).mean()) for e, b in blocks.items()}
        whitish = {e: float((b[..., 0] < 1.2 * b[..., 1]).mean()) for e, b in blocks.items()}
        agree = float(np.corrcoef((blocks["osl"][..., 0] / blocks["osl"][..., 1]).ravel(),
                                  (blocks["fallback"][..., 0] / blocks["fallback"][..., 1]).ravel())[0, 1])
        out.update(reddish=reddish, whitish=whitish, agree=agree)

        pattern.warp = "W8 Q8"
        out["bad"] = [pattern.problem, inputs["warp stripe 2 threads"].default_value]  # still the check's
        drawn = []
        class Layout:
            def __getattr__(self, name):
                def call(*args, **kw):
                    drawn.append((name, kw.get("text", "")))
                    return Layout()
                return call
        ext.ui.material_panel.VIEW3D_PT_woven_fabric_colour.draw(SimpleNamespace(layout=Layout()), bpy.context)
        out["drawn"] = drawn
        assert bpy.ops.fabric.sett_preset(preset="NONE") == {"FINISHED"}
        out["none"] = sum(inputs[f"warp stripe {k} threads"].default_value for k in range(1, 13))
        print("RESULT " + json.dumps(out))
    """, size=32)
    turn = (result["turned_hue"] - result["plain_hue"]) % 360
    assert abs(turn - 120) <= HUE_TOLERANCE_DEG, result
    assert result["texts"] == ["W8 R8", "", ""] and result["threads"] == [8, 8, 0]
    for engine in ("osl", "fallback"):
        assert 0.15 < result["reddish"][engine] < 0.85 and result["whitish"][engine] > 0.1, result
    assert result["agree"] > 0.8, result
    assert result["bad"][0].startswith("warp sett: unknown colour code 'Q'") and result["bad"][1] == 40, result
    assert ["operator", "Gingham"] in result["drawn"] and ["label", result["bad"][0]] in result["drawn"], result
    assert result["none"] == 0


def test_the_node_group_builds_without_osl_warnings(tmp_path):
    """Building the group compiles the OSL shader; the compiler says nothing (the noise parameter no
    longer hides OSL's noise function)."""
    require_bpy()
    script = tmp_path / "build.py"
    script.write_text(f"import sys\nsys.path.insert(0, {str(ROOT)!r})\nimport bpy\n"
                      "from blender_addon.scene import node_group\n"
                      "group = node_group.ensure_node_group()\n"
                      "print('ERROR' if group.get('woven_fabric_osl_error') else 'BUILT')\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    output = done.stdout + done.stderr
    assert done.returncode == 0 and "BUILT" in output, output[-3000:]
    assert "warning" not in output.lower() and "already declared" not in output, output[-3000:]
