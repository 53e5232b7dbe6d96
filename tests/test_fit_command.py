"""The fit command around the fit: stop requests on stdin (the add-on's way on every platform) and
params.json written before anything optional, so that a late failure loses nothing.

The command runs as a subprocess, as the add-on runs it, with the optimisation replaced by a
stand-in (``STAND_IN``): the photos, the outputs, the protocol and the stop handling are the real
command's; only the minutes of fitting are skipped. (test_fit.py stops the real pipeline with
SIGTERM, the terminal's way; both set the same stop flag the pipeline polls.)
"""
import json
import os
import subprocess
import sys
import textwrap

import cv2
import numpy as np
import pytest
from conftest import ROOT

from backend.app.folder import EXAMPLE_PARAMS
from backend.core import priors
from backend.core.params import FabricParams
from backend.core.protocol import EXIT_CANCELLED, STOP_REQUEST, decode
from backend.core.rig import DEFAULT_RIG
from backend.image.png import write_png
from backend.model.render import render_pair

HANG_S = 120  # a liveness bound, not a timing

# argv[1]: JSON {"fail": "renders" | "metrics" | "report" | "", "steps": N[, "params": the fit's interchange
# string, default the example's]}; the rest: the fit command.
STAND_IN = textwrap.dedent("""
    import json, sys, time
    import backend.app.folder as command
    from backend.app.cli.main import main
    from backend.core.params import FabricParams
    from backend.fit.settings import FitCancelled, FitResult

    options = json.loads(sys.argv[1])
    params = FabricParams.from_interchange(options.get("params", command.EXAMPLE_PARAMS))

    def stand_in_fit(reflection, transmission, rig, settings, progress, should_stop, **unused):
        for step in range(options["steps"]):
            progress("optimise", step, options["steps"], 0.5, None)
            if should_stop():
                raise FitCancelled(params)
            time.sleep(0.02)
        return FitResult(params, 0.5, {"loss": 0.5}, [], [], {"total_s": 0.1}, 0.0)

    def failing(*args, **kwargs):
        raise RuntimeError("simulated failure (disk full)")

    command.fit = stand_in_fit
    if options["fail"]:
        setattr(command, {"renders": "_final_renders", "metrics": "compare", "report": "write_report"}[options["fail"]],
                failing)
    sys.exit(main(sys.argv[2:]))
""")


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    folder = tmp_path_factory.mktemp("photos")
    pair = render_pair(FabricParams.from_interchange(EXAMPLE_PARAMS), DEFAULT_RIG, size=256, spp=1, seed=3)
    return (write_png(folder / "cloth_R.png", pair.reflection.numpy(), bits=8),
            write_png(folder / "cloth_T.png", pair.transmission.numpy(), bits=8))


def start(photos, out, *flags, fail="", steps=3, stdin=subprocess.DEVNULL, params=EXAMPLE_PARAMS):
    arguments = ["fit", str(photos[0]), str(photos[1]), "--out", str(out), "--json-progress", "--init", "prior",
                 "--output-spp", "1", *flags]
    options = {"fail": fail, "steps": steps, "params": params}
    return subprocess.Popen([sys.executable, "-c", STAND_IN, json.dumps(options), *arguments],
                            cwd=ROOT, stdin=stdin, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT), "WFC_COMPILE": "0"})


def finish(process) -> tuple[list[dict], str]:
    """The events and stderr of the run (its stdin may be closed already, so no communicate())."""
    out, err = process.stdout.read(), process.stderr.read()  # stderr holds a few lines: no pipe fills up
    process.wait(HANG_S)
    return [decode(line) for line in out.splitlines()], err


def events_until_optimising(process) -> list[dict]:
    events = []
    for line in process.stdout:
        events.append(decode(line))
        if events[-1].get("stage") == "optimise":
            return events
    raise AssertionError(f"the fit ended before optimising: {events} {process.stderr.read()[-2000:]}")


@pytest.mark.parametrize("how", ["stop line", "closed stdin"])
def test_a_stop_request_on_stdin_keeps_the_best_parameters(photos, tmp_path, how):
    out = tmp_path / "fit"
    process = start(photos, out, "--stop-on-stdin", steps=100000, stdin=subprocess.PIPE)
    events_until_optimising(process)
    if how == "stop line":
        process.stdin.write(STOP_REQUEST + "\n")
        process.stdin.flush()
    else:  # the caller went away (Blender quit or crashed)
        process.stdin.close()
    events, err = finish(process)
    assert process.returncode == EXIT_CANCELLED, err[-2000:]
    assert events[-1]["event"] == "error" and events[-1]["kind"] == "cancelled"
    assert "params.partial.json" in events[-1]["message"]
    partial = json.loads((out / "params.partial.json").read_text())
    assert FabricParams.from_dict(partial) == FabricParams.from_interchange(EXAMPLE_PARAMS)
    assert not (out / "params.json").exists()


