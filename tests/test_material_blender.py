"""The material tools inside Blender (the installed extension, bpy subprocesses, small renders):
a painted colour layer changes the render, Set Real-World Scale gives the weave its photographed
period on any mesh, fits are assets with catalogs in the saved file, the weave lookup images are
restored when painted over, the sidebar batch runs in the background with a row per pair, and the
panel says which shader renders.

The backend is tests/fake_backend.py (see test_addon_blender.py, whose helpers these tests share).
"""
from __future__ import annotations

import json
import math
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from addon_support import extension_zip_for_tests  # noqa: E402
from test_addon_blender import FAKE_BACKEND, run_bpy, write_png  # noqa: E402

from backend.core.params import FabricParams  # noqa: E402
from blender_addon.core import shader_params  # noqa: E402

pytestmark = pytest.mark.blender

LOAD_FAKE = f"""
import importlib.util
import pytest
_spec = importlib.util.spec_from_file_location("fake", {str(FAKE_BACKEND)!r})
fake = importlib.util.module_from_spec(_spec); _spec.loader.exec_module(fake)
import numpy as np
node_group = ext.scene.node_group
rig_scene = importlib.import_module(ext.__name__ + ".scene.rig_scene")
"""


@pytest.fixture(scope="module")
def extension_zip(tmp_path_factory) -> Path:
    return extension_zip_for_tests(tmp_path_factory.mktemp("dist"))


def run(tmp_path, extension_zip, body: str, **env) -> str:
    """run_bpy with the fake backend's module (``fake``), numpy, node_group and rig_scene loaded."""
    return run_bpy(tmp_path, extension_zip, LOAD_FAKE + textwrap.dedent(body), **env)


def test_a_painted_colour_layer_changes_the_render(tmp_path, extension_zip):
    """Add Colour Layer (multiply, then replace) on the fabric of the rig scene: the new layer is
    neutral, becomes the active paint slot, and paint in it shows in a Cycles (OSL) render where it
    was painted only."""
    output = run(tmp_path, extension_zip, """
        material = ext.scene.materials.new_fit_material("denim", fake.fake_params("denim"), 5.0)
        scene = rig_scene.build_scene(material, size=24, samples=4, osl=True, scene=bpy.context.scene, threads=1)
        fabric = rig_scene.rig_object(scene, "fabric")
        bpy.context.view_layer.objects.active = fabric
        fabric.select_set(True)
        render = lambda: rig_scene.render_linear(scene, "front")[..., :3]
        before = render()

        assert bpy.ops.fabric.add_colour_layer(mode="MULTIPLY", paint=False) == {"FINISHED"}
        layer = next(im for im in bpy.data.images if im.get("woven_fabric_colour_layer") == "MULTIPLY")
        assert material.texture_paint_images[material.paint_active_slot] == layer
        assert bpy.context.scene.tool_settings.image_paint.canvas == layer
        neutral = render()
        assert np.abs(neutral - before).max() < 1e-3 * before.max(), "a new layer must not change the fabric"
        w, h = layer.size
        px = np.empty(w * h * 4, np.float32); layer.pixels.foreach_get(px); px = px.reshape(h, w, 4)
        assert (px == 1.0).all()  # white, opaque
        px[:, : w // 2, 1:3] = 0.0  # paint the left half of the UV square red
        layer.pixels.foreach_set(px.ravel())
        painted = render()
        # The camera sees u in [0, 0.8] (x in [0, V] of the 10-unit plane): u < 0.5 is the left 15 columns.
        left, right = slice(0, 13), slice(17, 24)
        print("LEFT", neutral[:, left].mean((0, 1)), painted[:, left].mean((0, 1)))
        # The map dyes every albedo by the paint (core/dye.py): green drops, red stays.
        assert painted[:, left, 1].mean() < 0.85 * neutral[:, left, 1].mean()
        assert painted[:, left, 0].mean() == pytest.approx(neutral[:, left, 0].mean(), rel=1e-3)
        assert np.abs(painted[:, right] - neutral[:, right]).max() < 1e-3 * neutral.max()

        # Replace: transparent until painted; where painted (alpha 1) the yarns are dyed to the colour.
        assert bpy.ops.fabric.add_colour_layer(mode="REPLACE", paint=False) == {"FINISHED"}
        cover = next(im for im in bpy.data.images if im.get("woven_fabric_colour_layer") == "REPLACE")
        assert material.texture_paint_images[material.paint_active_slot] == cover
        assert np.abs(render() - painted).max() < 1e-3 * painted.max()
        w, h = cover.size
        px = np.zeros((h, w, 4), np.float32)
        px[h // 2:, :, :] = (0.0, 0.0, 1.0, 1.0)  # paint the top half of the UV square pure blue
        cover.pixels.foreach_set(px.ravel())
        replaced = render()
        top, bottom = slice(0, 8), slice(16, 24)  # image row 0 is v = 1 (the top of the UV square)
        print("TOP", painted[top].mean((0, 1)), replaced[top].mean((0, 1)))
        assert replaced[top, :, 2].mean() > 1.1 * painted[top, :, 2].mean()
        assert replaced[top, :, 0].mean() < 0.9 * painted[top, :, 0].mean()
        assert np.abs(replaced[bottom] - painted[bottom]).max() < 1e-3 * painted.max()
        print("PAINT OK")
    """)
    assert "PAINT OK" in output


