"""Helpers of the add-on tests: the bpy requirement, a Python without PyTorch, a bpy subprocess.

bpy is a declared dependency (the ``blender`` extra the README installs): a missing bpy is a broken
install, so the tests that need it fail and say so instead of skipping.
"""
from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def require_bpy() -> None:
    if importlib.util.find_spec("bpy") is None:
        pytest.fail("the bpy module is not installed; install the project with pip install -e '.[test,blender]'")


def validate_extension(zip_path: Path) -> str:
    """Runs Blender's own extension validator (``blender_ext.py validate``, in the bpy module) on a zip;
    fails the test with its output unless it accepts the zip; returns that output."""
    require_bpy()
    validator = next(Path(importlib.util.find_spec("bpy").origin).parent.glob(
        "*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    checked = subprocess.run([sys.executable, str(validator), "validate", str(zip_path)], capture_output=True,
                             text=True, timeout=120)
    output = checked.stdout + checked.stderr
    assert checked.returncode == 0 and "Success" in checked.stdout, output
    return output


def python_without_torch(folder: Path) -> str:
    """A fresh Python 3.11 without PyTorch (a virtual environment without pip or site-packages)."""
    done = subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(folder)], capture_output=True,
                          text=True)
    assert done.returncode == 0, done.stderr
    return str(folder / "bin" / "python")


def extension_zip_for_tests(folder: Path) -> Path:
    """The extension zip to test: ``WOVEN_FABRIC_TEST_ZIP`` if set, else one built into ``folder``."""
    if os.environ.get("WOVEN_FABRIC_TEST_ZIP"):
        return Path(os.environ["WOVEN_FABRIC_TEST_ZIP"])
    spec = importlib.util.spec_from_file_location("woven_fabric_build", ROOT / "build.py")
    build = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build)
    return build.build(folder)


def run_blender(script: str, tmp_path: Path, timeout: int = 300) -> dict:
    """Runs `script` with the bpy module in a fresh interpreter; returns the JSON it prints last.

    The script sees ``bpy``, ``rig_scene`` and ``node_group`` (blender_addon.scene) and ``emit(obj)``.
    """
    require_bpy()
    path = tmp_path / "script.py"
    prelude = textwrap.dedent(f"""
        import sys, json
        sys.path.insert(0, {str(ROOT)!r})
        import bpy
        from blender_addon.scene import node_group, rig_scene
        def emit(obj):
            print("RESULT " + json.dumps(obj), flush=True)
    """)
    path.write_text(prelude + textwrap.dedent(script))
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "blender_user"), PYTHONUNBUFFERED="1")
    done = subprocess.run([sys.executable, str(path)], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=timeout)
    results = [line[7:] for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    assert done.returncode == 0 and results, f"blender script failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return json.loads(results[-1])
