"""Conformance with the paper's renderer: every dev golden case rendered at 64 spp as ``render-cases``
renders it (one test per case, so that pytest's workers share them out), judged by the shared checker
``compare_golden.py`` (tolerances derived from each case's noise floor). The command itself is
tested in tests/test_cli.py."""
import subprocess
import sys

import pytest
from conftest import golden_case_names

from backend.app.cli.render import parse_case, render_and_save
from backend.core.rig import DEFAULT_RIG


@pytest.mark.parametrize("name", golden_case_names())
def test_the_golden_case_passes_compare_golden(name, golden_dir, golden_cases, shared_tools, tmp_path):
    index, case = next((i, c) for i, c in enumerate(golden_cases) if c["name"] == name)
    name, params, options = parse_case(case, index, golden_dir / "cases.json")
    render_and_save(params, tmp_path, (f"{name}_R.png", f"{name}_T.png"), DEFAULT_RIG, options,
                    size=512, spp=64, seed=0, dev="cpu")
    check = subprocess.run([sys.executable, str(shared_tools / "compare_golden.py"), str(golden_dir), str(tmp_path),
                            name], capture_output=True, text=True)
    print(check.stdout)
    lines = [line for line in check.stdout.splitlines() if line.startswith(("PASS", "FAIL"))]
    assert len(lines) == 1 and lines[0].startswith(f"PASS {name}:") and check.returncode == 0, check.stdout
