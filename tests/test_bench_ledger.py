"""The results ledger: every benchmark run appends what it printed, with its commit, date, command,
machine and data, to devtools/bench/results/<bench>.jsonl; a dry run and a run outside a git
checkout are handled."""
import json
import re
import subprocess

import pytest

from devtools.bench import fit, ledger, placement
from devtools.bench.ledger import Ledger
from devtools.cli.main import main

RUN_FIELDS = {"bench", "date", "commit", "dirty", "command", "environment", "machine", "datasets", "kind", "data"}


def _records(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.fixture
def results(tmp_path, monkeypatch):
    """The ledger's folder, away from the checkout's."""
    folder = tmp_path / "results"
    monkeypatch.setattr(ledger, "RESULTS", folder)
    return folder


@pytest.fixture
def placed_pairs(monkeypatch):
    """``bench placement`` on two made-up pairs: the ledger sees its rows, not the placement's work."""
    jobs = [{"kind": "photolike", "name": name} for name in ("first", "second")]
    monkeypatch.setattr(placement, "pair_jobs", lambda synthetic, real, names: jobs)
    monkeypatch.setattr(placement, "place", lambda job: {
        "kind": job["kind"], "name": job["name"], "rotation_deg": 0.1, "skew_deg": 0.0, "true_rotation_deg": 0.2,
        "true_skew_deg": 0.0, "rotation_error_deg": 0.1, "tiles_error_pct": 0.5, "best_scored_is_true": True,
        "candidates": [], "seconds": 1.0})


def test_a_run_appends_one_record_per_row_it_prints_and_one_summary(results, placed_pairs, tmp_path, monkeypatch,
                                                                    capsys):
    monkeypatch.setenv("WFC_COMPILE", "0")
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    monkeypatch.setenv("UNRELATED", "x")
    monkeypatch.setenv("MKL_CBWR", "COMPATIBLE")  # a numeric library's code path: it changes the fits' last bits
    argv = ["bench", "placement", "--synthetic", str(tmp_path / "set"), "--json"]
    assert main(argv) == 0
    printed = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    records = _records(results / "placement.jsonl")
    assert [r["kind"] for r in records] == ["row", "row", "summary"]
    assert [r["data"] for r in records] == printed  # what it printed, as printed
    for record in records:
        assert set(record) == RUN_FIELDS
        assert record["bench"] == "placement" and record["command"] == "python -m devtools " + " ".join(argv)
        assert record["datasets"] == [str((tmp_path / "set").resolve())]
        assert record["environment"] == {"MKL_CBWR": "COMPATIBLE", "OMP_NUM_THREADS": "3", "WFC_COMPILE": "0"}
        assert set(record["machine"]) == {"cpu", "cores", "torch_threads", "kernels", "device", "gpu"}
        assert record["machine"]["kernels"] == ledger.kernels()
        assert record["machine"]["device"] == "cpu" and record["machine"]["torch_threads"] >= 1
    assert len({(r["date"], r["commit"]) for r in records}) == 1  # the run's context, read once
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", records[0]["date"])
    assert re.fullmatch(r"[0-9a-f]{40}", records[0]["commit"]) and isinstance(records[0]["dirty"], bool)


def test_two_runs_append_and_a_dry_run_appends_nothing(results, placed_pairs, tmp_path, capsys):
    argv = ["bench", "placement", "--synthetic", str(tmp_path / "set")]
    assert main(argv) == 0
    first = (results / "placement.jsonl").read_text()
    assert main(argv + ["--json"]) == 0
    both = (results / "placement.jsonl").read_text()
    assert both.startswith(first) and len(_records(results / "placement.jsonl")) == 6
    assert main(argv + ["--no-record"]) == 0
    assert (results / "placement.jsonl").read_text() == both
    assert sorted(p.name for p in results.iterdir()) == ["placement.jsonl"]


def test_the_fit_benchmark_records_its_data_folders_and_the_fits_device(results, tmp_path, monkeypatch, capsys):
    jobs = [{"kind": "real", "name": "pair", "reflection": None, "transmission": None, "truth": None}]
    monkeypatch.setattr(fit, "pair_jobs", lambda synthetic, real, names: jobs)
    monkeypatch.setattr(fit, "run_fit", lambda *args: {"error": "no result", "wall_s": 2.0})
    assert main(["bench", "fit", "--real", str(tmp_path / "a"), str(tmp_path / "b"), "--fit-args",
                 "--device cuda:1 --size 256"]) == 1  # a failed fit: exit 1, and still recorded
    row, summary = _records(results / "fit.jsonl")
    assert row["data"] == {"kind": "real", "name": "pair", "wall_s": 2.0, "error": "no result"}
    assert summary["data"]["failed"] == 1
    assert row["datasets"] == [str((tmp_path / name).resolve()) for name in "ab"]
    assert row["machine"]["device"] == "cuda:1"


def test_outside_a_git_checkout_the_commit_is_null(tmp_path, monkeypatch):
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path))  # git looks no higher than tmp_path
    (tmp_path / "checkout").mkdir()
    run = Ledger.open("render", ["bench", "render"], folder=tmp_path / "results", root=tmp_path / "checkout")
    run.summary({"forward_s": 0.1})
    [record] = _records(tmp_path / "results" / "render.jsonl")
    assert record["commit"] is None and record["dirty"] is None and record["data"] == {"forward_s": 0.1}


