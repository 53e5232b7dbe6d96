"""Plain Python, testable without Blender: the backend subprocess, its setup and check, the facts
read from the backend's declarations, the rig's settings, result folders, the batch, the shader's
sockets and weave tables, the rig's output transform.

Imports: the standard library, numpy, and the backend's torch-free ``core`` modules through
paths.backend_module; never bpy, scene/ or ui/, never torch (tests/test_addon_bridge.py checks).
"""
