"""Synthetic training data for the initialisation network (:mod:`backend.init.network`).

    python -m devtools dataset --out DIR --per-pattern N [--workers K] [--seed S] [--size 256] [--spp 16]

For every weave preset and index ``i < N`` one *item*: parameters drawn from the paper's dataset
prior of that preset (:func:`backend.core.priors.sample`, spec section 5, item 4), the rig's reflection
and transmission renders at the fit's working size, and the network's features at the lattices the
fit would propose for that pair:

- the true pattern at the true tiles times a small random error (relative, normal, s.d. 0.3 %,
  clipped at 1 %: the lattice estimator's typical error), and once more at the exact tiles;
- every other preset at the lattice the estimator would give it: the true lattice times the ratio
  pair (1/3 .. 3 per axis, :data:`backend.texture.GATES.ratios`) that lies in that preset's density range
  and best matches its harmonic signature (what :func:`backend.texture.candidates.comb_lattices` does), with the
  same small error. Those rows teach the network which candidate is the photos' weave.

Photo-like items (``--photo-scale K``): the sample is drawn, framed, turned and photographed by a
phone instead (:func:`devtools.photo_like.photograph` at K phone pixels per film pixel), and the
8-bit photos are reduced to the working size as the fit reduces a photo; the candidates are read at
the true (axis-aligned) lattice as above, so the network learns the features of turned, blurred,
noisy, unevenly lit photos. The renders then have no ``--spp``: one sample per phone pixel.

Resolution and samples: 256 x 256 (the working size of the fit, where the features are read) with
16 samples per pixel on a fixed stratified jitter (the fit's own renders use the same). Against
renders of many more samples, what remains of the features' error at 16 spp is the sampling noise
the fit sees too: an independent 16-spp render is as far from the reference.

Files: ``DIR/dataset.json`` (the settings; a resumed run must use the same ones) and one
``DIR/<pattern>_<index>.npz`` per item (arrays: 16-bit ``reflection`` and ``transmission``,
``features`` (6, FEATURE_DIM) with rows in :data:`backend.core.priors.PATTERNS` order then the exact-tiles
row, ``tiles`` (6, 2), ``pattern`` (index of the true preset), ``target`` (the [0, 1] parameter
vector), ``params`` (interchange string), ``feature_version``). Each file is written to a temporary
name and renamed, so an interrupted run leaves only whole items, and a rerun skips them. Everything
is a function of (seed, pattern, index) and the settings: the same bytes whatever the worker count.
"""
from __future__ import annotations

import io
import json
import math
import os
import random
import subprocess
import sys
import time
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from backend.core import priors
from backend.core.params import FabricParams
from backend.core.rig import DEFAULT_RIG, CaptureRig
from backend.image.spectrum import peakness
from backend.init import network as init_net
from backend.model import rng
from backend.model.render import Renderer
from backend.texture import candidates, lattice
from backend.texture.gates import GATES
from backend.texture.signatures import signatures as pattern_signatures

from .photo_like import photograph

LATTICE_ERROR = 0.003    # relative s.d. of the lattice estimator's tiles (checked on the golden pairs)
LATTICE_ERROR_MAX = 0.01
ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed timestamps: the same item gives the same bytes
WORKER_EXIT_S = 60.0  # how long workers whose items are written may take to exit before they are stopped


@dataclass(frozen=True)
class DatasetSettings:
    size: int = init_net.WORK_SIZE
    spp: int = 16
    seed: int = 0
    photo_scale: int = 0    # 0: clean renders; k: photo-like shots at k phone pixels per film pixel


def item_name(pattern: str, index: int) -> str:
    return f"{pattern}_{index:05d}"


def item_seed(seed: int, pattern: str, index: int) -> int:
    """A 32-bit seed from (dataset seed, pattern, index), the same in every process."""
    h = rng.hash32_int(seed)
    h = rng.hash32_int(h ^ (priors.PATTERNS.index(pattern) + 1))
    return rng.hash32_int(h ^ (index + 0x9E3779B9))


# -- candidate lattices ----------------------------------------------------------------------------
def _jittered(tiles, rnd: random.Random) -> tuple[float, float]:
    def factor():
        return 1.0 + max(-LATTICE_ERROR_MAX, min(LATTICE_ERROR_MAX, rnd.gauss(0.0, LATTICE_ERROR)))

    return tiles[0] * factor(), tiles[1] * factor()


