"""Operators: fit (modal, never blocking), cancel, check/detect the backend, results and preview.

Each operator reads the context, calls a plain function (core/, scene/) and reports; ``execute``
does the work, ``invoke`` only asks for input (Load Fit's file browser).

The fit operator is a modal job (modal_job.py): it starts a backend_bridge.FitProcess, which a
timer polls so Blender stays responsive; ESC or the Cancel button asks the backend to stop (the
stop line, then SIGKILL after a grace period). Loading another file or disabling the add-on
cancels a running fit too, so no backend is left running without a reader. A finished fit becomes
a new material (a new version if the name is taken) unless "Update Active Material" is on; a
cancelled one becomes "<name> (partial)" from its best parameters so far, where it had any.

Photos that look swapped are refused (``fit --strict``, unless "Refuse Swapped Photos" is off): the
Fit panel then shows both photos, with Swap Photos and Fit As Given. Every warning of a fit goes
to the status bar, the console (background mode too), the fit's backend.log and the Fit panel.
"""
from __future__ import annotations

import os
from pathlib import Path

import bpy

from ..core import backend_bridge, backend_setup, captures, rig_settings
from ..core.check_job import backend_check
from ..scene import drape, materials
from . import layout, modal_job, preferences, properties

fit_job = modal_job.ActiveJob()  # the one fit that may run at a time


def _abspath(path: str) -> Path:
    return Path(bpy.path.abspath(path)).resolve() if path else Path()


def _width_cm(settings) -> float | None:
    return settings.rig.width_cm or None


def _material_name(settings) -> str:
    return settings.material_name if settings is not None else ""


def new_fit(context, settings, strict: bool | None = None) -> backend_bridge.FitProcess:
    """The fit the panel's settings ask for, in a new result folder (not started); ``strict`` None:
    refuse swapped photos as the panel says."""
    reflection = captures.require_photo("reflection", settings.reflection_path, _abspath(settings.reflection_path))
    transmission = captures.require_photo("transmission", settings.transmission_path,
                                          _abspath(settings.transmission_path))
    rig = rig_settings.rig_dict(properties.rig_values(settings.rig))
    options = properties.fit_options(settings, preferences.selected_device(context), strict)
    return captures.new_fit(preferences.selected_backend(context), reflection, transmission,
                            preferences.results_parent(context), captures.fit_name(settings.material_name, reflection),
                            rig, **options)


def log_warning(operator, warning: str) -> None:
    """A fit's warning in the status bar and on the console (where background mode shows it)."""
    operator.report({"WARNING"}, warning)
    print(f"Woven Fabric: warning: {warning}")


