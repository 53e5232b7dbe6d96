"""Add-on preferences: which Python runs the backend, on which device, where fit results go; the
first-run checklist; the GPU route.

With the zip made for the artist's platform nothing needs setting: the backend runs in Blender's
own Python with the extension's installed wheels (:func:`bundled_backend`). An external Python (a
CUDA environment, a development checkout) can still be named; then the environment
(``WOVEN_FABRIC_PYTHON``, ``WOVEN_FABRIC_BACKEND_SCRIPT``) and auto-detection follow (see
backend_setup.resolve_backend).

The checklist (core/checklist.py) shows which backend is in use, its PyTorch version and device,
and whether Cycles can run the OSL shader; it is filled by a backend check on a thread
(core/check_job.py), started when the preferences are first drawn and by *Check Backend*.

The GPU route (platform zips only): *Install GPU PyTorch* downloads a CUDA build of PyTorch into the
extension's user folder (core/gpu_env.py), only when Blender allows online access. It is a modal
job (modal_job.py) with a progress bar, *Cancel* and ESC; closing the preferences window does not
stop the download (a timer follows it to the end). Once installed, *Use the GPU PyTorch* puts it
before the bundled packages.
"""
from __future__ import annotations

import sys
from pathlib import Path

import bpy

from ..core import backend_bridge, backend_setup, captures, checklist, gpu_env, paths
from ..core.check_job import backend_check
from ..scene import cycles_osl
from . import layout, modal_job

# Preferences belong to the add-on's package, not to this ui sub-package.
ADDON_PACKAGE = __package__.rpartition(".")[0]
CHECKLIST_ICONS = {checklist.OK: "CHECKMARK", checklist.PROBLEM: "ERROR", checklist.PENDING: "TIME"}


class WovenFabricPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    python_path: bpy.props.StringProperty(
        name="External Python", subtype="FILE_PATH",
        description="A Python 3.11 interpreter with PyTorch that runs the fitting backend instead (for example a "
                    "CUDA environment). Empty: Blender's own Python with the packages the extension installed")
    backend_script: bpy.props.StringProperty(
        name="Backend Script", subtype="FILE_PATH",
        description="Advanced: a script run instead of 'python -m backend' (for example a test stand-in). "
                    "Empty: the backend bundled with the add-on")
    device: bpy.props.EnumProperty(
        name="Device", default="AUTO",
        items=(("AUTO", "Automatic", "The backend's default device (the CPU)"),
               ("CPU", "CPU", "Fit on the CPU"),
               ("CUDA", "CUDA", "Fit on an NVIDIA GPU (needs a CUDA build of PyTorch)")))
    results_folder: bpy.props.StringProperty(
        name="Results Folder", subtype="DIR_PATH",
        description="Where each fit gets a new folder. Empty: 'fabric_fits' beside the saved .blend, "
                    "else the temporary folder")
    use_gpu_torch: bpy.props.BoolProperty(
        name="Use the GPU PyTorch", default=False,
        description="Run the backend with the CUDA build of PyTorch installed below, instead of the bundled "
                    "CPU build")
    cuda_index: bpy.props.StringProperty(
        name="CUDA Package Index", default=gpu_env.CUDA_INDEX,
        description="The package index the GPU PyTorch is installed from (PyTorch's index of a CUDA version)")

    def draw(self, context):
        layout_ = self.layout
        _start_first_check()
        _draw_checklist(layout_.box(), context)
        column = layout_.column()
        column.use_property_split = True
        row = column.row(align=True)
        row.prop(self, "python_path")
        row.operator("fabric.detect_python", text="", icon="VIEWZOOM")
        column.prop(self, "device")
        column.prop(self, "results_folder")
        if paths.bundled_wheels():
            _draw_gpu_route(layout_.box(), self, context)
        column = layout_.column()
        column.use_property_split = True
        column.prop(self, "backend_script")


def _draw_checklist(box, context):
    header = box.row()
    header.label(text="First-Run Checklist", icon="PREFERENCES")
    header.operator("fabric.check_backend", icon="FILE_REFRESH")
    check = backend_check.last
    items = checklist.first_run_checklist(check, backend_check.running, selected_device(context),
                                          cycles_osl.osl_problem())
    for item in items:
        layout.wrapped_labels(box, item.text, context, icon=CHECKLIST_ICONS[item.state])
    if check is not None and not backend_check.running:
        for problem in check.problems:
            layout.wrapped_labels(box, problem, context, icon="X")


_first_check_started = False


def _start_first_check():
    """Checks the backend the first time the preferences are drawn (on a thread: the draw never waits)."""
    global _first_check_started
    if _first_check_started or backend_check.last is not None or backend_check.running:
        return
    _first_check_started = True
    backend = saved_backend()
    if backend is not None:
        backend_check.start(backend, selected_device())
        layout.redraw_while(lambda: backend_check.running, "PREFERENCES")


def _draw_gpu_route(box, prefs, context):
    box.label(text="GPU PyTorch (NVIDIA CUDA, optional)", icon="MEMORY")
    job = gpu_install.job
    if job is not None and not job.done:
        modal_job.draw_progress(box, job.progress, job.status, "fabric.cancel_gpu_torch")
        return
    folder = gpu_folder()
    if gpu_env.installed(folder):
        box.prop(prefs, "use_gpu_torch")
        layout.wrapped_labels(box, f"Installed in {folder}", context, icon="CHECKMARK")
    if job is not None and job.state == gpu_env.FAILED:
        modal_job.draw_error(box, job.error, context)
    column = box.column()
    column.enabled = online_access()
    column.operator("fabric.install_gpu_torch", icon="IMPORT",
                    text="Reinstall GPU PyTorch" if gpu_env.installed(folder) else "Install GPU PyTorch")
    if not online_access():
        layout.wrapped_labels(box, "Needs online access: turn on Allow Online Access in Edit > Preferences > "
                                   "System > Network.", context, icon="INFO")
    column = box.column()
    column.use_property_split = True
    column.prop(prefs, "cuda_index")