def confusable_tiles(maps: list[np.ndarray], signature, true_tiles, pattern: str, rig: CaptureRig,
                     size: int) -> tuple[float, float]:
    """The tiles the lattice estimator would propose for ``pattern`` when the true lattice is
    ``true_tiles``: the admissible ratio pair scoring best against the pattern's signature."""
    scale = rig.view_size / rig.plane_size
    (ulo, uhi), (vlo, vhi) = candidates.tile_range(pattern, rig)
    best = None
    for ra in GATES.ratios:
        for rb in GATES.ratios:
            tu, tv = true_tiles[0] * ra, true_tiles[1] * rb
            if not (ulo <= tu <= uhi and vlo <= tv <= vhi):
                continue
            a, b = np.array([[tu * scale]]), np.array([[tv * scale]])
            # lattice.signature_score is the estimator's own signature score (what candidates.comb_lattices ranks by).
            score = float(lattice.signature_score(maps, signature, a, b, size)[0, 0])
            if best is None or score > best[0]:
                best = (score, (tu, tv))
    return best[1] if best else priors.typical(pattern).tiles


def candidate_rows(pair: init_net.WorkingPair, params: FabricParams, rig: CaptureRig, signatures,
                   rnd: random.Random) -> tuple[np.ndarray, np.ndarray]:
    """Features (6, FEATURE_DIM) and tiles (6, 2): one candidate per preset, then the exact truth."""
    images = [pair.reflection.numpy().astype(np.float64), pair.transmission.numpy().astype(np.float64)]
    maps = [peakness(img, blur=0.0) for img in images]
    tiles = []
    for pattern in priors.PATTERNS:
        if pattern == params.pattern:
            tiles.append(_jittered(params.tiles, rnd))
        else:
            tiles.append(_jittered(confusable_tiles(maps, signatures[pattern], params.tiles, pattern, rig,
                                                    pair.reflection.shape[0]), rnd))
    tiles.append(tuple(params.tiles))
    tiles = np.asarray(tiles, dtype=np.float64)
    return row_features(pair, params.pattern, tiles, rig), tiles


def row_features(pair: init_net.WorkingPair, pattern: str, tiles: np.ndarray, rig: CaptureRig) -> np.ndarray:
    """Features of an item's six rows: the presets in order, then ``pattern`` again (exact tiles)."""
    patterns = list(priors.PATTERNS) + [pattern]
    features = torch.stack([init_net.candidate_features(pair, p, tuple(t), rig) for p, t in zip(patterns, tiles)])
    return features.numpy().astype(np.float32)


def redescribed(item: dict[str, np.ndarray], rig: CaptureRig = DEFAULT_RIG) -> dict[str, np.ndarray]:
    """An item with its features recomputed by the current code from its stored renders and tiles
    (the same bytes as a fresh item: features are always taken from the stored 16-bit images)."""
    pair = init_net.WorkingPair.from_images(_from_uint16(item["reflection"]), _from_uint16(item["transmission"]),
                                            rig.gamma)
    pattern = priors.PATTERNS[int(item["pattern"])]
    return {**item, "features": row_features(pair, pattern, item["tiles"], rig),
            "feature_version": np.asarray(init_net.FEATURE_VERSION, dtype=np.int64)}


