"""Conformance with the paper's renderer: every dev golden case through the real command line at 64 spp,
judged by the shared checker ``compare_golden.py`` (tolerances derived from each case's noise floor)."""
import subprocess
import sys

from conftest import ROOT


def test_every_golden_case_passes_compare_golden(golden_dir, golden_cases, shared_tools, tmp_path):
    out = tmp_path / "renders"
    render = subprocess.run([sys.executable, "-m", "backend", "render-cases", str(golden_dir / "cases.json"),
                             "--out", str(out), "--spp", "64"], cwd=ROOT, capture_output=True, text=True)
    assert render.returncode == 0, render.stderr
    check = subprocess.run([sys.executable, str(shared_tools / "compare_golden.py"), str(golden_dir), str(out)],
                           capture_output=True, text=True)
    print(check.stdout)
    lines = [line for line in check.stdout.splitlines() if line.startswith(("PASS", "FAIL"))]
    assert len(lines) == len(golden_cases)
    assert check.returncode == 0 and all(line.startswith("PASS") for line in lines), check.stdout