gpu_install = modal_job.ActiveJob(survives_file=True)  # the one GPU PyTorch install that may run


class FABRIC_OT_install_gpu_torch(modal_job.ModalJobOperator, bpy.types.Operator):
    """Download a CUDA build of PyTorch (a few GB) into the extension's user folder, for NVIDIA GPUs"""

    bl_idname = "fabric.install_gpu_torch"
    bl_label = "Install GPU PyTorch"

    active = gpu_install
    timer_interval_s = layout.REDRAW_INTERVAL_S
    redraw_area = "PREFERENCES"

    def start_job(self, context):
        prefs = preferences(context)
        packages = backend_setup.bundled_backend(sys.executable, extensions_site_packages()) \
            if paths.bundled_wheels() else backend_bridge.Backend(sys.executable)
        job = gpu_env.TorchInstall(packages, gpu_folder(), gpu_env.torch_requirement(),
                                   (prefs.cuda_index if prefs else "") or None)
        try:
            job.start(online=online_access())
        except gpu_env.InstallRefused as exc:
            self.report({"ERROR"}, str(exc))
            return None
        self.report({"INFO"}, f"Installing {job.requirement} into {job.folder} ...")
        return job

    def finish_job(self, context, job) -> set:
        _use_installed(job)
        return {"FINISHED"} if job.state == gpu_env.SUCCEEDED else {"CANCELLED"}

    def cancel(self, context):
        # The preferences window closed (or a file was loaded): the download goes on, a timer follows it.
        bpy.app.timers.register(_follow_install, first_interval=layout.REDRAW_INTERVAL_S)
        self._end(context, {"CANCELLED"})


class FABRIC_OT_cancel_gpu_torch(bpy.types.Operator):
    """Stop the GPU PyTorch install; nothing is changed"""

    bl_idname = "fabric.cancel_gpu_torch"
    bl_label = "Cancel GPU PyTorch Install"

    @classmethod
    def poll(cls, context):
        return gpu_install.running()

    def execute(self, context):
        gpu_install.cancel()
        return {"FINISHED"}


def _follow_install():
    """Timer: follows an install whose operator has ended before it did, to the same end."""
    job = gpu_install.job
    if job is None:
        return None
    job.poll()
    layout.redraw_areas("PREFERENCES")
    if not job.done:
        return layout.REDRAW_INTERVAL_S
    _use_installed(job)
    return None


def _use_installed(job) -> None:
    """Once the install succeeded, the GPU PyTorch is chosen and checked."""
    prefs = preferences()
    if job.state == gpu_env.SUCCEEDED and prefs is not None:
        prefs.use_gpu_torch = True
        if prefs.device == "AUTO":
            prefs.device = "CUDA"
        backend_check.start(selected_backend(), selected_device())
        layout.redraw_while(lambda: backend_check.running, "PREFERENCES")


def preferences(context=None):
    """The add-on's preferences, or None when the add-on runs unregistered (batch from a checkout)."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_PACKAGE)
    return addon.preferences if addon else None


def extensions_site_packages() -> Path:
    """Where Blender installs the wheels of extensions (for this Blender's Python version)."""
    return Path(bpy.utils.user_resource("EXTENSIONS"), ".local", "lib",
                "python{}.{}".format(*sys.version_info[:2]), "site-packages")


def gpu_folder(create: bool = False) -> Path:
    """The GPU route's PyTorch folder in the extension's user folder (kept across updates)."""
    return Path(bpy.utils.extension_path_user(ADDON_PACKAGE, path=gpu_env.FOLDER_NAME, create=create))


def bundled_backend(context=None) -> backend_bridge.Backend | None:
    """Blender's own Python with the extension's installed wheels, when this is a platform zip."""
    if not paths.bundled_wheels():
        return None
    prefs = preferences(context)
    gpu = None
    if prefs is not None and prefs.use_gpu_torch and gpu_env.installed(gpu_folder()):
        gpu = gpu_folder()
    return backend_setup.bundled_backend(sys.executable, extensions_site_packages(), gpu)


def selected_backend(context=None, detect: bool = True) -> backend_bridge.Backend:
    """The backend the preferences (or the environment, the bundled packages, auto-detection) point at."""
    prefs = preferences(context)
    python = bpy.path.abspath(prefs.python_path) if prefs and prefs.python_path else ""
    script = bpy.path.abspath(prefs.backend_script) if prefs and prefs.backend_script else ""
    return backend_setup.resolve_backend(python, script, detect=detect, bundled=bundled_backend(context))


def saved_backend() -> backend_bridge.Backend | None:
    """The backend the preferences, the environment or the bundled packages name, without
    auto-detection; None if none."""
    try:
        return selected_backend(detect=False)
    except backend_bridge.BackendError:
        return None


def selected_device(context=None) -> str | None:
    prefs = preferences(context)
    return None if prefs is None or prefs.device == "AUTO" else prefs.device.lower()


def results_parent(context=None) -> Path:
    prefs = preferences(context)
    if prefs and prefs.results_folder:
        return Path(bpy.path.abspath(prefs.results_folder))
    return captures.default_results_parent(bpy.data.filepath)


def online_access() -> bool:
    return bool(bpy.app.online_access)


CLASSES = (WovenFabricPreferences, FABRIC_OT_install_gpu_torch, FABRIC_OT_cancel_gpu_torch)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    if bpy.app.timers.is_registered(_follow_install):
        bpy.app.timers.unregister(_follow_install)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
