"""build.py bundles whole folders (the add-on, backend/, shaders/) and nothing else: the developer
tools live in devtools/, which never ships, and the bundled backend runs without them."""
import os
import subprocess
import sys
import zipfile

import pytest


@pytest.fixture(scope="module")
def unpacked(build_module, tmp_path_factory):
    folder = tmp_path_factory.mktemp("extension")
    with zipfile.ZipFile(build_module.build(tmp_path_factory.mktemp("dist"))) as archive:
        archive.extractall(folder)
    return folder


def test_the_bundle_is_the_shipped_folders_whole(unpacked):
    names = {p.relative_to(unpacked).as_posix() for p in unpacked.rglob("*") if p.is_file()}
    assert "backend/app/cli/fit.py" in names and "backend/data/init_net.pt" in names
    assert "shaders/woven_fabric.osl" in names and "blender_manifest.toml" in names
    assert not [n for n in names if n.startswith(("devtools/", "tests/")) or "__pycache__" in n]


def test_the_bundled_backend_imports_every_module_without_the_developer_tools(unpacked):
    env = {**os.environ, "PYTHONPATH": str(unpacked)}
    script = ("import importlib, pathlib, sys\n"
              "names = sorted('.'.join(p.with_suffix('').parts) for p in pathlib.Path('backend').rglob('*.py')\n"
              "               if p.name not in ('__main__.py',))\n"
              "for name in names:\n"
              "    importlib.import_module(name.removesuffix('.__init__'))\n"
              "assert 'devtools' not in sys.modules\n"
              "print(len(names))\n")
    result = subprocess.run([sys.executable, "-c", script], cwd=unpacked, env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert int(result.stdout) > 50


def test_the_bundled_command_line_has_the_users_commands_only(unpacked):
    env = {**os.environ, "PYTHONPATH": str(unpacked)}
    result = subprocess.run([sys.executable, "-m", "backend", "--help"], cwd=unpacked, env=env,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "{render,render-cases,fit,batch,warm-compile}" in result.stdout
    refused = subprocess.run([sys.executable, "-m", "backend", "bench", "render"], cwd=unpacked, env=env,
                             capture_output=True, text=True)
    assert refused.returncode == 2 and "invalid choice: 'bench'" in refused.stderr
