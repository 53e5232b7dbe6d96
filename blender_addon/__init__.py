"""Woven Fabric Capture: a Blender extension that fits woven-fabric materials from a photo pair.

This file only registers. The modules are imported inside register() so that the plain-Python
parts (backend_bridge, captures, paths) can be imported and tested without Blender.
"""

# The order matters: properties before the panels and operators that use them.
_MODULE_NAMES = ("ui.preferences", "ui.properties", "ui.operators", "ui.panels", "batch")


def _modules():
    import importlib

    return [importlib.import_module(f".{name}", __package__) for name in _MODULE_NAMES]


def register():
    for module in _modules():
        module.register()


def unregister():
    for module in reversed(_modules()):
        module.unregister()
