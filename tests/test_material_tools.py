"""The material tools' plain-Python side (blender_addon/core, no Blender): asset catalogs and tags,
which shader renders, the real-world scale of a mesh, the colour layer's rules and the batch queue
that the sidebar's batch polls (against the fake backend)."""
from __future__ import annotations

import math
import os
import signal
import sys
import threading
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from blender_addon.core import (  # noqa: E402
    asset_catalogs,
    backend_bridge,
    batch_queue,
    colour_layer,
    declarations,
    mesh_scale,
    shader_params,
    shader_status,
)

FAKE_BACKEND = Path(__file__).resolve().parent / "fake_backend.py"
PNG_1x1 = bytes.fromhex("89504e470d0a1a0a0000000d4948445200000001000000010806000000"
                        "1f15c4890000000d49444154789c6360f8cfc0f01f0005000201d1b5a0550000000049454e44ae426082")
HANG_S = 60  # a liveness bound (a hung poll fails instead of blocking the suite), not a timing
POLLS = 3000  # a liveness bound on the polls of a batch (about a minute of 20 ms pauses), not a timing


# -- catalogs and tags -----------------------------------------------------------------------------

def test_catalogs_have_the_weaves_names_for_people():
    """Catalogs are named from the weave declaration (one name per preset, no internal codes)."""
    paths = [asset_catalogs.catalog_path(name) for name in declarations.preset_names()]
    assert len(set(paths)) == len(paths)
    assert paths[:2] == ["Fabrics/Plain", "Fabrics/Twill (warp-faced)"]
    assert asset_catalogs.catalog_path("satin0m") == "Fabrics/Satin (weft-faced, mirrored)"
    assert not any(any(ch.isdigit() for ch in path) for path in paths)
    assert asset_catalogs.catalog_path("custom") == "Fabrics/custom"


def test_catalog_ids_are_stable_and_the_file_is_merged(tmp_path):
    path = asset_catalogs.catalog_path("twill1")
    assert path == "Fabrics/Twill (weft-faced)"
    assert asset_catalogs.catalog_id(path) == asset_catalogs.catalog_id("Fabrics/Twill (weft-faced)")
    assert uuid.UUID(asset_catalogs.catalog_id(path)).version == 5
    ids = asset_catalogs.ensure_catalogs(tmp_path, ["Fabrics/twill1", "Fabrics/plain"])
    text = (tmp_path / asset_catalogs.CATALOG_FILE).read_text()
    assert "VERSION 1" in text
    assert asset_catalogs.parse(text) == {p: asset_catalogs.catalog_id(p)
                                          for p in ("Fabrics", "Fabrics/twill1", "Fabrics/plain")}
    assert ids == {p: asset_catalogs.catalog_id(p) for p in ("Fabrics/twill1", "Fabrics/plain")}
    # Again: nothing duplicated. A catalog the user made by hand keeps its UUID; their lines stay.
    mine = "0b5e1a2c-0000-4000-8000-000000000001"
    (tmp_path / asset_catalogs.CATALOG_FILE).write_text(text + f"{mine}:Fabrics/satin0:my satins\n"
                                                        "# a comment of theirs\n")
    ids = asset_catalogs.ensure_catalogs(tmp_path, ["Fabrics/twill1", "Fabrics/satin0"])
    again = (tmp_path / asset_catalogs.CATALOG_FILE).read_text()
    assert ids["Fabrics/satin0"] == mine and "# a comment of theirs" in again
    assert again.count(":Fabrics/twill1:") == 1 and again.count(":Fabrics/satin0:") == 1


@pytest.mark.parametrize("rgb, name", [((0.8, 0.05, 0.05), "red"), ((0.05, 0.1, 0.7), "blue"),
                                       ((0.1, 0.5, 0.1), "green"), ((0.5, 0.5, 0.5), "grey"),
                                       ((0.01, 0.01, 0.01), "black"), ((0.9, 0.9, 0.88), "white"),
                                       ((0.15, 0.06, 0.02), "brown"), ((0.8, 0.6, 0.05), "yellow")])
def test_colour_names(rgb, name):
    assert asset_catalogs.colour_name(rgb) == name


def test_tags_name_the_weave_and_the_colour():
    """The colour tag is the rendered colour's (specular and diffuse albedos), not the diffuse albedo's."""
    params = {"pattern": "satin0", "specular_albedo": [[0.05, 0.1, 0.7], [0.05, 0.12, 0.6]], "multiple_weight": 1.0,
              "diffuse_reflection": [0.05, 0.1, 0.7]}
    assert asset_catalogs.tags(params) == ["fabric", "woven", "satin0", "blue"]
    assert asset_catalogs.tags(dict(params, diffuse_reflection=[0.6, 0.05, 0.05]))[-1] == "pink"  # red + blue
    assert asset_catalogs.tags({"pattern": "plain"}) == ["fabric", "woven", "plain"]


