"""The fuzz harness's fast subset (issue 91): a few hundred generated cases of bad input, run against
the contract by devtools/fuzz (the full run: ``python -m devtools fuzz``), and a handful of end-to-end
runs of the real ``python -m backend fit``.

The contract: every case ends in a result or in exit code 2 with one line that names the file or
option and the problem; never a traceback, a hang (each case is bounded), a crash, or a result
computed from NaN. The cases are seeded: the same every run.
"""
import json
import os
import subprocess
import sys
from collections import Counter

import numpy as np
import pytest
from conftest import ROOT

from devtools.fuzz import cases
from devtools.fuzz.cases import EITHER, FIT, REFUSE, Case
from devtools.fuzz.images import ENCODINGS, FILM, base_pair
from devtools.fuzz.photos import MUTATIONS
from devtools.fuzz.runner import FITTED, REFUSED, CommandRun, judge, run_case, run_cases, stand_ins

SEED = 91  # the issue's number: any fixed seed gives a fixed set of cases
COUNTS = {"photo": 156, "options": 60, "params": 40, "rig": 40}
HANG_S = 300  # a liveness bound for one end-to-end run, not a timing


@pytest.mark.parametrize("kind", [pytest.param("photo", marks=pytest.mark.slow), "options", "params", "rig"])
def test_every_case_ends_in_a_result_or_one_line_naming_the_file_or_option(kind):
    mine = run_cases(cases({kind: COUNTS[kind]}, SEED))  # a worker process per kind: xdist spreads them
    assert len(mine) == COUNTS[kind]
    broken = [f"{o.result}: {o.label}: {o.detail}" for o in mine if not o.ok]
    assert not broken, "\n".join(broken)
    results = Counter(o.result for o in mine)
    assert results[FITTED] and results[REFUSED], results  # both ends are reached: the cases are not all alike


def test_the_photo_cases_cover_every_mutation_and_format():
    labels = [case.label for case in cases({"photo": COUNTS["photo"]}, SEED)]
    for mutation in MUTATIONS:
        assert any(f" {mutation}:" in label for label in labels), mutation
    for encoding in ENCODINGS:
        assert any(label.startswith(f"{encoding} ") for label in labels), encoding


# -- the harness catches what breaks the contract -------------------------------------------------------

@pytest.fixture
def in_process(monkeypatch, tmp_path):
    """run_case here (not in a worker), with the stand-ins in place."""
    for module, name, stand_in in stand_ins():
        monkeypatch.setattr(module, name, stand_in)
    return lambda case: run_case(case, tmp_path)


def nan_exr_case() -> Case:
    reflection, transmission = base_pair()
    broken = reflection.copy()
    broken[:10, :10, 1] = np.nan
    encode = ENCODINGS["exr"][1]
    return Case("photo", "NaN in an EXR", (("a_R.exr", encode(broken)), ("a_T.exr", encode(transmission)),
                                           ("rig.json", json.dumps({"film_size": FILM}).encode())),
                ("fit", "{dir}/a_R.exr", "{dir}/a_T.exr", "--out", "{dir}/out", "--rig", "{dir}/rig.json"),
                ("a_R.exr",), REFUSE, loader=("a_R.exr", "a_T.exr"))


def test_the_harness_catches_nan_getting_through_and_a_traceback(in_process, monkeypatch):
    from backend.image import decode, photos

    assert in_process(nan_exr_case()).result == REFUSED
    monkeypatch.setattr(decode, "check_finite", lambda pixels, path: None)  # the refusal taken away
    assert in_process(nan_exr_case()).result == "bad input accepted"  # NaN repaired silently to 0
    monkeypatch.setattr(photos, "to_linear", lambda region, linear: region.astype(np.float32))  # and the repair too
    outcome = in_process(nan_exr_case())  # NaN in the working images: the pair checks fail on them (IndexError)
    assert not outcome.ok and outcome.result in ("traceback", "bad inputs reached the work",
                                                 "loader raised IndexError", "loader: bad working images"), outcome
    monkeypatch.setattr(photos, "read_image", lambda path: 1 / 0)  # an exception the command does not expect
    outcome = in_process(nan_exr_case())
    assert (outcome.result, outcome.detail) == ("traceback", "error: ZeroDivisionError: division by zero")