def _peak_frequency(image) -> float:
    """Cycles per image of the strongest horizontal periodicity (the gaps between warp yarns)."""
    import numpy as np
    luminance = image.mean(axis=2)
    luminance = luminance - luminance.mean()
    window = np.hanning(luminance.shape[1])[None, :] * np.hanning(luminance.shape[0])[:, None]
    spectrum = np.abs(np.fft.rfft2(luminance * window))
    profile = spectrum[:2].sum(axis=0) + spectrum[-1:].sum(axis=0)  # k_y near 0
    profile[:4] = 0.0
    k = int(np.argmax(profile))
    # Parabolic refinement of the peak.
    a, b, c = profile[k - 1], profile[k], profile[k + 1]
    return k + 0.5 * (a - c) / (a - 2 * b + c)


def test_set_real_world_scale_gives_the_photographed_weave_period(tmp_path, extension_zip):
    """A 4 cm square whose UVs span it once (a UV unit is 4 cm, not the rig's 6.27 cm): after Set
    Real-World Scale its rendered yarn period is the photographed one (plain weave, tiles 40 over a
    5 cm photo: 12.77 yarns per cm), within 2 %."""
    params = FabricParams(pattern="plain", tiles=(40.0, 40.0), gap_scale=(0.5, 0.5), roughness=(0.5, 0.5),
                          diffuse_reflection=(0.8, 0.8, 0.8), specular_albedo=((0.5,) * 3, (0.5,) * 3)).to_dict()
    params["rig"] = {"width_cm": 5.0}
    output = run(tmp_path, extension_zip, f"""
        material = ext.scene.materials.new_fit_material("plain", {json.dumps(params)}, None)
        scene = bpy.context.scene
        for obj in list(scene.objects):
            bpy.data.objects.remove(obj)
        mesh = bpy.data.meshes.new("square")
        mesh.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [(0, 1, 2, 3)])
        uv = mesh.uv_layers.new(name="UVMap")
        for loop, corner in zip(mesh.loops, ((0, 0), (1, 0), (1, 1), (0, 1))):
            uv.data[loop.index].uv = corner
        mesh.materials.append(material)
        square = bpy.data.objects.new("square", mesh)
        square.scale = (0.02, 0.02, 0.02)  # 4 cm across, in metres
        scene.collection.objects.link(square)
        camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
        camera.data.type = "ORTHO"
        camera.data.ortho_scale = 0.04
        camera.location = (0, 0, 0.5)
        scene.collection.objects.link(camera)
        scene.camera = camera
        sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
        sun.data.energy = 3.0
        sun.rotation_euler = (0.3, 0.0, 0.0)
        scene.collection.objects.link(sun)
        scene.world = bpy.data.worlds.new("black")
        scene.world.color = (0, 0, 0)
        scene.render.engine = "CYCLES"
        scene.cycles.shading_system = True
        scene.cycles.device = "CPU"
        scene.cycles.samples = 4
        scene.render.resolution_x = scene.render.resolution_y = 256
        scene.render.threads_mode, scene.render.threads = "FIXED", 1
        scene.view_settings.view_transform = "Standard"
        bpy.context.view_layer.objects.active = square
        square.select_set(True)
        before = rig_scene.render_film(scene)[..., :3]
        assert bpy.ops.fabric.set_real_world_scale() == {{"FINISHED"}}
        after = rig_scene.render_film(scene)[..., :3]
        np.save("before.npy", before)
        np.save("after.npy", after)
        print("UVSCALE", square["woven_fabric_uv_scale"])
    """)
    import numpy as np
    uv_scale = float(next(line.split()[1] for line in output.splitlines() if line.startswith("UVSCALE")))
    rig_unit_cm = shader_params.uv_unit_cm(5.0)                 # 6.267 cm of fabric per rig UV unit
    assert uv_scale == pytest.approx(4.0 / rig_unit_cm, rel=1e-4)
    yarns_per_cm = 2 * 40.0 / rig_unit_cm                         # plain: two warps per repeat
    before = _peak_frequency(np.load(tmp_path / "before.npy"))
    after = _peak_frequency(np.load(tmp_path / "after.npy"))
    assert before == pytest.approx(2 * 40.0, rel=0.02)            # the rig's layout: 40 repeats per UV unit
    assert after == pytest.approx(4.0 * yarns_per_cm, rel=0.02)   # 51.1 yarns over the 4 cm square
    assert 4.0 / after == pytest.approx(1 / yarns_per_cm, rel=0.02)  # the photographed yarn period, in cm
    assert math.isfinite(after)