# -- which shader renders ------------------------------------------------------------------------

def test_shader_status_says_which_shader_renders():
    osl = shader_status.shader_status("CYCLES", True, "CPU")
    assert osl.osl and "OSL" in osl.text and not osl.can_enable_osl
    off = shader_status.shader_status("CYCLES", False, "CPU")
    assert not off.osl and "fallback" in off.text and off.can_enable_osl
    assert shader_status.shader_status("CYCLES", True, "GPU", "OPTIX").osl
    cuda = shader_status.shader_status("CYCLES", True, "GPU", "CUDA")
    assert not cuda.osl and not cuda.can_enable_osl and "fallback" in cuda.text
    assert shader_status.shader_status("CYCLES", True, "GPU", "NONE").osl  # GPU asked, none set up: CPU
    eevee = shader_status.shader_status("BLENDER_EEVEE")
    assert not eevee.osl and "EEVEE" in eevee.text and "fallback" in eevee.text


# -- real-world scale ----------------------------------------------------------------------------

def test_uv_unit_cm_from_areas():
    # A 2 m x 0.5 m rectangle (scene units in metres) whose UVs cover half the unit square, evenly:
    # 1 m^2 over 0.5 UV units^2 -> one UV unit is sqrt(2) m = 141.4 cm across.
    quad = np.array([[0, 0, 0], [2, 0, 0], [2, 0.5, 0], [0, 0.5, 0]], float)
    uv = np.array([[0, 0], [1, 0], [1, 0.5], [0, 0.5]], float)
    tris = [[0, 1, 2], [0, 2, 3]]
    assert mesh_scale.uv_unit_cm(quad[tris], uv[tris]) == pytest.approx(100 * math.sqrt(2))
    assert mesh_scale.uv_unit_cm(quad[tris], uv[tris], scale_length=0.01) == pytest.approx(math.sqrt(2))
    assert mesh_scale.triangle_areas(quad[tris]).sum() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="unwrap"):
        mesh_scale.uv_unit_cm(quad[tris], np.zeros((2, 3, 2)))
    # With the rig's rule: the weave's repeats per cm on the mesh equal those of the photo.
    width_cm, tiles = 4.0, 120.0
    scale = shader_params.uv_scale(width_cm, mesh_scale.uv_unit_cm(quad[tris], uv[tris]))
    assert tiles * scale / (100 * math.sqrt(2)) == pytest.approx(tiles / shader_params.uv_unit_cm(width_cm))


# -- colour layer ---------------------------------------------------------------------------------

def test_colour_layer_size_and_neutral_start():
    assert colour_layer.layer_size((173.0, 173.0)) == colour_layer.MIN_SIZE
    assert colour_layer.layer_size((120.0, 160.0), uv_scale=8.0) == 2048       # 1280 repeats
    assert colour_layer.layer_size((300.0, 300.0), uv_scale=100.0) == colour_layer.MAX_SIZE
    assert colour_layer.initial_pixel("MULTIPLY") == (1.0, 1.0, 1.0, 1.0)
    assert colour_layer.initial_pixel("REPLACE") == (1.0, 1.0, 1.0, 0.0)
    with pytest.raises(ValueError):
        colour_layer.initial_pixel("SCREEN")


# -- the batch queue ------------------------------------------------------------------------------