@pytest.mark.parametrize("stderr, code, result", [
    ("error: {dir}/a_R.png: the file is empty\n", 2, REFUSED),
    ("error: {dir}/other.png: the file is empty\n", 2, "refusal names none of a_R.png"),
    ("error: a_R.png: one\nerror: a_R.png: two\n", 2, "not one error line"),
    ("error: a_R.png: " + "x" * 2000 + "\n", 2, "overlong error line"),
    ("Traceback (most recent call last):\nerror: a_R.png: internal\n", 1, "traceback"),
    ("error: a_R.png: could not be decoded (Failed to allocate 10800000000 bytes)\n", 2, "ran out of memory"),
    ("", 0, "exit 0"),
])
def test_the_judge_tells_a_refusal_from_what_breaks_the_contract(stderr, code, result):
    case = Case("photo", "a case", (), (), ("a_R.png",), EITHER)
    assert judge(case, CommandRun(code=code, stderr=stderr))[0] == result
    good = Case("photo", "a good pair", (), (), ("a_R.png",), FIT)
    assert judge(good, CommandRun(code=2, stderr="error: a_R.png: x"))[0] == "good input refused"
    bad = Case("photo", "a bad pair", (), (), ("a_R.png",), REFUSE)
    assert judge(bad, CommandRun(code="reached"))[0] == "bad input accepted"
    assert judge(bad, CommandRun(code="reached", problems=("reflection: 3 non-finite values",)))[0] == \
        "bad inputs reached the work"


# -- end to end: the real command, in its own process ------------------------------------------------------

def backend(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "backend", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=HANG_S, env={**os.environ, "PYTHONPATH": str(ROOT), "WFC_COMPILE": "0",
                                               "OMP_NUM_THREADS": "1"})  # a tiny fit: threads only spin


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    folder = tmp_path_factory.mktemp("photos")
    (folder / "rig.json").write_text(json.dumps({"film_size": FILM}))
    for name, image in zip(("cloth_R", "cloth_T"), base_pair()):
        (folder / f"{name}.png").write_bytes(ENCODINGS["png8"][1](image))
        (folder / f"{name}.exr").write_bytes(ENCODINGS["exr"][1](image))
    broken = base_pair()[0].copy()
    broken.reshape(-1, 3)[np.random.default_rng(2).choice(broken.shape[0] * broken.shape[1], 300, replace=False)] = \
        np.nan
    (folder / "nan_R.exr").write_bytes(ENCODINGS["exr"][1](broken))
    return folder


@pytest.mark.parametrize("case", ["same photo twice", "300 NaN in an EXR", "--out that cannot be made",
                                  "--iterations -3"])
def test_the_issues_examples_end_to_end(photos, tmp_path, case):
    reflection, transmission = photos / "cloth_R.png", photos / "cloth_T.png"
    out, extra, needle = tmp_path / "out", [], None
    if case == "same photo twice":
        transmission, needle = reflection, "the two photos are the same image"
    elif case == "300 NaN in an EXR":
        reflection, transmission = photos / "nan_R.exr", photos / "cloth_T.exr"
        needle = f"{reflection}: 300 of its {96 * 96} pixels hold NaN or infinite values"
    elif case == "--out that cannot be made":
        (tmp_path / "notes.txt").write_text("a file in the way")
        out, needle = tmp_path / "notes.txt" / "out", "cannot create the folder (Not a directory)"
    else:
        extra, needle = ["--iterations", "-3"], "argument --iterations: must be at least 1, got -3"
    result = backend("fit", str(reflection), str(transmission), "--out", str(out), "--rig", str(photos / "rig.json"),
                     "--json-progress", *extra)
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr[-2000:]
    [line] = [line for line in result.stderr.splitlines() if "error:" in line]
    assert needle in line
    if case != "--iterations -3":  # the fit's own refusals: one line on stderr, one error event on stdout
        assert result.stderr.splitlines() == [line]
        assert json.loads(result.stdout.splitlines()[-1])["event"] == "error"


@pytest.mark.slow
def test_a_good_pair_is_fitted_end_to_end_at_a_tiny_size(photos, tmp_path):
    out = tmp_path / "out"
    result = backend("fit", str(photos / "cloth_R.png"), str(photos / "cloth_T.png"), "--out", str(out), "--rig",
                     str(photos / "rig.json"), "--size", "32", "--iterations", "1", "--output-spp", "1", "--init",
                     "prior", "--pattern", "plain", "--spacing-warp", "none", "--light-falloff", "none",
                     "--sample-rotation", "0", "--camera-blur", "0", "--json-progress")
    assert result.returncode == 0, result.stderr[-2000:]
    assert json.loads(result.stdout.splitlines()[-1])["event"] == "result"
    assert json.loads((out / "params.json").read_text())["pattern"] == "plain"
