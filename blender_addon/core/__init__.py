"""Plain Python, testable without Blender: the backend subprocess, its setup and check, the facts
read from the backend's declarations, the rig's settings, result folders, the batch (headless and
the sidebar's queue), the shader's sockets, weave tables and which shader renders, the rig's output
transform, the material tools' rules (colour layers, real-world scale, asset catalogs and tags).

Imports: the standard library, numpy, and the backend's torch-free ``core`` modules through
paths.backend_module; never bpy, scene/ or ui/, never torch (tests/test_addon_bridge.py checks).
"""