class FABRIC_OT_fit(modal_job.ModalJobOperator, bpy.types.Operator):
    """Fit the woven-fabric parameters to the photo pair with the backend (ESC cancels)"""

    bl_idname = "fabric.fit"
    bl_label = "Fit Fabric"
    # UNDO: the new material gets its own undo step when the fit finishes.
    bl_options = {"REGISTER", "UNDO"}

    as_given: bpy.props.BoolProperty(
        name="As Given", options={"SKIP_SAVE"},
        description="Fit the photos in the order given even where their lighting reads the other way round")

    active = fit_job
    _scene_name = ""
    _warned = 0

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.scene is not None

    def start_job(self, context):
        settings = context.scene.woven_fabric
        try:
            fit = new_fit(context, settings, strict=False if self.as_given else None)
        except (backend_bridge.BackendError, ValueError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return None
        fit.start()
        if fit.done:  # could not even start
            self.report({"ERROR"}, fit.error)
            settings.fit_status = fit.error
            return None
        self._scene_name = context.scene.name
        self._warned = 0
        settings.fit_progress, settings.fit_status = 0.0, fit.status
        settings.last_result_folder = str(fit.request.out_dir)
        return fit

    def follow_job(self, context, fit) -> bool:
        fit.poll()
        for warning in fit.warnings[self._warned:]:
            log_warning(self, warning)
        self._warned = len(fit.warnings)
        settings = self._settings()
        if settings is None or (settings.fit_progress, settings.fit_status) == (fit.progress, fit.status):
            return False
        settings.fit_progress, settings.fit_status = fit.progress, fit.status
        return True

    def _settings(self):
        scene = bpy.data.scenes.get(self._scene_name)
        return scene.woven_fabric if scene is not None else None

    def finish_job(self, context, fit) -> set:
        settings = self._settings()
        if fit.state == backend_bridge.CANCELLED:
            return self._cancelled(context, fit, settings)
        if fit.state == backend_bridge.FAILED:
            hint = " Swap Photos or Fit As Given in the Fit panel." if fit.refused_swapped else ""
            self.report({"ERROR"}, fit.error + hint)
            if fit.details:
                print(f"Woven Fabric: backend log of the failed fit:\n{fit.details}")
            return {"CANCELLED"}
        try:
            material = self._material(context, fit, settings, captures.read_fit_params(fit.result))
        except Exception as exc:  # the fit is on disk; say why it did not become a material
            self.report({"ERROR"}, f"The fit finished in {fit.result.get('out_dir')} but could not become "
                                   f"a material: {exc}")
            return {"CANCELLED"}
        self._made(settings, material, f"Fit finished: material {material.name}")
        self.report({"INFO"}, f"Fitted material {material.name} (results in {fit.result.get('out_dir')})")
        return {"FINISHED"}

    def _cancelled(self, context, fit, settings) -> set:
        """A cancelled fit becomes a material where it left parameters: its params.json when it was
        cancelled after the fit ended, else its best so far, named as partial."""
        left = captures.cancelled_fit_params(fit.request.out_dir)
        if left is None:
            self.report({"WARNING"}, fit.error)
            return {"CANCELLED"}
        params, partial = left
        try:
            material = self._material(context, fit, settings, params, captures.PARTIAL if partial else "")
        except Exception as exc:
            self.report({"WARNING"}, f"{fit.error} Its parameters could not become a material: {exc}")
            return {"CANCELLED"}
        what = "the best parameters so far" if partial else "the fitted parameters"
        self._made(settings, material, f"Fit cancelled: material {material.name} from {what}")
        self.report({"WARNING"}, f"Fit cancelled: material {material.name} from {what} "
                                 f"(in {fit.request.out_dir})")
        return {"FINISHED"}

    @staticmethod
    def _made(settings, material, status: str) -> None:
        if settings is not None:
            settings.last_material = material.name
            settings.fit_status = status

    def _material(self, context, fit, settings, params: dict, suffix: str = ""):
        """The fit's material: the active one updated where the panel asks (never with partial
        parameters, ``suffix``), else a new one."""
        width = _width_cm(settings) if settings is not None else None
        folder = str(fit.request.out_dir)
        if settings is not None and settings.update_active_material and not suffix:
            target = getattr(context.object, "active_material", None) if context.object else None
            if materials.is_fabric_material(target):
                return materials.update_fit_material(target, params, width, folder)
            self.report({"WARNING"}, "The active object has no Woven Fabric material to update; "
                                     "the fit becomes a new material")
        name = captures.fit_name(_material_name(settings), fit.request.reflection) + suffix
        return materials.new_fit_material(name, params, width, folder)


class FABRIC_OT_swap_photos(bpy.types.Operator):
    """Swap the reflection and transmission photos (the reflection photo is the one lit from the front)"""

    bl_idname = "fabric.swap_photos"
    bl_label = "Swap Photos"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        settings = getattr(context.scene, "woven_fabric", None)
        return settings is not None and bool(settings.reflection_path or settings.transmission_path)

    def execute(self, context):
        settings = context.scene.woven_fabric
        settings.reflection_path, settings.transmission_path = settings.transmission_path, settings.reflection_path
        self.report({"INFO"}, f"Reflection: {settings.reflection_path}; transmission: {settings.transmission_path}")
        return {"FINISHED"}


class FABRIC_OT_cancel_fit(bpy.types.Operator):
    """Stop the running fit; its partial results stay in its folder"""

    bl_idname = "fabric.cancel_fit"
    bl_label = "Cancel Fit"

    @classmethod
    def poll(cls, context):
        return fit_job.running()

    def execute(self, context):
        fit_job.cancel()
        return {"FINISHED"}


class FABRIC_OT_check_backend(bpy.types.Operator):
    """Run the backend's interpreter and report, in words, what is missing to fit"""

    bl_idname = "fabric.check_backend"
    bl_label = "Check Backend"

    python: bpy.props.StringProperty(name="Python", options={"SKIP_SAVE"},
                                     description="Interpreter to check; empty: the one the preferences select")

    @classmethod
    def poll(cls, context):
        return not backend_check.running

    def execute(self, context):
        try:
            backend = preferences.selected_backend(context)
            if self.python:
                backend = backend_bridge.Backend(self.python, backend.script)
        except backend_bridge.BackendError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        device = preferences.selected_device(context)
        if bpy.app.background:  # no event loop would redraw the outcome: check now and report it
            check = backend_check.run(backend, device)
            self.report({"INFO"} if check.ok else {"ERROR"}, check.summary())
            return {"FINISHED"} if check.ok else {"CANCELLED"}
        backend_check.start(backend, device)
        layout.redraw_while(lambda: backend_check.running, "PREFERENCES")
        self.report({"INFO"}, f"Checking {backend.python} ...")
        return {"FINISHED"}


class FABRIC_OT_detect_python(bpy.types.Operator):
    """Look for a Python with PyTorch (the project's environment, then Blender's own) and select it"""

    bl_idname = "fabric.detect_python"
    bl_label = "Detect Python"

    def execute(self, context):
        found = backend_setup.find_interpreter()
        prefs = preferences.preferences(context)
        if not found:
            self.report({"ERROR"}, "No Python with PyTorch was found; set the Backend Python by hand "
                                   f"(tried: {', '.join(backend_setup.interpreter_candidates())})")
            return {"CANCELLED"}
        if prefs is not None:
            prefs.python_path = found
        self.report({"INFO"}, f"Backend Python: {found}")
        return {"FINISHED"}


class FABRIC_OT_reset_rig(bpy.types.Operator):
    """Set every rig setting back to the spec's defaults (the paper's rig)"""

    bl_idname = "fabric.reset_rig"
    bl_label = "Reset Rig"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        rig = context.scene.woven_fabric.rig
        for field in rig_settings.rig_fields():
            rig.property_unset(field.name)
        return {"FINISHED"}


class FABRIC_OT_load_fit(bpy.types.Operator):
    """Make a new material from an earlier fit's params.json"""

    bl_idname = "fabric.load_fit"
    bl_label = "Load Fit"
    bl_options = {"REGISTER", "UNDO"}

    filepath: bpy.props.StringProperty(subtype="FILE_PATH")
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        path = _abspath(self.filepath)
        try:
            params = captures.read_fit_params({"params": str(path)})
            settings = context.scene.woven_fabric
            name = captures.run_name(path.parent)
            material = materials.new_fit_material(name, params, _width_cm(settings), path.parent)
        except Exception as exc:
            self.report({"ERROR"}, f"{path}: {exc}")
            return {"CANCELLED"}
        settings.last_material, settings.last_result_folder = material.name, str(path.parent)
        self.report({"INFO"}, f"Material {material.name} from {path}")
        return {"FINISHED"}


def _last_material(context):
    return bpy.data.materials.get(context.scene.woven_fabric.last_material)


class FABRIC_OT_assign_material(bpy.types.Operator):
    """Give the selected meshes the fitted material in a new material slot (existing slots stay)"""

    bl_idname = "fabric.assign_material"
    bl_label = "Assign to Selected"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _last_material(context) is not None and any(o.type == "MESH" for o in context.selected_objects)

    def execute(self, context):
        materials.assign(_last_material(context), [obj for obj in context.selected_objects if obj.type == "MESH"])
        return {"FINISHED"}


class FABRIC_OT_add_drape_preview(bpy.types.Operator):
    """Add a new scene with the fitted material on a cloth draped over a sphere, camera and lights"""

    bl_idname = "fabric.add_drape_preview"
    bl_label = "Add Draped Cloth Preview"
    bl_options = {"REGISTER", "UNDO"}

    material: bpy.props.StringProperty(name="Material", description="Empty: the last fitted material")
    cloth_size_cm: bpy.props.FloatProperty(name="Cloth Size", default=100.0, min=5.0, max=1000.0,
                                           description="Side of the cloth square in centimetres")
    resolution: bpy.props.IntProperty(name="Resolution", default=40, min=4, max=200,
                                      description="Cloth grid divisions per side")
    frames: bpy.props.IntProperty(name="Frames", default=40, min=1, max=500,
                                  description="Simulated frames before the drape is kept")
    freeze: bpy.props.BoolProperty(name="Freeze Drape", default=True,
                                   description="Keep the draped shape and drop the simulation")

    @classmethod
    def poll(cls, context):
        if _last_material(context) is None:
            cls.poll_message_set("Fit a fabric (or load a fit) first: there is no fitted material")
            return False
        return True

    def execute(self, context):
        material = bpy.data.materials.get(self.material) if self.material else _last_material(context)
        if material is None:
            self.report({"ERROR"}, f"There is no material {self.material!r}.")
            return {"CANCELLED"}
        try:
            scene = drape.add_drape_preview(material, cloth_size_cm=self.cloth_size_cm, resolution=self.resolution,
                                            frames=self.frames, freeze=self.freeze,
                                            engine=context.scene.render.engine if context.scene else None)
        except Exception as exc:
            self.report({"ERROR"}, f"The draped preview could not be built: {exc}")
            return {"CANCELLED"}
        scene.woven_fabric.last_material = material.name
        if context.window is not None:
            context.window.scene = scene
        self.report({"INFO"}, f"Scene {scene.name}: {material.name} draped over a sphere")
        return {"FINISHED"}


class FABRIC_OT_open_results(bpy.types.Operator):
    """Open the folder of the last fit (params.json, report.png, renders, backend.log)"""

    bl_idname = "fabric.open_results"
    bl_label = "Open Results Folder"

    @classmethod
    def poll(cls, context):
        folder = context.scene.woven_fabric.last_result_folder
        return bool(folder) and os.path.isdir(folder)

    def execute(self, context):
        bpy.ops.wm.path_open(filepath=context.scene.woven_fabric.last_result_folder)
        return {"FINISHED"}


class FABRIC_OT_open_fit_log(bpy.types.Operator):
    """Open the fit's backend log (everything it wrote on stderr) in Blender's text editor"""

    bl_idname = "fabric.open_fit_log"
    bl_label = "Open Log"

    filepath: bpy.props.StringProperty(subtype="FILE_PATH", options={"SKIP_SAVE"})

    def execute(self, context):
        try:
            text = layout.show_text_file(context, Path(self.filepath))
        except OSError as exc:
            self.report({"ERROR"}, f"{self.filepath}: the log cannot be read ({exc.strerror or exc})")
            return {"CANCELLED"}
        self.report({"INFO"}, f"The backend log is the text {text.name!r}")
        return {"FINISHED"}


CLASSES = (FABRIC_OT_fit, FABRIC_OT_swap_photos, FABRIC_OT_cancel_fit, FABRIC_OT_check_backend, FABRIC_OT_detect_python,
           FABRIC_OT_reset_rig, FABRIC_OT_load_fit, FABRIC_OT_assign_material, FABRIC_OT_add_drape_preview,
           FABRIC_OT_open_results, FABRIC_OT_open_fit_log)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