def feature_version(path: Path) -> int | None:
    """The feature version of an item file; None if it cannot be read (it is then remade)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return int(data["feature_version"])
    except Exception:  # a damaged file is as good as a missing one
        return None


# -- one item --------------------------------------------------------------------------------------
class ItemMaker:
    """Renders and describes items; one per worker process (its renderer keeps the fixed jitter)."""

    def __init__(self, settings: DatasetSettings, signatures, rig: CaptureRig = DEFAULT_RIG,
                 compile: bool | None = None):
        self.settings, self.signatures, self.rig = settings, signatures, rig
        self._renderer_args = (rig, settings.size, settings.spp, settings.seed, compile)
        self._renderer = None

    @property
    def renderer(self):
        """Built on first use (an update of old items' features renders nothing)."""
        if self._renderer is None:
            rig, size, spp, seed, compile = self._renderer_args
            self._renderer = Renderer(rig, size, spp, seed=seed, compile=compile)
        return self._renderer

    def make(self, pattern: str, index: int) -> dict[str, np.ndarray]:
        seed = item_seed(self.settings.seed, pattern, index)
        if self.settings.photo_scale:
            shot = photograph(pattern, random.Random(seed), self.rig, self.settings.photo_scale)
            params = shot.params
            # The fit's own path: 8-bit photos at the film's size, area-averaged in linear light.
            rendered = init_net.WorkingPair.from_images(torch.from_numpy(shot.reflection),
                                                        torch.from_numpy(shot.transmission), self.rig.gamma)
        else:
            params = priors.sample(pattern, random.Random(seed))
            with torch.no_grad():
                rendered = self.renderer.render(params)
        # Quantised to 16 bits first, as stored: the features of a reloaded item are the same.
        reflection, transmission = _to_uint16(rendered.reflection), _to_uint16(rendered.transmission)
        pair = init_net.WorkingPair.from_images(_from_uint16(reflection), _from_uint16(transmission), self.rig.gamma)
        features, tiles = candidate_rows(pair, params, self.rig, self.signatures, random.Random(seed ^ 0x5EED))
        return {"reflection": reflection, "transmission": transmission, "features": features, "tiles": tiles,
                "pattern": np.asarray(priors.PATTERNS.index(pattern), dtype=np.int64),
                "target": init_net.target_vector(params), "params": np.asarray(params.to_interchange()),
                "feature_version": np.asarray(init_net.FEATURE_VERSION, dtype=np.int64)}


def _to_uint16(image: torch.Tensor) -> np.ndarray:
    return np.round(image.clamp(0, 1).numpy().astype(np.float64) * 65535).astype(np.uint16)


def _from_uint16(data: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(data.astype(np.float32) / 65535.0)


def write_item(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """An .npz (readable by numpy.load) with fixed timestamps, written atomically."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name in sorted(arrays):
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.asarray(arrays[name]), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            archive.writestr(info, buffer.getvalue())
    tmp.replace(path)


def read_item(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {name: data[name] for name in data.files}


# -- the whole set ---------------------------------------------------------------------------------
def make_items(out: Path, jobs: list[tuple[str, int]], settings: DatasetSettings, signatures,
               compile: bool | None, on_item=lambda name: None) -> None:
    """Makes the given items in this process, one core."""
    torch.set_num_threads(1)  # one core per worker: K workers use K cores
    maker = ItemMaker(settings, signatures, compile=compile)
    for pattern, index in jobs:
        path = out / f"{item_name(pattern, index)}.npz"
        if feature_version(path) is not None:  # an item of an older feature version: describe it again
            write_item(path, redescribed(read_item(path)))
        else:
            write_item(path, maker.make(pattern, index))
        on_item(item_name(pattern, index))


def _shard_main() -> None:
    """Entry point of a worker process: its job list and settings come as JSON on stdin."""
    job = json.loads(sys.stdin.read())
    make_items(Path(job["out"]), [tuple(j) for j in job["jobs"]], DatasetSettings(**job["settings"]),
               pattern_signatures(DEFAULT_RIG), job["compile"])


def _run_shards(out: Path, jobs, settings: DatasetSettings, compile, workers: int, report) -> None:
    """Splits the jobs over ``workers`` Python processes (plain subprocesses: the command line's
    ``__main__`` must not be re-run the way multiprocessing's spawn would) and reports progress by
    watching the finished files appear."""
    procs = _start_workers(out, jobs, settings, compile, workers)
    try:
        missing = _watch(out, jobs, procs, report)
        _wait_for_exit(procs)
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.terminate()
            proc.wait()
    failed = [p.returncode for p in procs if p.returncode]
    if failed or missing:
        raise RuntimeError(f"dataset: {missing} item(s) not made; worker exit codes {failed}")


def _start_workers(out: Path, jobs, settings: DatasetSettings, compile, workers: int) -> list[subprocess.Popen]:
    """One worker process per non-empty shard (every ``workers``-th job), its jobs sent on stdin."""
    root = str(Path(__file__).resolve().parents[1])  # the checkout: holds the backend and devtools packages
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    procs = []
    for k in range(workers):
        shard = jobs[k::workers]
        if not shard:
            continue
        proc = subprocess.Popen([sys.executable, "-c", "from devtools.dataset import _shard_main; _shard_main()"],
                                stdin=subprocess.PIPE, env=env, text=True)
        proc.stdin.write(json.dumps({"out": str(out), "jobs": shard, "settings": asdict(settings),
                                     "compile": compile}))
        proc.stdin.close()
        procs.append(proc)
    return procs


def _wait_for_exit(procs: list[subprocess.Popen]) -> None:
    """Workers whose items are all written are still shutting down (Python, torch): up to
    WORKER_EXIT_S for all of them; one still running then is stopped and reported by its exit code."""
    deadline = time.monotonic() + WORKER_EXIT_S
    for proc in procs:
        try:
            proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            return


def _watch(out: Path, jobs, procs: list[subprocess.Popen], report) -> int:
    """Reports each item file as it appears, until all have or every worker has ended; returns how
    many are missing."""
    waiting = {f"{item_name(p, i)}.npz" for p, i in jobs}
    started = time.time() - 1.0

    def written(name):  # new or rewritten since the start (a stat, not a read: thousands are polled)
        try:
            return (out / name).stat().st_mtime >= started
        except FileNotFoundError:
            return False

    while waiting:
        finished = {name for name in waiting if written(name)}
        for name in sorted(finished):
            report(name[:-4])
        waiting -= finished
        if all(p.poll() is not None for p in procs):
            waiting = {name for name in waiting if not written(name)}
            break
        time.sleep(1.0)
    return len(waiting)


def recorded_settings(folder: str | Path) -> dict | None:
    """What a dataset folder's ``dataset.json`` records (None without one). A setting added since the
    folder was made reads as its default (photo_scale 0: clean renders)."""
    manifest = Path(folder) / "dataset.json"
    if not manifest.exists():
        return None
    return {**asdict(DatasetSettings()), **json.loads(manifest.read_text())}


def _check_settings(out: Path, settings: DatasetSettings, patterns: tuple[str, ...]) -> None:
    manifest = out / "dataset.json"
    wanted = {**asdict(settings), "patterns": list(patterns)}
    found = recorded_settings(out)
    if found is not None:
        mismatch = {k: (found.get(k), v) for k, v in wanted.items() if found.get(k) != v}
        if mismatch:
            raise ValueError(f"{manifest}: this folder was made with other settings "
                             f"({', '.join(f'{k}: {a!r} there, {b!r} now' for k, (a, b) in mismatch.items())}); "
                             "use a new --out folder")
    manifest.write_text(json.dumps({**wanted, "feature_version": init_net.FEATURE_VERSION}, indent=2) + "\n")


def pending_jobs(out: Path, per_pattern: int, patterns: tuple[str, ...] = priors.PATTERNS) -> list[tuple[str, int]]:
    """Items missing, unreadable or of an older feature version, patterns interleaved (a partial set
    stays balanced)."""
    return [(p, i) for i in range(per_pattern) for p in patterns
            if feature_version(out / f"{item_name(p, i)}.npz") != init_net.FEATURE_VERSION]


def generate(out: str | Path, per_pattern: int, workers: int = 1, settings: DatasetSettings = DatasetSettings(),
             compile: bool | None = None, patterns: tuple[str, ...] = priors.PATTERNS, signatures=None,
             log=sys.stderr) -> int:
    """Makes the missing items of a dataset folder; returns how many were made.

    ``patterns`` limits the presets drawn (every preset is still a candidate); ``signatures`` (the
    presets' harmonic signatures, :func:`backend.texture.signatures.signatures`) may be given to an in-process
    run (``workers`` 1) to skip measuring them.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if settings.photo_scale < 0 or (settings.photo_scale and settings.size != init_net.WORK_SIZE):
        raise ValueError(f"photo-like items need a photo scale >= 1 and the working size {init_net.WORK_SIZE} "
                         f"(got scale {settings.photo_scale}, size {settings.size})")
    unknown = [p for p in patterns if p not in priors.PATTERNS]
    if unknown:
        raise ValueError(f"unknown pattern(s) {', '.join(unknown)}; expected some of {', '.join(priors.PATTERNS)}")
    _check_settings(out, settings, tuple(patterns))
    for stale in out.glob(".*.tmp"):  # left by an interrupted run
        stale.unlink()
    jobs = pending_jobs(out, per_pattern, tuple(patterns))
    total = per_pattern * len(patterns)
    print(f"dataset: {total - len(jobs)}/{total} items present in {out}, {len(jobs)} to make "
          f"({settings.size} px, {settings.spp} spp, {workers} worker(s))", file=log, flush=True)
    if not jobs:
        return 0
    started = time.perf_counter()
    done = 0

    def report(name):
        nonlocal done
        done += 1
        rate = done / (time.perf_counter() - started)
        eta = (len(jobs) - done) / rate if rate > 0 else math.inf
        if done == len(jobs) or done % 10 == 0 or done < 3:
            print(f"dataset: {total - len(jobs) + done}/{total} ({name}) {rate:.2f} items/s, "
                  f"eta {eta / 60:.1f} min", file=log, flush=True)

    if workers <= 1:
        make_items(out, jobs, settings, signatures or pattern_signatures(DEFAULT_RIG), compile, report)
    else:
        _run_shards(out, jobs, settings, compile, workers, report)
    return done


def load_items(folder: str | Path, limit: int | None = None) -> list[Path]:
    """The item files of a dataset folder, sorted by name."""
    files = sorted(Path(folder).glob("*.npz"))
    return files[:limit] if limit else files
