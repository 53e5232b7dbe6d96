"""Where the add-on finds the backend and the shader, and how it loads the backend's plain modules.

Two layouts are supported:
- installed extension (built by build.py): ``<extension>/backend/`` and ``<extension>/shaders/``
  sit inside the add-on folder;
- the repository: ``blender_addon/``, ``backend/`` and ``shaders/`` are siblings.

:func:`bundled_wheels` says whether this is a platform zip (its manifest lists the backend's
wheels, which Blender installed into the extensions' site-packages).

:func:`backend_module` imports a torch-free backend module (``core.params``, ``core.rig``, ...)
under a private package name, so that no top-level ``backend`` module is added to Blender's Python;
declarations.py says which facts the add-on reads that way.
"""
from __future__ import annotations

import functools
import importlib
import importlib.util
import sys
import tomllib
from pathlib import Path

_ADDON = Path(__file__).resolve().parent.parent  # blender_addon/ (the extension folder when installed)
_ALIAS = "_woven_fabric_backend"


def backend_root() -> Path:
    """The folder that contains the ``backend`` package (put it on PYTHONPATH for the subprocess)."""
    for root in (_ADDON, _ADDON.parent):
        if (root / "backend" / "__init__.py").is_file():
            return root
    raise FileNotFoundError(f"the fabric backend was not found next to {_ADDON}; reinstall the add-on")


def shader_path() -> Path:
    """The OSL source of the Woven Fabric shader."""
    for root in (_ADDON, _ADDON.parent):
        path = root / "shaders" / "woven_fabric.osl"
        if path.is_file():
            return path
    raise FileNotFoundError(f"shaders/woven_fabric.osl was not found next to {_ADDON}; reinstall the add-on")


@functools.cache  # the manifest of an installed extension does not change while it is loaded
def bundled_wheels() -> tuple[str, ...]:
    """The wheels the extension's manifest lists (a platform zip); () for the plain zip or a checkout."""
    try:
        with open(_ADDON / "blender_manifest.toml", "rb") as fh:
            return tuple(tomllib.load(fh).get("wheels", ()))
    except (OSError, tomllib.TOMLDecodeError):
        return ()


def write_whole(path: str | Path, content: str | bytes) -> Path:
    """Writes a file whole or not at all, as the backend writes its own (``core.jsonfile.write_whole``:
    a hidden temporary beside it, synced, renamed over it), so a crash or a kill mid-write never
    leaves an artist's file half written."""
    return backend_module("core.jsonfile").write_whole(path, content)


def backend_module(name: str):
    """Imports ``backend.<name>`` (a torch-free module such as core.params) under a private alias."""
    if _ALIAS not in sys.modules:
        package = backend_root() / "backend"
        spec = importlib.util.spec_from_file_location(_ALIAS, package / "__init__.py",
                                                      submodule_search_locations=[str(package)])
        module = importlib.util.module_from_spec(spec)
        sys.modules[_ALIAS] = module
        spec.loader.exec_module(module)
    return importlib.import_module(f"{_ALIAS}.{name}")
