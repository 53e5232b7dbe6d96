"""Nothing lost (issue 91): every file the fit writes is written whole or not at all, through a
temporary file renamed over it (backend/core/jsonfile.py: ``replacing``), tested by killing the writer
midway: with SIGKILL, which nothing can catch or clean up after."""
import json
import os
import signal
import subprocess
import sys
import textwrap

import cv2
import numpy as np
import pytest
from conftest import ROOT

from backend.app import folder as job
from backend.app.cli.main import main
from backend.core.jsonfile import replacing, write_whole
from backend.core.params import FabricParams
from backend.core.results import RESULT_FILES
from backend.fit.settings import FitResult
from blender_addon.core import asset_catalogs
from devtools.fuzz.images import ENCODINGS, FILM, base_pair

HANG_S = 120  # a liveness bound, not a timing
OLD = "the earlier version, whole\n"

# argv[1]: the path; the child writes half of the new text, says so, and waits to be killed
HALF_WRITTEN = textwrap.dedent("""
    import sys, time
    from backend.core.jsonfile import replacing
    with replacing(sys.argv[1]) as temporary, open(temporary, "w") as fh:
        fh.write("the new version, half of it")
        fh.flush()
        print("half", flush=True)
        time.sleep(600)
        fh.write(" and the rest")
""")

# argv[1]: the result file at whose rename the process kills itself; argv[2]: the fitted parameters
# (interchange); the rest: the fit command. The fit itself is a stand-in returning those parameters.
KILLED_AT_RENAME = textwrap.dedent("""
    import os, signal, sys
    import backend.app.folder as job
    from backend.app.cli.main import main
    from backend.core.params import FabricParams
    from backend.fit.settings import FitResult

    kill_at, params = sys.argv[1], FabricParams.from_interchange(sys.argv[2])
    job.fit = lambda *args, **kwargs: FitResult(params, 0.5, {"loss": 0.5}, [], [], {"total_s": 0.1}, 0.0)
    rename = os.replace

    def replace(source, target):
        if os.path.basename(target) == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)
        rename(source, target)

    os.replace = replace
    sys.exit(main(sys.argv[3:]))
""")