def test_the_ledger_s_own_folder_does_not_make_the_tree_dirty(tmp_path, monkeypatch):
    monkeypatch.setenv("GIT_CEILING_DIRECTORIES", str(tmp_path))
    checkout = tmp_path / "checkout"
    (checkout / ledger.IN_CHECKOUT).mkdir(parents=True)
    (checkout / "code.py").write_text("x = 1\n")

    def git(*args):
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=checkout, check=True,
                       capture_output=True)

    git("init", "-q")
    git("add", "code.py")
    git("commit", "-q", "-m", "code")

    def context():
        return Ledger.open("fit", [], folder=checkout / ledger.IN_CHECKOUT, root=checkout).context

    clean = context()
    assert re.fullmatch(r"[0-9a-f]{40}", clean["commit"]) and clean["dirty"] is False
    Ledger(checkout / ledger.IN_CHECKOUT / "fit.jsonl", clean).summary({})
    assert context()["dirty"] is False
    (checkout / "code.py").write_text("x = 2\n")
    assert context()["dirty"] is True


def test_evaluate_init_records_each_case_as_a_row_and_its_report_without_them_as_the_summary(
        results, tmp_path, monkeypatch, capsys):
    from types import SimpleNamespace

    from backend.core.priors import typical
    from devtools.bench import init_eval
    from devtools.cli import evaluate_init

    truth = typical("twill0").replace(tiles=(40.0, 60.0))
    golden = {"cases": [{"case": "one", "pattern": "twill0", "predicted_pattern": "twill0", "probability": 0.9}],
              "pattern_accuracy": 1.0, "family_accuracy": 1.0, "network_mae": {}, "prior_mae": {}}
    monkeypatch.setattr(evaluate_init, "evaluate_golden", lambda model, folder, ledger: golden)
    monkeypatch.setattr(init_eval, "golden_cases", lambda folder: [("one", "R", "T", truth)])
    monkeypatch.setattr(init_eval, "_load", lambda r, t: (r, t))
    monkeypatch.setattr(init_eval, "_timed_fit", lambda r, t, settings, use_network, model: {
        "result": SimpleNamespace(params=truth, loss=0.5 - 0.1 * use_network, timings={}),
        "trace": [(2.0, 10, 0.45)], "seconds": 3.0})
    assert main(["evaluate-init", "--golden", str(tmp_path), "--iterations", "5"]) == 0
    row, summary = _records(results / "evaluate-init.jsonl")
    assert row["data"]["section"] == "fits" and row["data"]["case"] == "one"
    assert row["data"]["network_reaches_prior_loss"] == {"iteration": 10, "seconds": 2.0}
    assert summary["data"]["golden"] == {k: v for k, v in golden.items() if k != "cases"}
    assert summary["data"]["fits"]["iterations"] == 5 and "cases" not in summary["data"]["fits"]
    assert summary["data"]["fits"]["summary"]["network"]["pattern_accuracy"] == 1.0
    assert summary["datasets"] == [str(tmp_path.resolve())]


def test_the_machine_s_kernels_are_the_vector_code_the_libraries_run():
    """In a process told to keep to AVX2 (torch's ATEN_CPU_CAPABILITY, NumPy's dispatch without its
    AVX-512 targets), the ledger's ``kernels`` say AVX2 for both, on any machine that has AVX2; a
    machine without it runs neither, and says so."""
    import os
    import sys

    import torch

    native = ledger.kernels()
    if native["torch"] not in ("AVX2", "AVX512"):
        pytest.skip(f"this CPU runs torch's {native['torch']} kernels: no AVX2 to keep to")
    no_avx512 = " ".join(f"AVX512{suffix}" for suffix in ("F", "CD", "_SKX", "_CLX", "_CNL", "_ICL", "_SPR"))
    env = dict(os.environ, ATEN_CPU_CAPABILITY="avx2", NPY_DISABLE_CPU_FEATURES=no_avx512)
    done = subprocess.run([sys.executable, "-c", "import json; from devtools.bench.ledger import kernels; "
                           "print(json.dumps(kernels()))"], env=env, capture_output=True, text=True, check=True,
                          cwd=ledger.ROOT)
    assert json.loads(done.stdout.splitlines()[-1]) == {"torch": "AVX2", "numpy": "AVX2"}
    assert native["torch"] == torch.backends.cpu.get_cpu_capability()
