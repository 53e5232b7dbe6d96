"""The extension inside Blender (the bpy module): build, install, register, fit, batch, drape.

Each bpy check runs in its own Python process with a temporary ``BLENDER_USER_RESOURCES`` (so the
extension is installed there, never into the user's Blender) and speaks to pytest through its exit
code and output. The backend is tests/fake_backend.py, selected through the environment the
add-on reads (``WOVEN_FABRIC_PYTHON``, ``WOVEN_FABRIC_BACKEND_SCRIPT``), except in the slow test
that runs the extension's bundled backend.

``WOVEN_FABRIC_TEST_ZIP`` may name an already built extension zip to test instead of building one.
"""
from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import textwrap
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from addon_support import extension_zip_for_tests, python_without_torch, require_bpy, validate_extension  # noqa: E402

from backend.core.params import FabricParams  # noqa: E402
from backend.core.priors import FIT_PATTERNS  # noqa: E402
from backend.core.rig import DEFAULT_RIG  # noqa: E402
from backend.image.png import write_png as write_png16  # noqa: E402
from backend.model.render import render_pair  # noqa: E402

pytestmark = pytest.mark.blender

FAKE_BACKEND = Path(__file__).resolve().parent / "fake_backend.py"
BACKEND_SCRIPT = str(FAKE_BACKEND)
EXTENSION = "bl_ext.user_default.woven_fabric"
TIMEOUT_S = 120  # a liveness bound for one bpy check with the fake backend, not a timing


