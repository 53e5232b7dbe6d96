"""Woven Fabric Capture: a Blender extension that fits woven-fabric materials from a photo pair.

This file only registers. The add-on's layers, whose imports point one way (ui -> scene -> core):

- ``core/``: plain Python, no bpy (paths, the backend subprocess and its setup, the backend check,
  the facts shared with the backend, the rig's settings, result folders, the batch, the shader's
  sockets and tables): testable without Blender;
- ``scene/``: what bpy builds (the node group, materials, the draped preview, the rig scene);
- ``ui/``: what the user sees (operators, panels, preferences, scene properties, the batch command).

Nothing imports torch: the backend runs as a subprocess. The ui modules are imported inside
register() because importing this package must not import bpy (core/ runs without Blender).
"""
from importlib import import_module

# The order matters: properties before the panels and operators that use them, the main panel before
# the sub-panels of the later modules.
_MODULE_NAMES = ("ui.modal_job", "ui.preferences", "ui.properties", "ui.operators", "ui.panels", "ui.batch",
                 "ui.material_operators", "ui.material_panel", "ui.batch_operators")


def _modules():
    return [import_module(f".{name}", __package__) for name in _MODULE_NAMES]


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
