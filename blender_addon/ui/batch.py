"""The batch fit as Blender offers it: the ``blender --command fabric_fit`` command and the
``fabric.batch_fit`` operator (for scripts). core/batch.py does the work; here it gets the backend
the add-on preferences name and scene/materials.py's AssetLibrary for the materials.
"""
from __future__ import annotations

import bpy

from ..core import batch, declarations
from ..scene import materials
from . import preferences


def main(argv: list[str] | None = None) -> int:
    """``blender --command fabric_fit ARGS``: fits a folder of photo pairs; returns the exit code."""
    return batch.main(argv, library=materials.AssetLibrary(), preferred_backend=preferences.saved_backend)


class FABRIC_OT_batch_fit(bpy.types.Operator):
    """Fit every photo pair of a folder into a .blend of asset materials (blocks until done: for scripts)"""

    bl_idname = "fabric.batch_fit"
    bl_label = "Batch Fit Folder"

    directory: bpy.props.StringProperty(subtype="DIR_PATH", name="Photos")
    filepath: bpy.props.StringProperty(subtype="FILE_PATH", name="Library",
                                       description="The .blend to write (default: in the photo folder)")
    pattern: bpy.props.StringProperty(default=declarations.AUTO_PATTERN)
    iterations: bpy.props.IntProperty(default=0, min=0)
    width_cm: bpy.props.FloatProperty(default=0.0, min=0.0)

    def execute(self, context):
        argv = [bpy.path.abspath(self.directory), "--pattern", self.pattern]
        if self.filepath:
            argv += ["--out", bpy.path.abspath(self.filepath)]
        if self.iterations:
            argv += ["--iterations", str(self.iterations)]
        if self.width_cm:
            argv += ["--width-cm", str(self.width_cm)]
        failed = main(argv)
        if failed:
            self.report({"WARNING"}, f"{failed} pair(s) failed; see the console")
        return {"FINISHED"}


_cli_handle = None


def register():
    global _cli_handle
    bpy.utils.register_class(FABRIC_OT_batch_fit)
    _cli_handle = bpy.utils.register_cli_command(batch.CLI_COMMAND, main)


def unregister():
    global _cli_handle
    if _cli_handle is not None:
        bpy.utils.unregister_cli_command(_cli_handle)
        _cli_handle = None
    bpy.utils.unregister_class(FABRIC_OT_batch_fit)
