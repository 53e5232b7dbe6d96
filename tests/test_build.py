"""build.py bundles what runs in the add-on and nothing else: the bundled backend fits, its
development tools (benchmarks, dataset, training) are left out and their commands are gone."""
import os
import subprocess
import sys
import zipfile

import pytest
from conftest import ROOT


@pytest.fixture(scope="module")
def unpacked(build_module, tmp_path_factory):
    folder = tmp_path_factory.mktemp("extension")
    with zipfile.ZipFile(build_module.build(tmp_path_factory.mktemp("dist"))) as archive:
        archive.extractall(folder)
    return folder


def test_every_development_only_entry_exists(build_module):
    # A stale entry would silently bundle a renamed tool.
    for entry in build_module.DEVELOPMENT_ONLY:
        assert (ROOT / entry.rstrip("/")).exists(), entry


def test_the_bundle_leaves_the_development_tools_out(build_module, unpacked):
    names = {p.relative_to(unpacked).as_posix() for p in unpacked.rglob("*") if p.is_file()}
    assert "backend/cli/fit.py" in names and "backend/data/init_net.pt" in names
    assert not [n for n in names if build_module._development_only(n)]
    assert not [n for n in names if n.startswith("tests/") or "__pycache__" in n]


def test_the_bundled_backend_runs_without_its_development_commands(unpacked):
    env = {**os.environ, "PYTHONPATH": str(unpacked)}
    result = subprocess.run([sys.executable, "-m", "backend", "--help"], cwd=unpacked, env=env,
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert "{render,render-cases,fit}" in result.stdout
    refused = subprocess.run([sys.executable, "-m", "backend", "bench", "render"], cwd=unpacked, env=env,
                             capture_output=True, text=True)
    assert refused.returncode == 2 and "invalid choice: 'bench'" in refused.stderr
