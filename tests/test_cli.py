"""The command line contract: outputs, 16-bit images, and clear errors with exit code 2."""
import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
import torch
from conftest import ROOT

from backend.core.params import FabricParams

EXAMPLE = ("twill1_R_0.6,0.66_S_0.75,1.53_T_1.33,1.39_N_0.0_UV_121.8,168.9_Kd_0.456,0.398,0.089,0.286,0.279,0.0"
           "_G_0.99,1.0_Rm_0.65,0.62_Tm_2.66,0.79_W_0.71,1.29_Ks_0.325,0.37,0.0,0.351,0.883,0.0_Psi_-30.5,-29.5")


def run(*args, env=None, program="backend"):
    return subprocess.run([sys.executable, "-m", program, *args], cwd=ROOT, capture_output=True, text=True, env=env)


def test_render_writes_16_bit_images_and_params(tmp_path):
    result = run("render", EXAMPLE, "--out", str(tmp_path), "--spp", "2", "--size", "48")
    assert result.returncode == 0, result.stderr
    for name in ("reflection.png", "transmission.png"):
        image = cv2.imread(str(tmp_path / name), cv2.IMREAD_UNCHANGED)
        assert image.dtype == np.uint16 and image.shape == (48, 48, 3)
        assert 0.05 < image.mean() / 65535 < 0.95
    saved = json.loads((tmp_path / "params.json").read_text())
    assert FabricParams.from_dict(saved) == FabricParams.from_interchange(EXAMPLE)
    assert saved["interchange"] == EXAMPLE and saved["spp"] == 2


def test_render_reads_a_json_file_with_flags_and_rig(tmp_path):
    params = tmp_path / "p.json"
    params.write_text(FabricParams(pattern="satin0").to_json())
    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps({"camera_height": 6.0, "fov_deg": 40.0}))
    result = run("render", str(params), "--out", str(tmp_path / "o"), "--spp", "1", "--size", "16",
                 "--rig", str(rig), "--flags", '{"layers": 1, "glow": false}')
    assert result.returncode == 0, result.stderr
    saved = json.loads((tmp_path / "o" / "params.json").read_text())
    assert saved["rig"]["camera_height"] == 6.0 and saved["flags"] == {"layers": 1, "glow": False}


@pytest.mark.parametrize("args,needle", [
    (["render", "missing.json", "--out", "OUT"], "missing.json: cannot read"),
    (["render", "plain_R_0.5,0.5", "--out", "OUT"], "missing key(s)"),
    (["render", EXAMPLE.replace("R_0.6,0.66", "R_0.6,7.0"), "--out", "OUT"], "roughness: 7.0 is outside [0.01, 1]"),
    (["render", EXAMPLE, "--out", "OUT", "--flags", "{bad"], "--flags: not valid JSON"),
    (["render", EXAMPLE, "--out", "OUT", "--flags", '{"layers": 3}'], "layers: expected 1 or 2"),
    (["render", EXAMPLE, "--out", "OUT", "--rig", "RIG"], "cannot read"),
    (["render-cases", "CASES", "--out", "OUT"], "cannot read"),
    (["fit", "--example", "--out", "OUT", "--size", "0"], "must be at least 32 pixels, got 0"),
    (["fit", "--example", "--out", "OUT", "--size", "1024"], "--size 1024: larger than the photos' working size"),
])
def test_bad_input_gives_exit_code_2_and_a_clear_message(tmp_path, args, needle):
    args = [str(tmp_path / "x") if a == "OUT" else str(tmp_path / "nothing.json") if a in ("RIG", "CASES") else a
            for a in args]
    result = run(*args)
    assert result.returncode == 2
    assert needle in result.stderr
    assert "Traceback" not in result.stderr


def test_render_cases_uses_names_and_flags(tmp_path):
    cases = [{"name": "a", "params": EXAMPLE, "flags": {}},
             {"name": "b", "params": FabricParams(pattern="plain").to_dict(), "flags": {"diffuse": False}}]
    path = tmp_path / "cases.json"
    path.write_text(json.dumps(cases))
    result = run("render-cases", str(path), "--out", str(tmp_path / "o"), "--spp", "1", "--size", "16")
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["a_R.png", "a_T.png", "b_R.png", "b_T.png"]


def test_render_cases_reports_the_bad_case(tmp_path):
    path = tmp_path / "cases.json"
    path.write_text(json.dumps([{"name": "ok", "params": EXAMPLE},
                                {"name": "bad", "params": EXAMPLE, "flags": {"glowing": 1}}]))
    result = run("render-cases", str(path), "--out", str(tmp_path / "o"))
    assert result.returncode == 2
    assert "case 'bad'" in result.stderr and "unknown flag" in result.stderr


def test_bench_prints_one_json_line_with_the_figures():
    # Eager only here: compilation has its own test, and a cold compile costs half a minute.
    result = run("bench", "render", "--json", "--size", "32", "--spp", "1", "--runs", "1", "--no-record",
                 env={**os.environ, "WFC_COMPILE": "0"}, program="devtools")
    assert result.returncode == 0, result.stderr
    figures = json.loads(result.stdout.strip().splitlines()[-1])
    for key in ("forward_s", "backward_s", "eager_forward_s", "peak_mb", "autograd_backward_s",
                "hand_gradient_speedup"):
        assert figures[key] > 0
    assert figures["size"] == 32 and figures["spp"] == 1 and figures["compiled"] is False


def test_cuda_request_without_cuda_is_a_clear_error(tmp_path):
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA; the error path is for machines without it")
    result = run("render", EXAMPLE, "--out", str(tmp_path), "--device", "cuda")
    assert result.returncode == 2 and "CUDA is not available" in result.stderr
