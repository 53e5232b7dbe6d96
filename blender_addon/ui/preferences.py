"""Add-on preferences: which Python runs the backend, on which device, where fit results go.

Empty settings fall back to the environment (``WOVEN_FABRIC_PYTHON``,
``WOVEN_FABRIC_BACKEND_SCRIPT``) and then to auto-detection: the project's ``.venv`` beside the
backend, else Blender's own Python if PyTorch imports there (see backend_setup.resolve_backend).
Below the buttons the preferences show the last "Check Backend" (core/check_job.py).
"""
from __future__ import annotations

from pathlib import Path

import bpy

from ..core import backend_bridge, backend_setup, captures
from ..core.check_job import backend_check

# Preferences belong to the add-on's package, not to this ui sub-package.
ADDON_PACKAGE = __package__.rpartition(".")[0]


class WovenFabricPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_PACKAGE

    python_path: bpy.props.StringProperty(
        name="Backend Python", subtype="FILE_PATH",
        description="Python interpreter with PyTorch that runs the fitting backend. "
                    "Empty: the project's .venv, else Blender's own Python if PyTorch imports there")
    backend_script: bpy.props.StringProperty(
        name="Backend Script", subtype="FILE_PATH",
        description="Advanced: a script run instead of 'python -m backend' (for example a test stand-in). "
                    "Empty: the backend bundled with the add-on")
    device: bpy.props.EnumProperty(
        name="Device", default="AUTO",
        items=(("AUTO", "Automatic", "The backend's default device"),
               ("CPU", "CPU", "Fit on the CPU"),
               ("CUDA", "CUDA", "Fit on an NVIDIA GPU (needs a CUDA build of PyTorch)")))
    results_folder: bpy.props.StringProperty(
        name="Results Folder", subtype="DIR_PATH",
        description="Where each fit gets a new folder. Empty: 'fabric_fits' beside the saved .blend, "
                    "else the temporary folder")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "python_path")
        layout.prop(self, "device")
        layout.prop(self, "results_folder")
        layout.prop(self, "backend_script")
        row = layout.row()
        row.operator("fabric.detect_python", icon="VIEWZOOM")
        row.operator("fabric.check_backend", icon="CHECKMARK")
        check = backend_check.last
        if backend_check.running:
            layout.label(text="Checking the backend ...", icon="TIME")
        elif check is not None:
            box = layout.box()
            box.label(text=f"{check.python}:", icon="CHECKMARK" if check.ok else "ERROR")
            for problem in check.problems:
                box.label(text=problem, icon="X")
            for note in check.notes:
                box.label(text=note, icon="INFO")


def preferences(context=None):
    """The add-on's preferences, or None when the add-on runs unregistered (batch from a checkout)."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_PACKAGE)
    return addon.preferences if addon else None


def selected_backend(context=None, detect: bool = True) -> backend_bridge.Backend:
    """The backend the preferences (or the environment, or auto-detection) point at."""
    prefs = preferences(context)
    python = bpy.path.abspath(prefs.python_path) if prefs and prefs.python_path else ""
    script = bpy.path.abspath(prefs.backend_script) if prefs and prefs.backend_script else ""
    return backend_setup.resolve_backend(python, script, detect=detect)


def saved_backend() -> backend_bridge.Backend | None:
    """The backend the preferences or the environment name, without auto-detection; None if none."""
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


def register():
    bpy.utils.register_class(WovenFabricPreferences)


def unregister():
    bpy.utils.unregister_class(WovenFabricPreferences)
