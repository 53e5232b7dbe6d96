"""Headless batch: fit every ``<name>_R.* / <name>_T.*`` pair of a folder into a .blend of asset
materials (exit code: the number of failed pairs; see core/batch.py for the rules).

Three ways to run it::

    blender --background --command fabric_fit PHOTOS/ [--out LIBRARY.blend] [options]
    blender --background --python-expr "import sys; from bl_ext.user_default.woven_fabric import batch; \\
        sys.exit(batch.main(['PHOTOS/', '--out', 'LIBRARY.blend']))"
    python -m blender_addon.batch PHOTOS/ [options]     # the bpy module, from a checkout
    blender --background --command fabric_fit --from-results DIR [--out LIBRARY.blend]   # no fitting:
        # the results folders of ``python -m backend batch --out DIR`` (e.g. fitted on a cluster)

(``bpy.ops.fabric.batch_fit(directory=..., filepath=...)`` does the same from a script.) Options:
see ``--help``. This module is only the entry point; the command is ui/batch.py's ``main``.
"""
from __future__ import annotations

import sys

from .ui.batch import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