def write_png(path: Path, rgb: tuple[int, int, int], size: int = 16):
    """A small solid-colour 8-bit RGB PNG with a darker grid (no image library needed)."""
    rows = b"".join(b"\x00" + b"".join(bytes(rgb if (x % 4 and y % 4) else (rgb[0] // 2, rgb[1] // 2, rgb[2] // 2))
                                       for x in range(size)) for y in range(size))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", size, size, 8, 2, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))


@pytest.fixture(scope="module")
def extension_zip(tmp_path_factory) -> Path:
    return extension_zip_for_tests(tmp_path_factory.mktemp("dist"))


@pytest.fixture
def photos(tmp_path) -> Path:
    """Two good pairs, one with a corrupt transmission photo, one reflection without its partner."""
    folder = tmp_path / "photos"
    folder.mkdir()
    write_png(folder / "linen_R.png", (200, 190, 170))
    write_png(folder / "linen_T.png", (90, 80, 60))
    write_png(folder / "wool_R.png", (120, 30, 40))
    write_png(folder / "wool_T.png", (50, 10, 15))
    write_png(folder / "torn_R.png", (10, 10, 10))
    (folder / "torn_T.png").write_text("not an image")
    write_png(folder / "solo_R.png", (10, 200, 10))
    return folder


PRELUDE = """
import json, os, sys
from pathlib import Path
import bpy

registered_commands = {}
_register_cli_command = bpy.utils.register_cli_command
def _record_cli_command(name, execute):
    registered_commands[name] = execute
    return _register_cli_command(name, execute)
bpy.utils.register_cli_command = _record_cli_command

assert bpy.ops.extensions.package_install_files(
    filepath=os.environ["FABRIC_TEST_ZIP"], repo="user_default", enable_on_install=True) == {"FINISHED"}
import importlib
ext = importlib.import_module("%s")

class StandIn:
    # A modal operator's state with its class's methods: Blender cannot make one without an event loop.
    def __init__(self, operator_class):
        self._class, self._timer, self.reports = operator_class, None, []
    def report(self, kind, message):
        self.reports.append((kind, message))
    def __getattr__(self, name):
        import inspect
        value = getattr(self._class, name)
        if isinstance(inspect.getattr_static(self._class, name), (staticmethod, classmethod)):
            return value  # already what the class gives an instance
        return value.__get__(self) if callable(value) and hasattr(value, "__get__") else value

def drawn_by(panel):
    # What a panel's draw() puts into its layout, in order: (call, its text or first argument).
    drawn = []
    class Recorder:
        def __getattr__(self, name):
            def call(*args, **kw):
                drawn.append((name, kw.get("text", args[0] if args else None)))
                return Recorder()
            return call
    from types import SimpleNamespace
    panel.draw(SimpleNamespace(layout=Recorder()), bpy.context)
    return drawn

def refused(operator, message, **properties):
    # Runs an operator that must fail (an ERROR report raises in background mode); its message.
    try:
        operator(**properties)
    except RuntimeError as exc:
        assert message in str(exc), exc
        return str(exc)
    raise AssertionError(f"{operator} was accepted; expected {message!r}")
""" % EXTENSION


def run_bpy(tmp_path: Path, extension_zip: Path, body: str, timeout: float = TIMEOUT_S, **env) -> str:
    """Runs PRELUDE + body in a fresh Python with bpy; returns its output, fails the test on error."""
    require_bpy()
    script = tmp_path / "check.py"
    script.write_text(PRELUDE + textwrap.dedent(body))
    resources = tmp_path / "blender_user"
    resources.mkdir(exist_ok=True)
    environment = {**os.environ, "BLENDER_USER_RESOURCES": str(resources), "FABRIC_TEST_ZIP": str(extension_zip),
                   "WOVEN_FABRIC_PYTHON": sys.executable, "WOVEN_FABRIC_BACKEND_SCRIPT": BACKEND_SCRIPT,
                   **{k: str(v) for k, v in env.items()}}
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=timeout,
                          env=environment, cwd=tmp_path)
    output = done.stdout + done.stderr
    assert done.returncode == 0, f"bpy check failed (exit {done.returncode}):\n{output[-6000:]}"
    return output


# -- the zip ----------------------------------------------------------------------------------------

def test_build_makes_an_extension_zip_with_backend_and_shaders(tmp_path):
    done = subprocess.run([sys.executable, str(ROOT / "build.py"), "--out", str(tmp_path)], capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    path = Path(done.stdout.strip())
    assert path.parent == tmp_path and path.name == "woven_fabric-0.1.0.zip"
    names = zipfile.ZipFile(path).namelist()
    for required in ("blender_manifest.toml", "__init__.py", "core/backend_bridge.py", "ui/operators.py", "batch.py",
                     "core/paths.py", "backend/__init__.py", "backend/core/protocol.py", "backend/core/params.py"):
        assert required in names, required
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc") or n.startswith("tests/")]
    validate_extension(path)  # Blender's own manifest check comes with the bpy module
    # Two builds of the same tree are byte-identical.
    again = subprocess.run([sys.executable, str(ROOT / "build.py"), "--out", str(tmp_path / "again")],
                           capture_output=True, text=True, timeout=60)
    assert Path(again.stdout.strip()).read_bytes() == path.read_bytes()


def test_build_bundles_the_shader(extension_zip):
    names = zipfile.ZipFile(extension_zip).namelist()
    assert "shaders/woven_fabric.osl" in names and "scene/node_group.py" in names


# -- registration -----------------------------------------------------------------------------------

def test_extension_registers_panel_operators_preferences_and_command(tmp_path, extension_zip, photos):
    output = run_bpy(tmp_path, extension_zip, """
        prefs = bpy.context.preferences.addons[ext.__name__].preferences
        assert {"python_path", "backend_script", "device", "results_folder"} <= set(prefs.bl_rna.properties.keys())
        assert prefs.device == "AUTO" and prefs.python_path == ""
        for panel in ("VIEW3D_PT_woven_fabric", "VIEW3D_PT_woven_fabric_rig", "VIEW3D_PT_woven_fabric_fit",
                      "VIEW3D_PT_woven_fabric_result"):
            cls = getattr(bpy.types, panel)
            assert cls.bl_category == "Fabric" and cls.bl_region_type == "UI", panel
        for op in ("fit", "cancel_fit", "check_backend", "detect_python", "reset_rig", "load_fit",
                   "assign_material", "add_drape_preview", "open_results", "batch_fit"):
            assert hasattr(bpy.ops.fabric, op), op
        settings = bpy.context.scene.woven_fabric
        # The rig's properties start at the backend's rig (float32 in Blender) and width_cm 0 (unknown).
        import numpy as np
        def rig_values():
            return {name: list(value) if hasattr(value, "__len__") else value
                    for name, value in ((n, getattr(settings.rig, n)) for n in expected_rig)}
        def close(a, b):
            return all(abs(x - y) <= 1e-6 * max(1.0, abs(y)) for x, y in zip(np.ravel(a), np.ravel(b)))
        expected_rig = json.loads(os.environ["FABRIC_TEST_RIG"])
        expected_rig["width_cm"] = expected_rig["width_cm"] or 0.0
        assert all(close(rig_values()[n], v) for n, v in expected_rig.items()), (rig_values(), expected_rig)
        settings.rig.fov_deg = 60.0
        settings.rig.front_light = (1.0, 2.0, 3.0)
        bpy.ops.fabric.reset_rig()
        assert all(close(rig_values()[n], v) for n, v in expected_rig.items()), rig_values()
        film = settings.rig.bl_rna.properties["film_size"]
        assert (film.hard_min, film.hard_max) == (32, 4096), (film.hard_min, film.hard_max)  # the backend's range
        weaves = [item.identifier for item in settings.bl_rna.properties["pattern"].enum_items]
        assert weaves == json.loads(os.environ["FABRIC_TEST_PATTERNS"]) and settings.pattern == "auto", weaves
        labels = {item.identifier: item.name for item in settings.bl_rna.properties["pattern"].enum_items}
        assert (labels["twill1"], labels["twill0m"], labels["plain"]) == ("Twill 1", "Twill 0 mirrored", "Plain")
        assert registered_commands["fabric_fit"] is ext.ui.batch.main
        assert importlib.import_module(ext.__name__ + ".batch").main is ext.ui.batch.main
        backend = ext.ui.preferences.selected_backend(detect=False)
        assert backend.python == sys.executable and backend.script == os.environ["WOVEN_FABRIC_BACKEND_SCRIPT"]
        # A fit without photos is refused with a readable message, nothing started.
        refused(bpy.ops.fabric.fit, "Choose the reflection photo first")

        # Draw every panel and the preferences into a layout that checks each property and operator.
        drawn = []
        class Layout:
            def __getattr__(self, name):
                def call(*args, **kw):
                    if name == "prop":
                        assert args[1] in args[0].bl_rna.properties, args[1]
                    elif name == "operator":
                        group, op = args[0].split(".")
                        assert hasattr(getattr(bpy.ops, group), op), args[0]
                    drawn.append((name, args[1] if name == "prop" else args[0] if args else kw))
                    return Layout()
                return call
        from types import SimpleNamespace
        settings.reflection_path = os.environ["FABRIC_TEST_PHOTO"]
        panels = [getattr(bpy.types, p) for p in ("VIEW3D_PT_woven_fabric", "VIEW3D_PT_woven_fabric_rig",
                                                    "VIEW3D_PT_woven_fabric_fit", "VIEW3D_PT_woven_fabric_result")]
        for panel in panels:
            panel.draw(SimpleNamespace(layout=Layout()), bpy.context)
        class PreferencesView:  # the preferences, drawn into the checking layout
            layout = Layout()
            def __getattr__(self, name):
                return getattr(prefs, name)
        type(prefs).draw(PreferencesView(), bpy.context)
        assert ("prop", "camera_height") in drawn and ("operator", "fabric.fit") in drawn
        # (Background mode has no icons: icon_id stays 0, but the preview image must load.)
        previews = list(ext.ui.panels._previews.values())
        assert len(previews) == 1 and tuple(previews[0].image_size) == (16, 16), previews

        # While a fit runs the Fit panel shows a progress bar and the Cancel button.
        os.environ["FAKE_BACKEND_MODE"] = "slow"
        bridge = ext.core.backend_bridge
        fit = bridge.FitProcess.fit(ext.ui.preferences.selected_backend(), bridge.FitRequest(
            Path(settings.reflection_path), Path(settings.reflection_path), Path("run"))).start()
        ext.ui.operators.fit_job.job = fit
        drawn.clear()
        panels[2].draw(SimpleNamespace(layout=Layout()), bpy.context)
        assert ("operator", "fabric.cancel_fit") in drawn and "progress" in [d[0] for d in drawn], drawn
        assert bpy.ops.fabric.cancel_fit() == {"FINISHED"}
        assert fit.wait(timeout=10) == "cancelled"

        bpy.ops.preferences.addon_disable(module=ext.__name__)
        assert not hasattr(bpy.types.Scene, "woven_fabric")
        assert not hasattr(bpy.types, "VIEW3D_PT_woven_fabric")
        print("REGISTRATION OK")
    """, FABRIC_TEST_PHOTO=photos / "linen_R.png", FABRIC_TEST_RIG=json.dumps(DEFAULT_RIG.to_dict()),
        FABRIC_TEST_PATTERNS=json.dumps(["auto", *FIT_PATTERNS]))
    assert "REGISTRATION OK" in output


def test_check_backend_reports_missing_torch_in_words(tmp_path, extension_zip):
    python = python_without_torch(tmp_path / "no_torch")
    output = run_bpy(tmp_path, extension_zip, f"""
        message = refused(bpy.ops.fabric.check_backend, "The backend cannot run yet", python={python!r})
        assert "PyTorch (torch), which renders and fits the fabric model, is not installed for {python}" in message
        assert ext.core.check_job.backend_check.last.problems
        print("CHECK OK")
    """)
    assert "CHECK OK" in output


# -- fitting, batch, drape -------------------------------------------------------------------------

def test_fit_operator_makes_new_versions_and_reports_errors(tmp_path, extension_zip, photos):
    output = run_bpy(tmp_path, extension_zip, f"""
        photos = Path({str(photos)!r})
        results = Path({str(tmp_path / 'results')!r})
        bpy.context.preferences.addons[ext.__name__].preferences.results_folder = str(results)
        users = bpy.data.materials.new("linen")  # the user's own material of the same name
        settings = bpy.context.scene.woven_fabric
        settings.reflection_path = str(photos / "linen_R.png")
        settings.transmission_path = str(photos / "linen_T.png")
        settings.rig.width_cm = 5.0
        assert bpy.ops.fabric.fit() == {{"FINISHED"}}
        assert bpy.ops.fabric.fit() == {{"FINISHED"}}
        assert settings.last_material == "linen.002", settings.last_material
        assert "Woven Fabric" not in [n.name for n in (users.node_tree.nodes if users.node_tree else [])]
        folders = sorted(p.name for p in results.iterdir())
        assert folders == ["linen_001", "linen_002"], folders
        for folder in folders:
            assert (results / folder / "params.json").is_file() and (results / folder / "rig.json").is_file()
        assert json.loads((results / "linen_002" / "rig.json").read_text())["width_cm"] == 5.0
        fitted = bpy.data.materials["linen.001"]
        assert fitted.use_fake_user and ext.scene.materials.is_fabric_material(fitted)
        values = ext.scene.node_group.read_params(fitted)
        assert values["pattern"] == "twill1" and abs(values["roughness"][1] - 0.66) < 1e-4, values

        # Asked to, a fit updates the active object's fabric material in place.
        cube = bpy.data.objects["Cube"]
        cube.data.materials.append(fitted)
        cube.active_material_index = len(cube.material_slots) - 1
        bpy.context.view_layer.objects.active = cube
        settings.update_active_material = True
        assert bpy.ops.fabric.fit() == {{"FINISHED"}}
        assert settings.last_material == "linen.001" and "linen.003" not in bpy.data.materials
        settings.update_active_material = False

        os.environ["FAKE_BACKEND_MODE"] = "error"
        refused(bpy.ops.fabric.fit, "Internal backend error: the optimiser diverged")
        assert "linen.003" not in bpy.data.materials
        # The Fit panel shows the error wrapped in a box with a button that opens the fit's log as a text.
        failed = ext.ui.operators.fit_job.job
        drawn = drawn_by(ext.ui.panels.VIEW3D_PT_woven_fabric_fit)
        assert ("operator", "fabric.open_fit_log") in drawn and ("box", None) in drawn, drawn
        assert [d for d in drawn if d[0] == "label" and "Internal backend error" in (d[1] or "")], drawn
        assert bpy.ops.fabric.open_fit_log(filepath=str(failed.log_path)) == {{"FINISHED"}}
        assert bpy.ops.fabric.open_fit_log(filepath=str(failed.log_path)) == {{"FINISHED"}}  # the same text again
        logs = [t for t in bpy.data.texts if t.name.startswith("backend.log")]
        assert len(logs) == 1 and "error: the optimiser diverged" in logs[0].as_string(), logs
        refused(bpy.ops.fabric.open_fit_log, "the log cannot be read", filepath=str(results / "no.log"))

        # An earlier fit's folder becomes a material again (named after the photo, not the folder).
        assert bpy.ops.fabric.load_fit(filepath=str(results / "linen_001" / "params.json")) == {{"FINISHED"}}
        assert settings.last_material == "linen.003", settings.last_material
        # A params.json edited into something that is not a fit: an error, and no material made.
        materials_before = set(bpy.data.materials.keys())
        crafted = results / "linen_001" / "crafted.json"
        crafted.write_text((results / "linen_001" / "params.json").read_text().replace('"twill1"', '"satin9"'))
        refused(bpy.ops.fabric.load_fit, "not a fit's parameters: pattern", filepath=str(crafted))
        assert set(bpy.data.materials.keys()) == materials_before and settings.last_material == "linen.003"
        print("FIT OK")
    """)
    assert "FIT OK" in output


def test_the_modal_job_operator_follows_a_job_to_its_end_and_cancels_it(tmp_path, extension_zip):
    """The base of the fit, batch and GPU install operators, with a job that ends after three polls:
    execute follows it to the end without an event loop; a modal tick polls it once and passes every
    other event on, ESC asks it to stop, a finished job is handed over once; another file or
    disabling the add-on cancels the jobs of the file, a job that survives files is asked to stop."""
    output = run_bpy(tmp_path, extension_zip, """
        from types import SimpleNamespace
        modal_job = ext.ui.modal_job

        class Job:  # a plain job as core/ makes them: poll, done, request_cancel, cancel
            def __init__(self, polls_to_end=3):
                self.polls, self.polls_to_end, self.state, self.progress = 0, polls_to_end, "running", 0.0
                self.calls = []
            @property
            def done(self):
                return self.state != "running"
            def poll(self):
                self.polls += 1
                self.progress = min(1.0, self.polls / self.polls_to_end)
                if self.cancel_asked() or self.polls >= self.polls_to_end:
                    self.state = "cancelled" if self.cancel_asked() else "done"
            def cancel_asked(self):
                return "request_cancel" in self.calls
            def request_cancel(self):
                self.calls.append("request_cancel")
            def cancel(self):
                self.calls.append("cancel")
                self.state = "cancelled"

        started, finished = [], []
        class FABRIC_OT_test_job(modal_job.ModalJobOperator, bpy.types.Operator):
            bl_idname, bl_label = "fabric.test_job", "Test Job"
            refuse: bpy.props.BoolProperty()
            active = modal_job.ActiveJob()
            def start_job(self, context):
                if self.refuse:
                    self.report({"ERROR"}, "The test job cannot start")
                    return None
                started.append(Job())
                return started[-1]
            def finish_job(self, context, job):
                finished.append(job)
                return {"FINISHED"} if job.state == "done" else {"CANCELLED"}
        bpy.utils.register_class(FABRIC_OT_test_job)

        # Without an event loop, execute follows the job to its end and hands it over once.
        assert bpy.ops.fabric.test_job() == {"FINISHED"}
        assert started[0].polls == 3 and finished == started
        refused(bpy.ops.fabric.test_job, "The test job cannot start", refuse=True)
        assert len(started) == 1 and FABRIC_OT_test_job.active.job is started[0]

        # Timer ticks: one poll each; other events pass through untouched; ESC asks the job to stop.
        timer = SimpleNamespace(type="TIMER", value="NOTHING")
        op, job = StandIn(FABRIC_OT_test_job), Job(polls_to_end=10)
        FABRIC_OT_test_job.active.job = job
        assert not FABRIC_OT_test_job.poll(bpy.context)  # one job of a kind at a time
        assert FABRIC_OT_test_job.modal(op, bpy.context, timer) == {"PASS_THROUGH"} and job.polls == 1
        assert FABRIC_OT_test_job.modal(op, bpy.context, SimpleNamespace(type="MOUSEMOVE", value="NOTHING")) \
            == {"PASS_THROUGH"} and job.polls == 1
        assert FABRIC_OT_test_job.modal(op, bpy.context, SimpleNamespace(type="ESC", value="PRESS")) \
            == {"RUNNING_MODAL"} and job.calls == ["request_cancel"] and finished == started
        assert FABRIC_OT_test_job.modal(op, bpy.context, timer) == {"CANCELLED"} and finished[-1] is job
        assert FABRIC_OT_test_job.poll(bpy.context)
        # Blender ending the operator (its window closed) cancels the job and waits for it.
        FABRIC_OT_test_job.active.job = job = Job()
        FABRIC_OT_test_job.cancel(op, bpy.context)
        assert job.calls == ["cancel"] and job.done

        # Drawn: the progress bar with its Cancel button; the error with the button that opens the log.
        drawn = []
        class Layout:
            def __getattr__(self, name):
                def call(*args, **kw):
                    drawn.append((name, kw.get("text", args[0] if args else None), kw.get("factor")))
                    return Layout()
                return call
        modal_job.draw_progress(Layout(), 0.25, "Optimising 5/20", "fabric.cancel_fit")
        assert ("progress", "Optimising 5/20", 0.25) in drawn and ("operator", "", None) in drawn, drawn
        log = Path("fit.log")
        log.write_text("the backend's stderr")
        drawn.clear()
        modal_job.draw_error(Layout(), "Bad input: the photo is black", bpy.context, log)
        assert ("label", "Bad input: the photo is black", None) in drawn and ("operator", "fabric.open_fit_log", None) \
            in drawn, drawn

        # Another file: the jobs of the old one are cancelled (waiting), a job that survives files goes on.
        survivor = modal_job.ActiveJob(survives_file=True)
        FABRIC_OT_test_job.active.job, survivor.job = Job(), Job()
        bpy.ops.wm.save_as_mainfile(filepath=str(Path("other.blend").resolve()))
        bpy.ops.wm.open_mainfile(filepath=str(Path("other.blend").resolve()))
        assert FABRIC_OT_test_job.active.job.calls == ["cancel"] and survivor.job.calls == []
        # Disabling the add-on stops every job: the file's waiting, the others asked to stop.
        FABRIC_OT_test_job.active.job = Job()
        bpy.ops.preferences.addon_disable(module=ext.__name__)
        assert FABRIC_OT_test_job.active.job.calls == ["cancel"] and survivor.job.calls == ["request_cancel"]
        print("MODAL JOB OK")
    """)
    assert "MODAL JOB OK" in output


def test_swapped_photos_are_refused_shown_side_by_side_and_can_be_swapped_or_fitted_as_given(
        tmp_path, extension_zip, photos):
    """The fit asks the backend to refuse photos that look swapped (``--strict``); the Fit panel then
    shows both photos with Swap Photos and Fit As Given. Fitted as given, the backend's warning is in
    the status bar, on the console (background mode), in the fit's backend.log and in the panel."""
    output = run_bpy(tmp_path, extension_zip, f"""
        photos = Path({str(photos)!r})
        results = Path({str(tmp_path / 'results')!r})
        bpy.context.preferences.addons[ext.__name__].preferences.results_folder = str(results)
        settings = bpy.context.scene.woven_fabric
        settings.reflection_path = str(photos / "linen_T.png")   # the wrong way round
        settings.transmission_path = str(photos / "linen_R.png")
        assert settings.refuse_swapped
        os.environ["FAKE_BACKEND_MODE"] = "swapped"
        message = refused(bpy.ops.fabric.fit, "the photos may be swapped")
        assert "Swap Photos or Fit As Given in the Fit panel" in message, message
        assert ext.ui.operators.fit_job.job.refused_swapped and not bpy.data.materials.get("linen")

        panel = ext.ui.panels.VIEW3D_PT_woven_fabric_fit
        drawn = drawn_by(panel)
        labels = [text for kind, text in drawn if kind == "label"]
        assert "linen_T.png" in labels and "linen_R.png" in labels, labels
        assert ("operator", "fabric.swap_photos") in drawn and ("operator", "Fit As Given") in drawn, drawn

        assert bpy.ops.fabric.swap_photos() == {{"FINISHED"}}
        assert Path(settings.reflection_path).name == "linen_R.png"
        assert Path(settings.transmission_path).name == "linen_T.png"
        assert bpy.ops.fabric.fit(as_given=True) == {{"FINISHED"}}
        fit = ext.ui.operators.fit_job.job
        assert fit.warnings and "may be swapped" in fit.warnings[0] and not fit.request.strict
        assert "warning:" in fit.log_path.read_text() and "may be swapped" in fit.log_path.read_text()
        drawn = drawn_by(panel)
        assert any("may be swapped" in (text or "") for kind, text in drawn if kind == "label"), drawn
        print("SWAPPED OK")
    """)
    assert "SWAPPED OK" in output
    assert "Woven Fabric: warning: " in output and "may be swapped" in output  # the console in background mode


def test_the_fit_refuses_what_the_backend_would_before_starting_it(tmp_path, extension_zip, photos):
    output = run_bpy(tmp_path, extension_zip, f"""
        photos = Path({str(photos)!r})
        results = Path({str(tmp_path / 'results')!r})
        bpy.context.preferences.addons[ext.__name__].preferences.results_folder = str(results)
        settings = bpy.context.scene.woven_fabric
        settings.reflection_path = str(photos / "linen_R.png")
        settings.transmission_path = str(photos / "linen_T.png")
        settings.size = 16   # the property takes 0 (the backend's default) and up; the fit takes 32 and up
        refused(bpy.ops.fabric.fit, "--size: must be at least 32 pixels, got 16")
        assert not results.exists(), "a refused fit made a result folder"
        queue = ext.ui.batch_operators.new_batch(bpy.context, str(photos))
        try:
            queue.start()
        except ext.core.backend_bridge.BackendError as exc:
            assert str(exc) == "--size: must be at least 32 pixels, got 16", exc
        else:
            raise AssertionError("the batch started")
        print("OPTIONS OK")
    """)
    assert "OPTIONS OK" in output


def test_modal_fit_returns_to_blender_between_polls_and_esc_cancels(tmp_path, extension_zip, photos):
    output = run_bpy(tmp_path, extension_zip, f"""
        import time
        from types import SimpleNamespace
        photos = Path({str(photos)!r})
        settings = bpy.context.scene.woven_fabric
        settings.reflection_path = str(photos / "wool_R.png")
        settings.transmission_path = str(photos / "wool_T.png")
        operator_class = ext.ui.operators.FABRIC_OT_fit

        class Operator(StandIn):
            _scene_name, _warned = bpy.context.scene.name, 0
        timer, esc = SimpleNamespace(type="TIMER", value="NOTHING"), SimpleNamespace(type="ESC", value="PRESS")

        def run(mode, cancel_when=None):
            os.environ["FAKE_BACKEND_MODE"] = mode
            op = Operator(operator_class)
            fit = ext.ui.operators.new_fit(bpy.context, settings).start()
            ext.ui.operators.fit_job.job = fit
            statuses, cancelled = [], cancel_when == ""
            if cancelled:  # at once, before the backend has reported anything
                assert operator_class.modal(op, bpy.context, esc) == {{"RUNNING_MODAL"}}
            for ticks in range(1, 2000):  # a liveness bound (100 s), not a timing
                result = operator_class.modal(op, bpy.context, timer)
                statuses.append((settings.fit_progress, settings.fit_status))
                if result != {{"PASS_THROUGH"}}:  # the last tick also builds the material
                    return result, op, fit, ticks, statuses
                if cancel_when is not None and not cancelled and cancel_when in settings.fit_status:
                    assert operator_class.modal(op, bpy.context, esc) == {{"RUNNING_MODAL"}}
                    cancelled = True
                time.sleep(0.05)
            raise AssertionError("the fit did not end")

        result, op, fit, ticks, statuses = run("ok")
        assert result == {{"FINISHED"}}, op.reports
        assert ticks > 1, "the timer tick waited for the whole fit"  # the first tick finds it starting
        assert settings.fit_progress == 1.0 and settings.last_material == "wool", settings.last_material
        assert settings.fit_status == "Fit finished: material wool"
        fractions = [fraction for fraction, _ in statuses]
        assert fractions == sorted(fractions), fractions  # one bar over the whole fit, never going back

        # Cancelled once it has parameters to keep: a material from the best so far, named as partial.
        result, op, fit, ticks, statuses = run("slow", cancel_when=" of 600")  # a step counted: parameters kept
        assert result == {{"FINISHED"}} and fit.state == "cancelled", (result, fit.state, op.reports)
        assert not Path(f"/proc/{{fit.pid}}").exists(), "the cancelled backend is still there"
        assert op.reports[-1][0] == {{"WARNING"}}, op.reports
        assert "Fit cancelled: material wool (partial) from the best parameters so far" in op.reports[-1][1]
        assert settings.last_material == "wool (partial)" and "wool.001" not in bpy.data.materials
        partial = ext.scene.node_group.read_params(bpy.data.materials["wool (partial)"])
        assert partial["pattern"] == "twill1", partial
        # Cancelled before it has any: no material.
        result, op, fit, ticks, statuses = run("slow", cancel_when="")
        assert result == {{"CANCELLED"}} and op.reports[-1][0] == {{"WARNING"}}, (result, op.reports)
        assert not [m for m in bpy.data.materials if m.name.startswith("wool (partial).")]
        print("MODAL OK")
    """)
    assert "MODAL OK" in output


def test_batch_command_fits_good_pairs_and_counts_bad_ones(tmp_path, extension_zip, photos):
    library = tmp_path / "library.blend"
    output = run_bpy(tmp_path, extension_zip, f"""
        # What `blender --command fabric_fit ARGS` does: call the registered callback with ARGS.
        code = registered_commands["fabric_fit"]([{str(photos)!r}, "--out", {str(library)!r}, "--iterations", "3"])
        print("EXIT", code)
        assert code == 2, code
        bpy.ops.wm.open_mainfile(filepath={str(library)!r})
        assets = sorted(m.name for m in bpy.data.materials if m.asset_data is not None)
        assert assets == ["linen", "wool"], assets
        catalogs = ext.core.asset_catalogs
        written = catalogs.parse((Path({str(library)!r}).parent / catalogs.CATALOG_FILE).read_text())
        for name in assets:
            material = bpy.data.materials[name]
            tags = [t.name for t in material.asset_data.tags]
            assert tags[:3] == ["fabric", "woven", "twill1"] and len(tags) == 4, tags  # + a colour name
            assert material.asset_data.catalog_id == written[catalogs.catalog_path("twill1")]
            assert tuple(material.preview.image_size) == (96, 96)  # rendered (scene/preview.py)
        print("BATCH OK")
    """)
    assert "BATCH OK" in output
    assert "SKIP solo: no transmission photo (solo_T.*) beside solo_R.png" in output
    assert "FAIL [2/3] torn" in output and "Bad input" in output
    assert sorted(p.name for p in (photos / "fabric_fits").iterdir()) == ["linen_001", "torn_001", "wool_001"]


def test_batch_runs_from_the_bpy_module_in_a_checkout(tmp_path, photos):
    (photos / "torn_T.png").unlink()
    (photos / "solo_R.png").unlink()
    (photos / "torn_R.png").unlink()
    environment = {**os.environ, "BLENDER_USER_RESOURCES": str(tmp_path / "blender_user"),
                   "WOVEN_FABRIC_PYTHON": sys.executable, "WOVEN_FABRIC_BACKEND_SCRIPT": BACKEND_SCRIPT}
    done = subprocess.run([sys.executable, "-m", "blender_addon.batch", str(photos), "--out",
                           str(tmp_path / "lib.blend")], capture_output=True, text=True, timeout=TIMEOUT_S,
                          env=environment, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "2 fitted, 0 failed" in done.stdout and (tmp_path / "lib.blend").is_file()


def test_the_checkout_batch_makes_a_library_from_results_without_fitting(tmp_path, photos):
    results = tmp_path / "results"   # fitted elsewhere (`python -m backend batch --out results`)
    for name in ("linen", "wool"):
        subprocess.run([sys.executable, str(FAKE_BACKEND), "fit", str(photos / f"{name}_R.png"),
                        str(photos / f"{name}_T.png"), "--out", str(results / name)], check=True, timeout=TIMEOUT_S)
    (results / "logs").mkdir()
    environment = {**os.environ, "BLENDER_USER_RESOURCES": str(tmp_path / "blender_user"),
                   "WOVEN_FABRIC_PYTHON": "/nonexistent/python"}  # no backend is needed
    done = subprocess.run([sys.executable, "-m", "blender_addon.batch", "--from-results", str(results)],
                          capture_output=True, text=True, timeout=TIMEOUT_S, env=environment, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "2 imported, 0 failed" in done.stdout and (results / "fabric_materials.blend").is_file()


def test_only_colour_layers_are_paint_slots_and_the_buttons_wait_for_something_to_act_on(tmp_path, extension_zip):
    """The weave's lookup images are never texture-paint slots (a Woven Fabric material has none
    until a colour layer is added, then exactly its colour layers); Add Draped Cloth Preview and Set
    Real-World Scale are greyed out with nothing to act on; the rig's labels read as words; the
    Material panel's long lines wrap; an unsaved file's fits go to a folder the artist can find."""
    output = run_bpy(tmp_path, extension_zip, f"""
        import importlib.util
        spec = importlib.util.spec_from_file_location("fake", {str(FAKE_BACKEND)!r})
        fake = importlib.util.module_from_spec(spec); spec.loader.exec_module(fake)
        cube = bpy.data.objects["Cube"]
        bpy.context.view_layer.objects.active = cube
        cube.select_set(True)
        assert not bpy.ops.fabric.add_drape_preview.poll() and not bpy.ops.fabric.set_real_world_scale.poll()

        material = ext.scene.materials.new_fit_material("denim", fake.fake_params("denim"), 5.0)
        cube.data.materials.clear()
        cube.data.materials.append(material)
        bpy.context.scene.woven_fabric.last_material = material.name
        assert bpy.ops.fabric.add_drape_preview.poll() and bpy.ops.fabric.set_real_world_scale.poll()
        bpy.ops.object.mode_set(mode="TEXTURE_PAINT")
        assert [slot.name for slot in material.texture_paint_slots] == [], list(material.texture_paint_slots)
        bpy.ops.object.mode_set(mode="OBJECT")
        assert bpy.ops.fabric.add_colour_layer(mode="MULTIPLY") == {{"FINISHED"}}
        assert bpy.ops.fabric.add_colour_layer(mode="REPLACE", paint=False) == {{"FINISHED"}}
        layers = [image.name for image in material.texture_paint_images]
        assert len(layers) == 2 and not [name for name in layers if name.startswith("Woven Fabric ")], layers

        labels = {{field.name: field.label for field in ext.core.rig_settings.rig_fields()}}
        assert (labels["sample_rotation_deg"], labels["sample_skew_deg"]) == ("Sample rotation", "Sample skew")
        # An unchanged panel gives the fit the backend's own rig, to the last digit (gamma 2.2, not the
        # 2.2000000476837 a single-precision property holds): the same fit as the command line's.
        rig = ext.core.rig_settings.rig_dict(ext.ui.properties.rig_values(bpy.context.scene.woven_fabric.rig))
        assert rig == json.loads(os.environ["FABRIC_TEST_RIG"]), rig

        bpy.context.scene.render.engine = "BLENDER_EEVEE"
        drawn = drawn_by(ext.ui.material_operators.VIEW3D_PT_woven_fabric_material)
        labels = [text for kind, text in drawn if kind == "label"]
        width = ext.ui.layout.line_width(bpy.context)
        assert "EEVEE" in labels[0] and max(map(len, labels)) <= width < len(" ".join(labels[:2])), labels

        assert not bpy.data.filepath
        parent = ext.ui.preferences.results_parent(bpy.context)
        assert parent.name == "Woven Fabric Fits" and parent.parent in (Path.home(), Path.home() / "Documents")
        drawn = drawn_by(ext.ui.panels.VIEW3D_PT_woven_fabric_fit)
        shown = " ".join(text or "" for kind, text in drawn if kind == "label")
        assert "Woven Fabric Fits" in shown, shown
        print("SMALL POINTS OK")
    """, FABRIC_TEST_RIG=json.dumps(DEFAULT_RIG.to_dict()))
    assert "SMALL POINTS OK" in output


def test_drape_preview_builds_a_cloth_scene(tmp_path, extension_zip, photos):
    output = run_bpy(tmp_path, extension_zip, f"""
        import importlib.util
        spec = importlib.util.spec_from_file_location("fake", {str(FAKE_BACKEND)!r})
        fake = importlib.util.module_from_spec(spec); spec.loader.exec_module(fake)
        material = ext.scene.materials.new_fit_material("denim", fake.fake_params("denim"), 5.0)
        before = set(bpy.context.scene.objects.keys())
        bpy.context.scene.woven_fabric.last_material = material.name
        assert bpy.ops.fabric.add_drape_preview(resolution=10, frames=12) == {{"FINISHED"}}
        preview = bpy.data.scenes["Fabric Preview"]
        assert set(bpy.data.scenes["Scene"].objects.keys()) == before  # the user's scene is untouched
        cloth = preview.objects["Fabric Cloth"]
        assert cloth.data.materials[0].name == "denim Drape" and material.name == "denim"
        uvs = [tuple(d.uv) for d in cloth.data.uv_layers[0].data]  # the weave needs UVs spanning the cloth
        assert min(uvs) == (0.0, 0.0) and max(uvs) == (1.0, 1.0), (min(uvs), max(uvs))
        zs = [(cloth.matrix_world @ v.co).z for v in cloth.data.vertices]
        assert max(zs) - min(zs) > 0.1, "the cloth did not drape"
        assert preview.camera is not None and len([o for o in preview.objects if o.type == "LIGHT"]) == 2
        assert any(m.type == "COLLISION" for m in preview.objects["Preview Collider"].modifiers)
        assert preview.cycles.shading_system, "a CPU render of the preview should use the OSL shader"
        print("DRAPE OK")
    """)
    assert "DRAPE OK" in output


@pytest.mark.slow
def test_installed_extension_batch_fits_with_the_real_backend_and_renders_both_engines(tmp_path, extension_zip):
    """The whole chain, no fake: the zip installed into bpy runs its *bundled* backend on a small
    synthetic 512-px pair, the node group holds the fitted values, Cycles (OSL) and EEVEE render them."""
    truth = FabricParams.from_interchange(
        "twill1_R_0.6,0.5_S_1.3,1.6_T_2.4,2.9_N_0.0_UV_92.0,131.0_Kd_0.32,0.18,0.11,0.26,0.14,0.08"
        "_G_0.88,0.9_Rm_0.7,0.45_Tm_2.2,2.6_W_0.6,0.9_Ks_0.62,0.38,0.25,0.55,0.33,0.22_Psi_-30.0,-30.0")
    pair = render_pair(truth, size=512, spp=4, seed=1)  # a 256-px photo would alias this yarn density
    photos = tmp_path / "photos"
    photos.mkdir()
    write_png16(photos / "cotton_R.png", pair.reflection.numpy())
    write_png16(photos / "cotton_T.png", pair.transmission.numpy())
    library = tmp_path / "cotton.blend"
    output = run_bpy(tmp_path, extension_zip, f"""
        import numpy as np
        code = registered_commands["fabric_fit"]([{str(photos)!r}, "--out", {str(library)!r}, "--pattern", "twill1",
                                                  "--iterations", "4", "--size", "256", "--output-spp", "4",
                                                  "--width-cm", "5"])
        assert code == 0, code
        bpy.ops.wm.open_mainfile(filepath={str(library)!r})
        material = bpy.data.materials["cotton"]
        assert material.asset_data is not None
        print("VALUES", json.dumps(ext.scene.node_group.read_params(material)))
        rig_scene = importlib.import_module(ext.__name__ + ".scene.rig_scene")
        means = {{}}
        for engine, osl in (("CYCLES", True), ("BLENDER_EEVEE", False)):
            scene = rig_scene.build_scene(material, size=16, samples=1, osl=osl, scene=bpy.data.scenes.new(engine),
                                              threads=1)
            scene.render.engine = engine
            image = rig_scene.render_linear(scene, "front")[..., :3]
            assert np.isfinite(image).all(), engine
            means[engine] = float(image.mean())
        print("MEANS", json.dumps(means))
    """, timeout=600, WOVEN_FABRIC_BACKEND_SCRIPT="", WFC_COMPILE="0")  # a real fit: a longer liveness bound
    lines = {line.split(" ", 1)[0]: json.loads(line.split(" ", 1)[1]) for line in output.splitlines()
             if line.startswith(("VALUES ", "MEANS "))}
    fitted = json.loads((photos / "fabric_fits" / "cotton_001" / "params.json").read_text())
    in_blender = lines["VALUES"]
    assert in_blender["pattern"] == fitted["pattern"] == "twill1"
    for name, value in FabricParams.from_dict(fitted).to_dict().items():
        if name != "pattern":
            assert np.ravel(in_blender[name]) == pytest.approx(np.ravel(value), rel=1e-4, abs=1e-5), name
    assert in_blender["tiles"] == pytest.approx(truth.tiles, rel=0.02)  # the lattice, through the whole chain
    assert min(lines["MEANS"].values()) > 1e-3, lines["MEANS"]

