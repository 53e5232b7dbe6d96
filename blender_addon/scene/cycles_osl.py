"""Cycles' Open Shading Language tools, as the Woven Fabric node group and the rig scene need them.

Cycles compiles a Script node with ``oslquery``, which lives in Blender's bundled site-packages;
the pip ``bpy`` module does not put that folder on ``sys.path``, so :func:`ensure_oslquery` does.
:func:`osl_problem` says whether this Blender can run the shader at all (the preferences' checklist).
"""
from __future__ import annotations

import functools
import importlib.util
import os
import sys

import bpy


def ensure_oslquery() -> None:
    """Blender's bundled site-packages (which hold ``oslquery``) on ``sys.path``."""
    path = os.path.join(bpy.utils.resource_path("LOCAL"), "python", "lib",
                        f"python{sys.version_info.major}.{sys.version_info.minor}", "site-packages")
    if os.path.isdir(path) and path not in sys.path:
        sys.path.append(path)


@functools.cache  # asked on every redraw of the preferences; the answer is the build's
def osl_problem() -> str:
    """Why Cycles cannot run the Woven Fabric OSL shader in this Blender, or "" when it can."""
    try:
        import _cycles  # Cycles' compiled module: whether this build has OSL at all
    except ImportError:
        return "the Cycles add-on is not available"
    if not getattr(_cycles, "with_osl", False):
        return "this Blender's Cycles was built without Open Shading Language"
    ensure_oslquery()
    if importlib.util.find_spec("oslquery") is None:
        return "Cycles cannot compile OSL scripts here (its oslquery module is missing)"
    return ""


def compile_script(node) -> str:
    """Compiles a Script node's OSL (Cycles' own compile-and-update, which also makes the node's
    sockets and stores the bytecode in it). Returns "" or the error."""
    ensure_oslquery()
    try:
        # Optional: without Cycles the node group is still built and renders its fallback.
        from cycles import osl as cycles_osl
    except ImportError as exc:  # pragma: no cover - Cycles is always bundled
        return f"the Cycles add-on is not available to compile the OSL shader ({exc})"
    messages = []
    try:
        ok = cycles_osl.update_script_node(node, lambda kind, text: messages.append(f"{kind}: {text}"))
    except ImportError as exc:  # pragma: no cover - oslquery missing from this Blender
        return f"Cycles cannot compile OSL here ({exc})"
    return "" if ok else "compiling shaders/woven_fabric.osl failed: " + "; ".join(messages)
