"""``python -m devtools gpu-check``'s plan, budget and reporting (on made-up command outputs and a
made-up clock: the real steps need a GPU and minutes), its command runner's time limit, and the gpu
marker's deselection without CUDA (tests/conftest.py)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from devtools import gpu_check
from devtools.gpu_check import Outcome, Step, plan, render_step, run_check, run_command

ROOT = Path(__file__).resolve().parents[1]
MACHINE = {"device": "cuda", "gpu": "made-up GPU"}
RENDER = {"cuda": {"backward_s": 0.01, "eager_backward_s": 0.02, "compiled": True},
          "cpu": {"backward_s": 0.5, "eager_backward_s": 1.0, "compiled": True}}


def _data(tmp_path: Path) -> tuple[Path, Path]:
    golden, real = tmp_path / "golden", tmp_path / "real"
    golden.mkdir()
    real.mkdir()
    (golden / "cases.json").write_text(json.dumps([{"name": "ablated", "flags": {"diffuse": False}},
                                                   {"name": "first", "params": ""}]))
    for folder, name in ((golden, "first"), (real, "denim")):
        for side in "RT":
            (folder / f"{name}_{side}.png").write_bytes(b"")
    return golden, real


class FakeMachine:
    """Runs no command: each step takes the given seconds on a made-up clock and prints canned output."""

    def __init__(self, seconds: dict[str, float], ledger: Path | None = None):
        self.now, self.seconds, self.ledger, self.ran = 0.0, seconds, ledger, []

    def clock(self) -> float:
        return self.now

    def __call__(self, step: Step, timeout: float, echo) -> Outcome:
        self.ran.append((step.name, timeout))
        took = self.seconds.get(step.name, 1.0)
        if step.name.startswith("render on"):
            stdout = json.dumps(RENDER["cpu" if "threads" in step.name else "cuda"]) + "\n"
        elif step.name.startswith("fit-"):
            kind = step.name[4:]
            stdout = (json.dumps({"kind": kind, "name": "p1", "wall_s": 7.5, "pattern": "twill1", "flip_R": 0.1,
                                  "flip_T": 0.12, "spectrum_corr_R": 0.7, "spectrum_corr_T": 0.8}) + "\n"
                      + json.dumps({"real": {"pairs": 1}}) + "\n")
            if self.ledger is not None:
                with (self.ledger / "fit.jsonl").open("a") as ledger:
                    ledger.write('{"kind": "row"}\n{"kind": "summary"}\n')
        else:
            stdout = "........ \n8 passed in 12.0s\n"
        if took > timeout:  # stopped at its limit
            self.now += timeout
            return Outcome(None, stdout[:10], timeout)
        self.now += took
        for line in stdout.splitlines():
            echo(line)
        return Outcome(0, stdout, took)


def test_the_plan_runs_the_tests_then_the_renders_then_the_real_and_golden_fits(tmp_path):
    golden, real = _data(tmp_path)
    steps = plan("cuda", False, golden, real, tmp_path / "out")
    assert [s.name for s in steps] == ["gpu-tests", "render on cuda", "render on cpu (2 threads)", "fit-real",
                                       "fit-golden"]
    tests, render_gpu, render_cpu, fit_real, fit_golden = steps
    assert tests.argv[1:5] == ["-m", "pytest", "-m", "gpu"] and "--collect-only" not in tests.argv
    assert render_gpu.argv[-2:] == ["--device", "cuda"] and render_cpu.argv[-2:] == ["--device", "cpu"]
    assert render_cpu.env["OMP_NUM_THREADS"] == str(gpu_check.CPU_BASELINE_THREADS)
    assert render_gpu.argv[render_gpu.argv.index("--size") + 1] == "512"
    for step, option, folder in ((fit_real, "--real", real), (fit_golden, "--golden", golden)):
        assert step.argv[step.argv.index(option) + 1] == str(folder)
        assert step.argv[step.argv.index("--device") + 1] == "cuda" and "--cases" not in step.argv


def test_a_quick_cpu_dry_run_collects_the_tests_and_shrinks_everything(tmp_path):
    golden, real = _data(tmp_path)
    tests, render_device, _, fit_real, fit_golden = plan("cpu", True, golden, real, tmp_path / "out", record=False)
    assert "--collect-only" in tests.argv  # the GPU tests need CUDA: a dry run only collects them
    assert render_device.argv[render_device.argv.index("--size") + 1] == "64"
    assert render_device.env["WFC_COMPILE"] == "0" and "--no-record" in render_device.argv
    assert fit_real.argv[fit_real.argv.index("--cases") + 1] == "denim"
    assert fit_golden.argv[fit_golden.argv.index("--cases") + 1] == "first"  # the first without ablation flags
    assert "--fit-args=--size 64 --output-spp 1" in fit_golden.argv


def test_the_check_skips_what_no_longer_fits_the_budget_and_says_so(tmp_path, capsys):
    golden, real = _data(tmp_path)
    ledger = tmp_path / "ledger"
    ledger.mkdir()
    (ledger / "fit.jsonl").write_text('{"kind": "old"}\n')
    fake = FakeMachine({"gpu-tests": 100, "render on cuda": 50, "render on cpu (2 threads)": 60, "fit-real": 320},
                       ledger)
    out = tmp_path / "out"
    summary = run_check(plan("cuda", False, golden, real, out), 540, out, "cuda", runner=fake, clock=fake.clock,
                        machine_info=MACHINE, ledger_folder=ledger)
    steps = summary["steps"]
    assert [name for name, _ in fake.ran] == ["gpu-tests", "render on cuda", "render on cpu (2 threads)", "fit-real"]
    assert fake.ran[0][1] == gpu_check.TESTS_CAP_S and fake.ran[3][1] == 540 - 210  # a fit set: the budget left
    assert steps["gpu-tests"] == {"status": "ok", "seconds": 100, "passed": 8}
    assert steps["fit-golden"]["status"] == "skipped" and "10 s left" in steps["fit-golden"]["reason"]
    assert summary["figures"]["render_ratio"] == 50.0 and summary["figures"]["render_ratio_eager"] == 50.0
    assert summary["figures"]["fit_real"]["wall_s_max"] == 7.5
    assert summary["complete"] is False
    assert json.loads((out / "summary.json").read_text()) == summary
    log = (out / "gpu-check.log").read_text()
    assert "fit-golden: SKIPPED, 10 s of the budget left" in log and "made-up GPU" in log
    assert "NOT COMPLETE" in log and "8 passed" in log  # the commands' output is in the log
    assert "fit-golden: SKIPPED" in capsys.readouterr().out
    # only what the steps appended to the ledger is copied to the output
    assert (out / "ledger" / "fit.jsonl").read_text() == '{"kind": "row"}\n{"kind": "summary"}\n'
    assert summary["ledger"] == {"fit.jsonl": 2}


def test_a_step_stopped_at_its_limit_and_missing_data_are_reported(tmp_path):
    golden, _ = _data(tmp_path)
    fake = FakeMachine({"render on cuda": 1000})
    out = tmp_path / "out"
    summary = run_check(plan("cuda", False, golden, tmp_path / "nowhere", out), 540, out, "cuda", runner=fake,
                        clock=fake.clock, machine_info=MACHINE, ledger_folder=tmp_path / "no-ledger")
    stopped = summary["steps"]["render on cuda"]
    assert stopped["status"] == "stopped" and "partial" in stopped["reason"]
    assert summary["steps"]["fit-real"] == {"status": "skipped",
                                            "reason": f"no real pairs at {tmp_path / 'nowhere'}"}
    assert "render_ratio" not in summary["figures"] and summary["complete"] is False


def test_every_step_ok_is_a_complete_check(tmp_path):
    golden, real = _data(tmp_path)
    fake = FakeMachine({})
    summary = run_check(plan("cuda", False, golden, real, tmp_path / "out"), 540, tmp_path / "out", "cuda",
                        runner=fake, clock=fake.clock, machine_info=MACHINE, ledger_folder=tmp_path / "no-ledger")
    assert summary["complete"] is True and all(s["status"] == "ok" for s in summary["steps"].values())


def test_the_runner_stops_a_command_at_its_time_limit_and_keeps_its_output():
    step = Step("sleeper", [sys.executable, "-c", "import time; print('started', flush=True); time.sleep(60)"],
                60, 0, gpu_check.last_json)
    echoed = []
    outcome = run_command(step, 2.0, echoed.append)
    assert outcome.returncode is None and outcome.stdout == "started\n" and echoed == ["started"]
    done = run_command(Step("quick", [sys.executable, "-c", "print('{\"a\": 1}')"], 60, 0, gpu_check.last_json),
                       30.0, echoed.append)
    assert done.returncode == 0 and gpu_check.last_json(done.stdout) == {"a": 1}


def _pytest(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "CUDA_VISIBLE_DEVICES": "", "OMP_NUM_THREADS": "1"}  # no CUDA, even on a GPU machine
    return subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-q", "tests/test_gpu.py", *args],
                          cwd=ROOT, capture_output=True, text=True, env=env, timeout=300)


def test_without_cuda_the_gpu_tests_are_deselected_and_the_summary_says_so():
    collected = _pytest("-m", "gpu", "--collect-only", "-n", "0")
    count = int(collected.stdout.split(" tests collected")[0].split()[-1])
    assert count >= 5
    for workers in ("0", "1"):  # in this process, and through a pytest-xdist worker and its controller
        done = _pytest("-n", workers)
        assert done.returncode == 5, done.stdout[-2000:]  # nothing ran: pytest's "no tests collected"
        assert f"{count} GPU test(s) NOT RUN: no CUDA device is present" in done.stdout
        assert "python -m devtools gpu-check" in done.stdout


def test_asked_for_without_cuda_the_gpu_tests_fail_loudly():
    done = _pytest("-m", "gpu", "-n", "0", "-k", "render_on_cuda and 0.0")
    assert done.returncode == 1
    assert "no CUDA device: these tests need one" in done.stdout


def test_the_render_step_names_say_which_is_the_baseline():
    assert render_step("cuda") == "render on cuda"
    assert render_step("cpu", 2) == "render on cpu (2 threads)"


def test_the_command_refuses_a_device_this_machine_lacks(tmp_path, capsys, monkeypatch):
    from devtools.cli.main import main

    monkeypatch.setattr("torch.cuda.is_available", lambda: False)
    assert main(["gpu-check", "--out", str(tmp_path / "out"), "--no-record"]) == 2  # the default: cuda
    assert "--device cuda: CUDA is not available" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    # the bench's --device goes to the fits, once
    assert main(["bench", "fit", "--real", str(tmp_path), "--device", "cpu", "--fit-args", "--device cpu",
                 "--no-record"]) == 2
    assert "give the device once" in capsys.readouterr().err
