"""A stand-in for ``python -m backend`` that speaks the fit command's JSON-lines protocol quickly.

Used by the add-on tests instead of a real fit (seconds instead of minutes, no torch needed):
``python tests/fake_backend.py fit REFLECTION TRANSMISSION --out DIR --json-progress ...`` writes
``params.json`` (valid FabricParams, colour taken from the photo name so pairs differ),
``reflection.png``, ``transmission.png``, ``report.png`` (copies of the inputs) and ``metrics.json``.

Behaviour is chosen with ``FAKE_BACKEND_MODE``:

=============  ===============================================================================
ok             progress lines, then a result (default)
error          an ``internal`` error event, exit 1
crash          a traceback on stderr, exit 1, no error event
garbage        a non-protocol line among the progress lines, then a normal result
garbage_only   non-protocol lines only, exit 0
slow           progress every 0.1 s for a minute (for cancel tests); a stop request -> cancelled, 130,
               with the best parameters so far in ``params.partial.json`` once a step has run
swapped        the photos look swapped: with ``--strict`` an ``input`` error, exit 2; else a warning
               and a normal result
stubborn       like slow but ignores stop requests (the caller must kill it)
no_result      progress and output files but no result line, exit 0
=============  ===============================================================================

A stop request is SIGTERM/SIGINT or, with ``--stop-on-stdin``, a ``stop`` line on stdin or its end
(as the real fit command does). In every mode a photo that is missing, or a ``.png``/``.jpg`` whose
bytes are not an image, is bad input: an ``input`` error event naming the file, exit 2 (as the real
backend does).
``FAKE_BACKEND_DELAY`` sets the sleep between progress lines (default 0.01 s).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import sys
import threading
import time
from pathlib import Path

EXIT_OK, EXIT_INTERNAL, EXIT_INPUT, EXIT_CANCELLED = 0, 1, 2, 130
SWAPPED = "the photos may be swapped"  # the protocol's SWAPPED_PHOTOS (a test keeps the two the same)
MAGIC = {".png": b"\x89PNG", ".jpg": b"\xff\xd8", ".jpeg": b"\xff\xd8"}


def emit(event: str, **fields):
    sys.stdout.write(json.dumps({"event": event, **fields}) + "\n")
    sys.stdout.flush()


STOP = threading.Event()


def on_terminate(signum, frame):
    emit("error", kind="cancelled", message="cancelled by signal", file=None)
    sys.exit(EXIT_CANCELLED)


def watch_stdin():
    for line in sys.stdin:
        if line.strip() == "stop":
            break
    STOP.set()


def bad_photo(path: Path) -> str:
    if not path.is_file():
        return "the file does not exist"
    magic = MAGIC.get(path.suffix.lower())
    if magic and not path.read_bytes().startswith(magic):
        return "not a readable image (corrupt or wrong extension)"
    return ""


def fake_params(name: str) -> dict:
    """A valid parameter set whose colour depends on the name (so materials of a batch differ)."""
    digest = hashlib.sha256(name.encode()).digest()
    colour = [round(0.1 + 0.8 * b / 255, 3) for b in digest[:3]]
    return {
        "pattern": "twill1", "tiles": [121.8, 168.9], "roughness": [0.6, 0.66], "thickness": [1.33, 1.39],
        "roughness_multiple": [0.65, 0.62], "thickness_multiple": [2.66, 0.79], "height_scale": [0.75, 1.53],
        "gap_scale": [0.99, 1.0], "twist_deg": [-30.5, -29.5],
        "specular_albedo": [[0.325, 0.37, 0.0], [0.351, 0.883, 0.0]], "multiple_weight": 1.29,
        "diffuse_reflection": colour, "diffuse_transmission": [c * 0.6 for c in colour],
        "diffuse_normal_weight": 0.71, "noise": 0.0, "version": "fake",
    }


def fit(args) -> int:
    mode = os.environ.get("FAKE_BACKEND_MODE", "ok")
    delay = float(os.environ.get("FAKE_BACKEND_DELAY", "0.01"))
    if mode != "stubborn":
        signal.signal(signal.SIGTERM, on_terminate)
        signal.signal(signal.SIGINT, on_terminate)
    else:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if args.stop_on_stdin and mode != "stubborn":
        threading.Thread(target=watch_stdin, daemon=True).start()
    print(f"fake backend: mode {mode}, pid {os.getpid()}", file=sys.stderr, flush=True)
    emit("start", command="fit", version="0.1.0-fake", device=args.device or "cpu")

    for which, path in (("reflection", args.reflection), ("transmission", args.transmission)):
        problem = bad_photo(Path(path))
        if problem:
            emit("error", kind="input", message=f"{which} photo {path}: {problem}", file=str(path))
            print(f"error: {which} photo {path}: {problem}", file=sys.stderr)
            return EXIT_INPUT

    if mode == "swapped":
        message = f"{args.reflection} / {args.transmission}: {SWAPPED} (reflection = front light, ...)"
        if args.strict:
            emit("error", kind="input", message=message, file=None)
            return EXIT_INPUT
        emit("warning", message=message, file=None)
        print(f"warning: {message}", file=sys.stderr, flush=True)
    if mode in ("slow", "stubborn"):
        for i in range(600):
            emit("progress", stage="optimise", iteration=i, total=600, loss=1.0 / (i + 1), eta_s=60 - i * 0.1,
                 elapsed_s=i * 0.1, since_best=0, patience=20)
            if STOP.wait(0.1):
                if i >= 1:
                    Path(args.out).mkdir(parents=True, exist_ok=True)
                    params = dict(fake_params(Path(args.reflection).stem.rsplit("_", 1)[0]), partial=True)
                    (Path(args.out) / "params.partial.json").write_text(json.dumps(params) + "\n")
                emit("error", kind="cancelled", message="cancelled by a stop request", file=None)
                return EXIT_CANCELLED
        return EXIT_INTERNAL
    if mode == "garbage_only":
        print("this is not JSON")
        print('{"no_event": 1}')
        return EXIT_OK

    # the real fit's sequence: each stage from 0 of 1, the search's counter starting again for its
    # starting points and its trials
    iterations = args.iterations or 10
    steps = [("load", (0, 1), 1), ("search", (0,), 1), ("search", range(1, 4), 3), ("search", range(1, 3), 2),
             ("optimise", range(1, iterations + 1), iterations), ("render", (0, 1), 1), ("report", (0, 1), 1)]
    for stage, counts, total in steps:
        for i in counts:
            optimiser = stage == "optimise"   # its loss falls at every step: a new best each time
            emit("progress", stage=stage, iteration=i, total=total, loss=0.1 / i if optimiser else None,
                 eta_s=None, elapsed_s=0.0, since_best=0 if optimiser else None, patience=20 if optimiser else None)
            if mode == "garbage" and stage == "search" and (i, total) == (1, 3):
                print("Warning: some library printed this on stdout")
            time.sleep(delay)
        if mode == "error" and stage == "search" and total == 2:
            emit("error", kind="internal", message="the optimiser diverged (loss is NaN)", file=None)
            print("error: the optimiser diverged", file=sys.stderr)
            return EXIT_INTERNAL
        if mode == "crash" and stage == "load":
            raise RuntimeError("simulated crash in the initialisation network")

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    name = Path(args.reflection).stem.rsplit("_", 1)[0]
    params = fake_params(name)
    if args.rig:
        params["rig"] = json.loads(Path(args.rig).read_text())
    (out / "params.json").write_text(json.dumps(params, indent=2) + "\n")
    files = {"reflection": out / "reflection.png", "transmission": out / "transmission.png",
             "report": out / "report.png", "metrics": out / "metrics.json"}
    shutil.copyfile(args.reflection, files["reflection"])
    shutil.copyfile(args.transmission, files["transmission"])
    shutil.copyfile(args.reflection, files["report"])
    metrics = {"loss": 0.01, "iterations": args.iterations or 10}
    files["metrics"].write_text(json.dumps(metrics) + "\n")
    if mode == "no_result":
        return EXIT_OK
    emit("result", out_dir=str(out), params=str(out / "params.json"), files={k: str(v) for k, v in files.items()},
         metrics=metrics, wall_s=0.1)
    return EXIT_OK


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="fake_backend")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("fit")
    p.add_argument("reflection")
    p.add_argument("transmission")
    p.add_argument("--out", required=True)
    p.add_argument("--pattern", default="auto")
    p.add_argument("--iterations", type=int)
    p.add_argument("--size", type=int)
    p.add_argument("--device")
    p.add_argument("--rig")
    p.add_argument("--output-spp", type=int)
    p.add_argument("--json-progress", action="store_true")
    p.add_argument("--stop-on-stdin", action="store_true")
    p.add_argument("--strict", action="store_true")
    args = parser.parse_args(argv)
    return fit(args)


if __name__ == "__main__":
    sys.exit(main())