def child(script: str, *args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", script, *args], cwd=ROOT, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT), "WFC_COMPILE": "0"}, **kwargs)


def test_a_writer_killed_midway_leaves_the_earlier_file_whole(tmp_path):
    path = tmp_path / "params.json"
    path.write_text(OLD)
    process = child(HALF_WRITTEN, str(path), stdout=subprocess.PIPE)
    assert process.stdout.readline() == "half\n"
    process.send_signal(signal.SIGKILL)
    process.wait(HANG_S)
    assert path.read_text() == OLD
    assert [p.name for p in tmp_path.iterdir() if p != path] == [".params.writing.json"]  # hidden, never read
    write_whole(path, "the next version\n")  # the next write goes through the same temporary
    assert sorted(p.name for p in tmp_path.iterdir()) == ["params.json"]
    assert path.read_text() == "the next version\n"


def test_a_failed_write_leaves_the_earlier_file_and_no_temporary(tmp_path):
    path = tmp_path / "metrics.json"
    path.write_text(OLD)
    with pytest.raises(RuntimeError, match="disk full"), replacing(path) as temporary:
        temporary.write_text("half")
        raise RuntimeError("disk full")
    assert path.read_text() == OLD and sorted(p.name for p in tmp_path.iterdir()) == ["metrics.json"]


@pytest.fixture
def photos(tmp_path):
    reflection, transmission = base_pair()
    encode = ENCODINGS["png8"][1]
    (tmp_path / "cloth_R.png").write_bytes(encode(reflection))
    (tmp_path / "cloth_T.png").write_bytes(encode(transmission))
    (tmp_path / "rig.json").write_text(json.dumps({"film_size": FILM}))
    return tmp_path


def fit_command(photos, out) -> list[str]:
    return ["fit", str(photos / "cloth_R.png"), str(photos / "cloth_T.png"), "--out", str(out), "--rig",
            str(photos / "rig.json"), "--init", "prior", "--output-spp", "1", "--overwrite"]


def fit_in_process(photos, out, params, monkeypatch) -> None:
    """The fit command, here, with a stand-in fit that returns ``params``."""
    monkeypatch.setattr(job, "fit", lambda *a, **k: FitResult(params, 0.5, {"loss": 0.5}, [], [], {}, 0.0))
    assert main(fit_command(photos, out)) == 0


def test_every_result_file_of_a_fit_is_renamed_into_place(photos, monkeypatch):
    renamed, rename = [], os.replace
    monkeypatch.setattr(os, "replace", lambda source, target: renamed.append((source, target)) or rename(source,
                                                                                                       target))
    out = photos / "out"
    fit_in_process(photos, out, FabricParams.from_interchange(job.EXAMPLE_PARAMS), monkeypatch)
    assert sorted(os.path.basename(target) for _, target in renamed) == sorted(RESULT_FILES)
    for source, target in renamed:
        stem, suffix = os.path.splitext(os.path.basename(target))
        assert os.path.basename(source) == f".{stem}.writing{suffix}"
    assert sorted(p.name for p in out.iterdir()) == sorted(RESULT_FILES)


@pytest.mark.parametrize("killed_at", ["params.json", "report.png"])
def test_a_fit_killed_while_writing_over_an_earlier_result_leaves_each_file_whole(photos, monkeypatch, killed_at):
    """An earlier complete result, then a fit with --overwrite killed just before it renames one of
    its files into place: every result file is whole, the earlier run's or the new one's."""
    earlier = FabricParams.from_interchange(job.EXAMPLE_PARAMS)
    newer = earlier.replace(roughness=(0.3, 0.3))
    out = photos / "out"
    fit_in_process(photos, out, earlier, monkeypatch)
    before = {name: (out / name).read_bytes() for name in RESULT_FILES}
    process = child(KILLED_AT_RENAME, killed_at, newer.to_interchange(), *fit_command(photos, out),
                    stderr=subprocess.PIPE)
    err = process.communicate(timeout=HANG_S)[1]
    assert process.returncode == -signal.SIGKILL, err[-2000:]
    saved = FabricParams.from_dict(json.loads((out / "params.json").read_text()))
    assert saved == (earlier if killed_at == "params.json" else newer)
    json.loads((out / "metrics.json").read_text())
    for name in ("reflection.png", "transmission.png", "report.png"):
        image = cv2.imread(str(out / name), cv2.IMREAD_UNCHANGED)
        assert image is not None and np.all(np.array(image.shape[:2]) > 0), name
    assert (out / killed_at).read_bytes() == before[killed_at]  # the killed write left the earlier file
    assert {p.name for p in out.iterdir() if not p.name.startswith(".")} == set(RESULT_FILES)


def test_the_batch_catalogue_is_renamed_into_place(tmp_path, monkeypatch):
    from backend.app.batch import catalogue
    from backend.core.pair_jobs import FAILED, PairJob

    renamed, rename = [], os.replace
    monkeypatch.setattr(os, "replace", lambda source, target: renamed.append((source, target)) or rename(source,
                                                                                                       target))
    rows = [catalogue.row(PairJob("denim", None, None, FAILED, reason="torn")),
            catalogue.row(PairJob("linen", None, None))]
    json_path, csv_path = catalogue.write(tmp_path, rows, {"photos": "P"})
    assert [(os.path.basename(s), t) for s, t in renamed] == [(".catalogue.writing.json", json_path),
                                                              (".catalogue.writing.csv", csv_path)]
    assert [row["name"] for row in json.loads(json_path.read_text())["pairs"]] == ["denim", "linen"]
    assert csv_path.read_bytes().count(b"\r\n") == 3  # the header and two rows, as the csv module ends them


# argv[1]: the folder; argv[2]: which of the add-on's files to write there. The process kills itself
# at the rename that would put the new file in place.
ADDON_KILLED_AT_RENAME = textwrap.dedent("""
    import os, signal, sys
    from blender_addon.core import asset_catalogs, captures

    os.replace = lambda source, target: os.kill(os.getpid(), signal.SIGKILL)
    if sys.argv[2] == "rig":
        captures.write_rig_json(sys.argv[1], {"film_size": 512, "width_cm": 4.0})
    else:
        asset_catalogs.ensure_catalogs(sys.argv[1], ["Fabrics/Plain"])
""")


@pytest.mark.parametrize("writer, name", [("rig", "rig.json"), ("catalogs", asset_catalogs.CATALOG_FILE)])
def test_the_addon_killed_as_it_writes_leaves_its_earlier_file_whole(tmp_path, writer, name):
    path = tmp_path / name
    path.write_text(OLD)
    process = child(ADDON_KILLED_AT_RENAME, str(tmp_path), writer)
    assert process.wait(HANG_S) == -signal.SIGKILL
    assert path.read_text() == OLD
