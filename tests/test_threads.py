"""The backend's OpenMP waiting policy (backend.core.threads), set before torch loads, and its ordered
map over threads."""
import os
import subprocess
import sys
import threading
import time

import pytest
from conftest import ROOT

from backend.core.threads import BLOCK_TIME_MS, SPIN_COUNT, ordered_map, wait_briefly


def test_the_backend_spins_briefly_unless_the_user_chose_a_policy():
    environ = {}
    wait_briefly(environ)
    assert environ == {"GOMP_SPINCOUNT": SPIN_COUNT, "KMP_BLOCKTIME": BLOCK_TIME_MS}
    own = {"GOMP_SPINCOUNT": "INFINITE"}
    wait_briefly(own)
    assert own == {"GOMP_SPINCOUNT": "INFINITE", "KMP_BLOCKTIME": BLOCK_TIME_MS}
    policy = {"OMP_WAIT_POLICY": "ACTIVE"}
    wait_briefly(policy)
    assert policy == {"OMP_WAIT_POLICY": "ACTIVE"}  # the policy sets both runtimes' waits itself


# Records the waiting policy when torch is first imported, then runs ``python -m backend fit --help``.
_PROBE = """
import os, runpy, sys
seen = []
class Probe:
    def find_spec(self, name, path=None, target=None):
        if name == "torch" and not seen:
            seen.append((os.environ.get("GOMP_SPINCOUNT"), os.environ.get("KMP_BLOCKTIME")))
        return None
sys.meta_path.insert(0, Probe())
sys.argv = ["backend", "fit", "--help"]
try:
    runpy.run_module("backend", run_name="__main__", alter_sys=True)
except SystemExit:
    pass
print(seen, file=sys.stderr)
"""


def test_python_m_backend_sets_the_waiting_policy_before_torch_loads():
    env = {k: v for k, v in os.environ.items() if k not in ("GOMP_SPINCOUNT", "KMP_BLOCKTIME", "OMP_WAIT_POLICY")}
    env["PYTHONPATH"] = str(ROOT)
    done = subprocess.run([sys.executable, "-c", _PROBE], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=120)
    assert "usage:" in done.stdout
    assert done.stderr.strip().splitlines()[-1] == repr([(SPIN_COUNT, BLOCK_TIME_MS)])


def test_ordered_map_keeps_the_order_and_runs_on_the_threads_asked():
    seen = set()
    both_started = threading.Barrier(2, timeout=10)  # two calls at once, or the barrier breaks

    def slow_first(k):
        seen.add(threading.get_ident())
        if k < 2:
            both_started.wait()
        time.sleep(0.02 * (5 - k))  # the later items finish first
        return k * k

    assert ordered_map(slow_first, range(5), workers=2) == [0, 1, 4, 9, 16]
    assert len(seen) == 2 and threading.get_ident() not in seen
    seen.clear()
    assert ordered_map(lambda k: seen.add(threading.get_ident()) or -k, [3, 1], workers=1) == [-3, -1]
    assert seen == {threading.get_ident()}  # one worker: this thread, no pool


def test_ordered_map_raises_what_a_call_raised():
    def fails_on_two(k):
        if k == 2:
            raise ValueError(f"bad item {k}")
        return k

    with pytest.raises(ValueError, match="bad item 2"):
        ordered_map(fails_on_two, range(4), workers=2)