def test_fits_are_assets_with_catalogs_in_the_saved_file(tmp_path, extension_zip):
    """An interactive fit is a material asset (rendered preview, tags, a catalog named after its weave);
    saving writes the catalog file beside the .blend, and the reopened file has both. A painted-over
    weave lookup image is restored before the save. Register Asset Library adds a library's folder
    to the preferences."""
    photos = tmp_path / "photos"
    photos.mkdir()
    write_png(photos / "linen_R.png", (200, 60, 50))
    write_png(photos / "linen_T.png", (90, 30, 20))
    blend = tmp_path / "scene" / "fabrics.blend"
    blend.parent.mkdir()
    output = run(tmp_path, extension_zip, f"""
        catalogs = ext.core.asset_catalogs
        settings = bpy.context.scene.woven_fabric
        settings.reflection_path = {str(photos / "linen_R.png")!r}
        settings.transmission_path = {str(photos / "linen_T.png")!r}
        bpy.context.preferences.addons[ext.__name__].preferences.results_folder = {str(tmp_path / "fits")!r}
        assert bpy.ops.fabric.fit() == {{"FINISHED"}}
        material = bpy.data.materials[settings.last_material]
        data = material.asset_data
        catalog = catalogs.catalog_path("twill1")
        assert catalog == "Fabrics/Twill (weft-faced)" and data.catalog_id == catalogs.catalog_id(catalog)
        tags = [t.name for t in data.tags]
        colour = catalogs.colour_name(ext.core.dye.base_colour(node_group.read_params(material)))
        assert tags == ["fabric", "woven", "twill1", colour], tags
        pixels = np.empty(96 * 96 * 4, np.float32)
        material.preview.image_pixels_float.foreach_get(pixels)
        assert tuple(material.preview.image_size) == (96, 96) and pixels.reshape(-1, 4)[:, :3].std() > 0.01

        # Paint over a weave lookup image: it is put back before the file is saved.
        atlas = bpy.data.images[ext.scene.fallback_atlases.ATLAS_PREFIX + "warp"]
        good = np.empty(len(atlas.pixels), np.float32); atlas.pixels.foreach_get(good)
        atlas.pixels.foreach_set(np.full_like(good, 0.5))
        bpy.ops.wm.save_as_mainfile(filepath={str(blend)!r})
        restored = np.empty(len(atlas.pixels), np.float32); atlas.pixels.foreach_get(restored)
        assert np.array_equal(restored, good)

        written = catalogs.parse((Path({str(blend)!r}).parent / catalogs.CATALOG_FILE).read_text())
        assert written[catalog] == data.catalog_id and "Fabrics" in written
        name = material.name
        bpy.ops.wm.open_mainfile(filepath={str(blend)!r})
        material = bpy.data.materials[name]
        assert material.asset_data.catalog_id == written[catalog]
        assert [t.name for t in material.asset_data.tags] == tags
        atlas = bpy.data.images[ext.scene.fallback_atlases.ATLAS_PREFIX + "warp"]
        again = np.empty(len(atlas.pixels), np.float32); atlas.pixels.foreach_get(again)
        assert np.array_equal(again, good)

        # A batch library's folder becomes an asset library (once).
        libraries = bpy.context.preferences.filepaths.asset_libraries
        before = len(libraries)
        assert bpy.ops.fabric.register_asset_library(filepath={str(blend)!r}) == {{"FINISHED"}}
        assert bpy.ops.fabric.register_asset_library(filepath={str(blend)!r}) == {{"FINISHED"}}
        assert len(libraries) == before + 1
        assert Path(bpy.path.abspath(libraries[-1].path)).resolve() == Path({str(blend.parent)!r}).resolve()
        refused(bpy.ops.fabric.register_asset_library, "choose a fabric library .blend",
                filepath={str(photos / "linen_R.png")!r})
        print("ASSETS OK")
    """)
    assert "ASSETS OK" in output