@pytest.fixture
def pair_folder(tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    for name in ("linen", "wool"):
        (folder / f"{name}_R.png").write_bytes(PNG_1x1)
        (folder / f"{name}_T.png").write_bytes(PNG_1x1)
    (folder / "torn_R.png").write_bytes(PNG_1x1)
    (folder / "torn_T.png").write_text("not an image")
    (folder / "solo_R.png").write_bytes(PNG_1x1)
    return folder


def _queue(folder, tmp_path, made, **options):
    def on_fitted(job, params, description, preview):
        made.append((job.name, params["pattern"], description, Path(preview).name))
        return f"{job.name} material"

    return batch_queue.BatchQueue(folder, backend_bridge.Backend(sys.executable, str(FAKE_BACKEND)),
                                  tmp_path / "fits", {"width_cm": 5.0}, on_fitted,
                                  batch_queue.BatchOptions({"iterations": 3}, **options))


def _poll_until(queue, ended):
    """Polls ``queue`` until ``ended()``; returns the pairs seen running (never two at once)."""
    seen_running = set()
    for _ in range(POLLS):
        if ended():
            return seen_running
        queue.poll()
        seen_running |= {job.name for job in queue.jobs if job.state == batch_queue.RUNNING}
        assert sum(job.state == batch_queue.RUNNING for job in queue.jobs) <= 1
        time.sleep(0.02)
    raise AssertionError("the batch did not get there")


def _poll_until_done(queue):
    return _poll_until(queue, lambda: queue.done)


def test_batch_queue_fits_pairs_one_at_a_time_and_lists_failures(tmp_path, pair_folder, monkeypatch):
    monkeypatch.setenv("FAKE_BACKEND_MODE", "ok")
    made = []
    queue = _queue(pair_folder, tmp_path, made).start()
    states = {job.name: job.state for job in queue.jobs}
    assert states["solo"] == batch_queue.FAILED  # no partner: failed at once, with the reason
    assert sum(s == batch_queue.RUNNING for s in states.values()) == 1
    running = _poll_until_done(queue)
    jobs = {job.name: job for job in queue.jobs}
    assert running == {"linen", "torn", "wool"}
    assert [m[0] for m in made] == ["linen", "wool"] and made[0][1:] == (
        "twill1", "Woven fabric fitted from linen_R.png and linen_T.png "
        f"({jobs['linen'].out_dir})", "reflection.png")
    assert jobs["linen"].state == batch_queue.DONE and jobs["linen"].material == "linen material"
    assert jobs["linen"].progress == 1.0 and (Path(jobs["linen"].out_dir) / "params.json").is_file()
    assert jobs["torn"].state == batch_queue.FAILED and "Bad input" in jobs["torn"].reason \
        and "torn_T.png" in jobs["torn"].reason
    assert "solo_T" in jobs["solo"].reason
    assert [job.name for job in queue.failures()] == ["torn", "solo"]
    assert queue.summary() == "2 fitted, 2 failed" and queue.progress == 1.0


def test_batch_queue_polls_without_blocking_and_cancels(tmp_path, pair_folder, monkeypatch):
    monkeypatch.setenv("FAKE_BACKEND_MODE", "slow")
    queue = _queue(pair_folder, tmp_path, []).start()
    first = next(job for job in queue.jobs if job.state == batch_queue.RUNNING)
    _poll_until(queue, lambda: first.progress > 0.0)
    assert 0.0 < queue.progress < 1.0 and "Optimising" in first.status
    pid = queue.fit.pid
    os.kill(pid, signal.SIGSTOP)  # alive, holding its pipes open, writing nothing
    try:
        poller = threading.Thread(target=lambda: [queue.poll() for _ in range(3)], daemon=True)
        poller.start()
        poller.join(HANG_S)
        assert not poller.is_alive(), "poll() waited for the backend"
        assert first.state == batch_queue.RUNNING and queue.fit.pid == pid
    finally:
        os.kill(pid, signal.SIGCONT)
    queue.request_cancel()
    _poll_until_done(queue)
    assert first.state == batch_queue.CANCELLED
    assert all(job.state in (batch_queue.CANCELLED, batch_queue.FAILED) for job in queue.jobs)
    assert not Path(f"/proc/{pid}").exists(), "the cancelled backend is still running"
    assert queue.summary().endswith("cancelled")


def test_batch_queue_refuses_a_folder_without_pairs(tmp_path):
    with pytest.raises(ValueError, match="not a folder"):
        _queue(tmp_path / "missing", tmp_path, [])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no <name>_R"):
        _queue(tmp_path / "empty", tmp_path, [])


def test_a_material_that_cannot_be_made_fails_only_its_pair(tmp_path, pair_folder, monkeypatch):
    monkeypatch.setenv("FAKE_BACKEND_MODE", "ok")
    (pair_folder / "torn_T.png").unlink()
    (pair_folder / "torn_R.png").unlink()

    def on_fitted(job, params, description, preview):
        if job.name == "linen":
            raise RuntimeError("no room in the file")
        return job.name

    queue = batch_queue.BatchQueue(pair_folder, backend_bridge.Backend(sys.executable, str(FAKE_BACKEND)),
                                   tmp_path / "fits", {}, on_fitted).start()
    _poll_until_done(queue)
    jobs = {job.name: job for job in queue.jobs}
    assert jobs["linen"].state == batch_queue.FAILED and "no room in the file" in jobs["linen"].reason
    assert jobs["wool"].state == batch_queue.DONE


def test_a_pair_past_the_time_limit_fails_and_the_next_one_runs(tmp_path, pair_folder, monkeypatch):
    monkeypatch.setenv("FAKE_BACKEND_MODE", "slow")
    (pair_folder / "torn_T.png").unlink()
    (pair_folder / "torn_R.png").unlink()
    queue = _queue(pair_folder, tmp_path, [], timeout_s=0.5).start()
    _poll_until_done(queue)
    jobs = {job.name: job for job in queue.jobs}
    assert [jobs[name].state for name in ("linen", "wool")] == [batch_queue.FAILED] * 2
    assert jobs["linen"].reason == "The fit took longer than 0.5 s and was stopped." and jobs["linen"].attempts == 1
