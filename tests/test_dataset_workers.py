"""The dataset's worker processes: a run whose workers wrote every item succeeds, however long
they take to exit after the last one; a worker that dies is reported."""
import sys

import pytest

from devtools import dataset


def _workers(script: str):
    """Workers that run ``script`` (``out`` and ``name`` given) for each shard's first item."""
    def start(out, jobs, settings, compile, workers):
        import subprocess
        return [subprocess.Popen([sys.executable, "-c", script, str(out), dataset.item_name(*job)])
                for job in jobs[:workers]]
    return start


WRITE_THEN_LINGER = ("import sys, time, pathlib; pathlib.Path(sys.argv[1], sys.argv[2] + '.npz').write_bytes(b'x');"
                     " time.sleep(2.5)")


def test_workers_that_wrote_every_item_are_waited_for_not_stopped(tmp_path, monkeypatch):
    monkeypatch.setattr(dataset, "_start_workers", _workers(WRITE_THEN_LINGER))
    seen = []
    dataset._run_shards(tmp_path, [("plain", 0), ("twill0", 0)], dataset.DatasetSettings(), False, 2, seen.append)
    assert sorted(seen) == ["plain_00000", "twill0_00000"]


def test_a_worker_that_fails_is_reported(tmp_path, monkeypatch):
    monkeypatch.setattr(dataset, "_start_workers", _workers("import sys; sys.exit(3)"))
    with pytest.raises(RuntimeError, match=r"1 item\(s\) not made; worker exit codes \[3\]"):
        dataset._run_shards(tmp_path, [("plain", 0)], dataset.DatasetSettings(), False, 1, lambda name: None)