@pytest.mark.parametrize("fail,kept", [
    ("report", {"params", "reflection", "transmission", "metrics"}),
    ("metrics", {"params", "reflection", "transmission"}),   # the report needs the metrics
    ("renders", {"params"}),                                 # the metrics and report need the renders
])
def test_params_json_comes_first_and_a_late_failure_is_a_warning(photos, tmp_path, fail, kept):
    out = tmp_path / "fit"
    # (Its stdin is at its end from the start: without --stop-on-stdin that stops nothing.)
    process = start(photos, out, fail=fail)
    events, err = finish(process)
    assert process.returncode == 0, err[-2000:]
    result = events[-1]
    assert result["event"] == "result" and set(result["files"]) == kept
    assert FabricParams.from_dict(json.loads((out / "params.json").read_text())) == \
        FabricParams.from_interchange(EXAMPLE_PARAMS)
    names = {"reflection": "reflection.png", "transmission": "transmission.png", "metrics": "metrics.json",
             "report": "report.png", "params": "params.json"}
    assert {key for key, name in names.items() if (out / name).is_file()} == kept
    warnings = [e["message"] for e in events if e["event"] == "warning" and "could not be written" in e["message"]]
    assert len(warnings) == 1 and "RuntimeError: simulated failure (disk full)" in warnings[0], warnings
    assert f"the fitted parameters are in {out / 'params.json'}" in warnings[0]
    assert "Traceback" in err  # the details go to the log


def test_a_registered_pairs_re_renders_are_written_and_compared_in_each_photos_own_framing(tmp_path):
    # The transmission photo taken with the phone moved back 8 % and turned 1 degree: the pair is
    # registered (the transmission magnified onto the reflection's framing) and the stand-in fit
    # returns the parameters the photos were rendered from. transmission.png must then lie on the
    # transmission photo as taken, and metrics.json compare the two over what the fit saw.
    from backend.image.metrics import compare
    from backend.image.photos import load_pair
    from backend.image.registration import magnified

    t = np.radians(1.0)
    turn = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    params = priors.typical("twill1").replace(tiles=(30.0, 40.0))  # yarns of 4-6 px: a misplaced lattice shows
    pair = render_pair(params, DEFAULT_RIG, size=512, spp=4, seed=3)
    photos = (write_png(tmp_path / "moved_R.png", pair.reflection.numpy(), bits=8),
              write_png(tmp_path / "moved_T.png", np.clip(magnified(pair.transmission.numpy(), turn * 1.08), 0, 1),
                        bits=8))
    out = tmp_path / "fit"
    events, err = finish(start(photos, out, "--output-spp", "4", params=params.to_interchange()))
    assert events and events[-1]["event"] == "result", err[-2000:]
    loaded = load_pair(*photos)
    registration = json.loads((out / "params.json").read_text())["photos"]["registration"]
    assert registration == loaded.registration.to_dict() and registration["moved"] == "transmission"
    taken = loaded.taken[1]
    written = cv2.imread(str(out / "transmission.png"), cv2.IMREAD_UNCHANGED)[..., ::-1] / 65535.0
    k = loaded.registration.seen_margin(512)
    inside = (slice(k, 512 - k), slice(k, 512 - k))
    carried_off = np.abs(written[inside] - taken[inside]).mean()
    magnified_off = np.abs(loaded.transmission[inside] - taken[inside]).mean()  # the fit's framing
    written_r = cv2.imread(str(out / "reflection.png"), cv2.IMREAD_UNCHANGED)[..., ::-1] / 65535.0
    floor = np.abs(written_r[inside] - loaded.reflection[inside]).mean()  # the unmoved photo: noise, blur
    # (measured: 0.018 against 0.035 in the fit's framing and 0.009 on the unmoved photo; what is left is
    # the map's own error, about 0.3 %, a pixel at the edges, and two bilinear resamplings)
    assert magnified_off - carried_off > 0.5 * (magnified_off - floor)
    saved = json.loads((out / "metrics.json").read_text())
    metrics = saved["metrics"]
    assert saved["compared_region"] == {"reflection": [0, 0, 512, 512],
                                        "transmission": [k, k, 512 - 2 * k, 512 - 2 * k]}
    again = compare(taken[inside], written[inside].astype(np.float32))
    for name, value in metrics["transmission"].items():
        assert value == pytest.approx(again[name], abs=2e-3), name
    assert metrics["reflection"]["flip"] == pytest.approx(
        compare(loaded.reflection, written_r.astype(np.float32))["flip"], abs=2e-3)