def test_sidebar_batch_runs_in_the_background_with_a_row_per_pair(tmp_path, extension_zip):
    """The Batch panel's operator, driven the way Blender drives a modal operator (timer events):
    each tick returns at once, the rows follow the pairs (progress while running, the material when
    done, the reason when failed), Cancel stops the rest. The Material panel says which shader
    renders and its button turns OSL on."""
    photos = tmp_path / "photos"
    photos.mkdir()
    for name, colour in (("linen", (200, 190, 170)), ("wool", (120, 30, 40))):
        write_png(photos / f"{name}_R.png", colour)
        write_png(photos / f"{name}_T.png", tuple(c // 2 for c in colour))
    write_png(photos / "torn_R.png", (10, 10, 10))
    (photos / "torn_T.png").write_text("not an image")
    output = run(tmp_path, extension_zip, f"""
        import faulthandler, signal, time
        from types import SimpleNamespace
        HANG_S = 60
        batch_ui = ext.ui.batch_operators
        bpy.context.preferences.addons[ext.__name__].preferences.results_folder = {str(tmp_path / "fits")!r}
        operator_class = batch_ui.FABRIC_OT_batch_fit_folder

        timer, esc = SimpleNamespace(type="TIMER", value="NOTHING"), SimpleNamespace(type="ESC", value="PRESS")

        drawn = []
        class Layout:  # records what a panel draws
            def __getattr__(self, name):
                def call(*args, **kw):
                    drawn.append((name, kw.get("text", args[0] if args else ""), kw.get("factor")))
                    return Layout()
                return call
        def draw(panel):
            drawn.clear()
            panel.draw(SimpleNamespace(layout=Layout()), bpy.context)
            return list(drawn)

        def tick_while_the_backend_is_stopped(op):
            # A tick reads the backend without waiting on it: with the backend stopped (alive, its pipes
            # open, silent) a tick still returns and the pair still runs.
            queue = batch_ui.batch_job.job
            pid = queue.fit.pid
            os.kill(pid, signal.SIGSTOP)
            faulthandler.dump_traceback_later(HANG_S, exit=True)  # a tick that waited ends the check here
            try:
                assert operator_class.modal(op, bpy.context, timer) == {{"PASS_THROUGH"}}
                assert queue.fit.pid == pid and queue.fit.state == "running"
            finally:
                faulthandler.cancel_dump_traceback_later()
                os.kill(pid, signal.SIGCONT)

        def run(mode, cancel_after=None):
            os.environ["FAKE_BACKEND_MODE"] = mode
            op = StandIn(operator_class)
            batch_ui.batch_job.job = batch_ui.new_batch(bpy.context, {str(photos)!r}).start()
            progress_rows = 0
            for ticks in range(1, 3000):  # a liveness bound (150 s), not a timing
                result = operator_class.modal(op, bpy.context, timer)
                rows = draw(batch_ui.VIEW3D_PT_woven_fabric_batch)
                progress_rows += sum(1 for kind, text, factor in rows if kind == "progress" and factor is not None
                                     and text != batch_ui.batch_job.job.summary())
                if result != {{"PASS_THROUGH"}}:
                    return result, op, ticks, progress_rows
                if cancel_after is not None and ticks == cancel_after:
                    tick_while_the_backend_is_stopped(op)
                    assert operator_class.modal(op, bpy.context, esc) == {{"RUNNING_MODAL"}}
                time.sleep(0.05)
            raise AssertionError("the batch did not end")

        result, op, ticks, progress_rows = run("ok")
        queue = batch_ui.batch_job.job
        states = {{job.name: job.state for job in queue.jobs}}
        assert result == {{"FINISHED"}} and ticks > 3, (result, ticks, op.reports)
        assert states == {{"linen": "done", "torn": "failed", "wool": "done"}}, states
        assert progress_rows > 0, "no progress row while a pair ran"
        for name in ("linen", "wool"):
            assert bpy.data.materials[name].asset_data is not None
        rows = draw(batch_ui.VIEW3D_PT_woven_fabric_batch)
        texts = [text for kind, text, factor in rows if kind == "label"]
        assert "linen" in texts and "Material linen" in texts and "Failed:" in texts, texts
        assert any(t.startswith("torn: Bad input") and "torn_T.png" in t for t in texts), texts
        assert any("torn" in message and "Bad input" in message for kind, message in op.reports)

        result, op, ticks, _ = run("slow", cancel_after=5)
        queue = batch_ui.batch_job.job
        assert result == {{"CANCELLED"}}, result
        assert [job.state for job in queue.jobs] == ["cancelled"] * 3, [job.state for job in queue.jobs]
        assert "wool.001" not in bpy.data.materials and "linen.001" not in bpy.data.materials

        # Which shader renders, and the button that turns OSL on.
        scene = bpy.context.scene
        scene.render.engine = "CYCLES"
        scene.cycles.shading_system = False
        rows = draw(ext.ui.material_operators.VIEW3D_PT_woven_fabric_material)
        assert any("fallback" in text and "Open Shading Language is off" in text for _, text, _ in rows), rows
        assert ("operator", "fabric.enable_osl", None) in rows
        assert bpy.ops.fabric.enable_osl() == {{"FINISHED"}} and scene.cycles.shading_system
        rows = draw(ext.ui.material_operators.VIEW3D_PT_woven_fabric_material)
        assert any("fitted OSL shader" in text for _, text, _ in rows) and ("operator", "fabric.enable_osl", None) \\
            not in rows
        scene.render.engine = "BLENDER_EEVEE"
        assert any("EEVEE renders the approximate fallback" in text
                   for _, text, _ in draw(ext.ui.material_operators.VIEW3D_PT_woven_fabric_material))
        print("BATCH UI OK")
    """)
    assert "BATCH UI OK" in output
