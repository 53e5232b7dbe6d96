"""The initialisation network: shipped weights, features, predictions, dataset and training (fast)."""
import argparse
import json
import random

import numpy as np
import pytest
import torch

from backend.app.cli.fit import add_parser
from backend.core import priors
from backend.core.params import FabricParams
from backend.core.rig import DEFAULT_RIG
from backend.init import network as init_net
from backend.model.render import render_pair
from backend.texture import lattice
from backend.texture.candidates import Candidate
from devtools import dataset, train

TINY = dataset.DatasetSettings(size=32, spp=1, seed=3)


@pytest.fixture(scope="module")
def small_pair():
    params = priors.typical("twill1")
    pair = render_pair(params, DEFAULT_RIG, size=96, spp=1, seed=0)
    return pair.reflection.numpy(), pair.transmission.numpy()


@pytest.fixture(scope="module")
def trivial_signatures():
    """A one-harmonic signature per preset: the dataset's mechanics, without measuring the real ones."""
    one = lattice.Signature(np.array([1]), np.array([0]), np.array([1.0]))
    return {p: [one, one] for p in priors.PATTERNS}


def test_shipped_weights_load_with_weights_only_and_are_small():
    path = init_net.DEFAULT_WEIGHTS
    assert path.is_file(), f"{path} is missing: run `python -m devtools train DATASET --out {path}`"
    assert path.stat().st_size < 20e6
    blob = torch.load(path, map_location="cpu", weights_only=True)
    header = json.loads(blob["header"])
    assert header["feature_version"] == init_net.FEATURE_VERSION
    assert header["feature_dim"] == init_net.FEATURE_DIM
    assert init_net.InitModel.load(path).info["targets"] == list(init_net.TARGETS)


def test_features_are_finite_and_sized(small_pair):
    pair = init_net.WorkingPair.from_images(*small_pair)
    assert pair.reflection.shape == (init_net.WORK_SIZE, init_net.WORK_SIZE, 3)
    for pattern in priors.PATTERNS:
        features = init_net.candidate_features(pair, pattern, priors.typical(pattern).tiles, DEFAULT_RIG)
        assert features.shape == (init_net.FEATURE_DIM,)
        assert torch.isfinite(features).all()
    black = init_net.WorkingPair.from_images(np.zeros((64, 64, 3)), np.zeros((64, 64, 3)))
    assert torch.isfinite(init_net.candidate_features(black, "plain", (173.0, 173.0), DEFAULT_RIG)).all()


def test_the_network_recognises_a_rendered_twill(small_pair):
    hook = init_net.NetworkStart(*small_pair, DEFAULT_RIG)
    candidates = [Candidate(p, priors.typical(p).tiles, 0.0) for p in priors.PATTERNS]
    probabilities = hook.pattern_probabilities(candidates)
    assert dict(zip(priors.PATTERNS, probabilities))["twill1"] > 0.9  # small_pair is a twill1 render
    guess = hook(Candidate("twill1", priors.typical("twill1").tiles, 0.0))
    assert all(abs(a - b) < 0.25 for a, b in zip(guess.roughness, priors.typical("twill1").roughness))
    # A weave the network was not trained on gets no guess and no opinion: the fit's prior start.
    custom = Candidate("custom", (100.0, 100.0), 0.0)
    assert hook(custom) is None and hook.pattern_probabilities(candidates[:1] + [custom]) is None


def test_a_mirrored_candidate_is_read_in_the_photos_mirrored():
    """The network knows the paper's five: a mirrored preset's candidate is the preset it mirrors,
    read in the photos mirrored left-right. So a twill1 render's mirror image is a twill1m (at about
    6 px per yarn; in small_pair's 96 px, 0.3 px per yarn, aliasing leaves the diagonal ambiguous)."""
    tiles = (12.0, 18.0)
    pair = render_pair(priors.typical("twill1").replace(tiles=tiles), DEFAULT_RIG, size=256, spp=1, seed=0)
    shot = (pair.reflection.numpy(), pair.transmission.numpy())
    candidates = [Candidate(p, tiles, 0.0) for p in ("twill1", "twill1m")]
    as_shot = init_net.NetworkStart(*shot, DEFAULT_RIG)
    flipped = init_net.NetworkStart(*(np.ascontiguousarray(image[:, ::-1]) for image in shot), DEFAULT_RIG)
    assert as_shot.pattern_probabilities(candidates)[0] > 0.99
    assert flipped.pattern_probabilities(candidates)[1] > 0.99
    guess = flipped(Candidate("twill1m", tiles, 0.0))
    assert guess.pattern == "twill1m"
    assert guess.replace(pattern="twill1").to_interchange() == as_shot(Candidate("twill1", tiles, 0.0)).to_interchange()
    # A turned sample turns the other way in the mirrored photos, so does its rig's lamp offset.
    turned = DEFAULT_RIG.__class__(sample_rotation_deg=2.0, sample_skew_deg=0.5, front_light=(1.0, 8.0, 8.0))
    assert (turned.mirrored().sample_rotation_deg, turned.mirrored().sample_skew_deg) == (-2.0, -0.5)
    assert turned.mirrored().front_light == (-1.0, 8.0, 8.0) and turned.mirrored().mirrored() == turned


def test_target_vector_round_trip():
    params = priors.sample("satin0", random.Random(5))
    again = init_net.params_from_vector(init_net.target_vector(params), "satin0", params.tiles)
    for name in init_net.TARGETS:
        assert again.flat(name) == pytest.approx(params.flat(name), abs=1e-5)


def test_fit_initialiser_falls_back_to_the_prior_with_a_warning(small_pair, tmp_path):
    warnings = []
    assert init_net.fit_initialiser("prior", *small_pair, DEFAULT_RIG, warnings.append) is None
    assert init_net.fit_initialiser("network", *small_pair, DEFAULT_RIG, warnings.append,
                                    path=tmp_path / "missing.pt") is None
    assert len(warnings) == 1 and "missing" in warnings[0]
    broken = tmp_path / "broken.pt"
    broken.write_bytes(b"not a checkpoint")
    assert init_net.fit_initialiser("network", *small_pair, DEFAULT_RIG, warnings.append, path=broken) is None
    assert len(warnings) == 2
    assert callable(init_net.fit_initialiser("network", *small_pair, DEFAULT_RIG, warnings.append))


def test_fit_command_defaults_to_the_network():
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())
    assert parser.parse_args(["fit", "--out", "x"]).init == "network"


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory, trivial_signatures):
    folder = tmp_path_factory.mktemp("dataset")
    made = dataset.generate(folder, 1, settings=TINY, compile=False, patterns=("plain", "satin0"),
                            signatures=trivial_signatures, log=open("/dev/null", "w"))
    assert made == 2
    return folder


def test_dataset_is_deterministic_and_resumable(tiny_dataset, tmp_path, trivial_signatures):
    first = {p.name: p.read_bytes() for p in tiny_dataset.glob("*.npz")}
    assert sorted(first) == ["plain_00000.npz", "satin0_00000.npz"]
    # Resume: a finished folder makes nothing; a missing item is remade with the same bytes.
    quiet = open("/dev/null", "w")
    assert dataset.generate(tiny_dataset, 1, settings=TINY, compile=False, patterns=("plain", "satin0"),
                            signatures=trivial_signatures, log=quiet) == 0
    (tmp_path / "again").mkdir()
    (tmp_path / "again" / "plain_00000.npz").write_bytes(first["plain_00000.npz"])
    assert dataset.generate(tmp_path / "again", 1, settings=TINY, compile=False, patterns=("plain", "satin0"),
                            signatures=trivial_signatures, log=quiet) == 1
    assert {p.name: p.read_bytes() for p in (tmp_path / "again").glob("*.npz")} == first
    with pytest.raises(ValueError, match="other settings"):
        dataset.generate(tiny_dataset, 1, settings=dataset.DatasetSettings(size=32, spp=2, seed=3),
                         compile=False, patterns=("plain", "satin0"), signatures=trivial_signatures, log=quiet)
    item = dataset.read_item(tiny_dataset / "satin0_00000.npz")
    assert item["features"].shape == (6, init_net.FEATURE_DIM) and np.isfinite(item["features"]).all()
    assert int(item["pattern"]) == priors.PATTERNS.index("satin0")
    truth = FabricParams.from_interchange(str(item["params"]))
    assert item["tiles"][-1] == pytest.approx(truth.tiles)
    assert item["target"] == pytest.approx(init_net.target_vector(truth))


def test_a_folder_made_before_photo_like_items_resumes_as_clean_renders(tiny_dataset, tmp_path, trivial_signatures):
    folder = tmp_path / "older"
    folder.mkdir()
    manifest = json.loads((tiny_dataset / "dataset.json").read_text())
    del manifest["photo_scale"]  # what a folder made before the setting existed holds
    (folder / "dataset.json").write_text(json.dumps(manifest))
    quiet = open("/dev/null", "w")
    assert dataset.generate(folder, 1, settings=TINY, compile=False, patterns=("plain", "satin0"),
                            signatures=trivial_signatures, log=quiet) == 2
    with pytest.raises(ValueError, match="photo_scale: 0 there, 2 now"):
        dataset.generate(folder, 1, settings=dataset.DatasetSettings(size=256, spp=1, seed=3, photo_scale=2),
                         compile=False, patterns=("plain", "satin0"), signatures=trivial_signatures, log=quiet)


def test_a_tiny_training_run_reduces_its_loss(tiny_dataset):
    arrays = train.load_arrays(tiny_dataset, log=open("/dev/null", "w"))
    net, info = train.train(arrays, train.TrainSettings(batch=2, lr=3e-3, dropout=0.0), log=open("/dev/null", "w"),
                            steps=40)
    assert info["train"]["loss"] < 0.5 * info["initial_train"]["loss"]
    path = init_net.save(net, tiny_dataset / "net.pt", {"training": info})
    model = init_net.InitModel.load(path)
    targets, logits = model.predict(arrays.features[:, :5])
    assert targets.shape == (2, 5, init_net.TARGET_SIZE) and logits.shape == (2, 5)


def test_photo_like_items_are_photographed_turned_samples(tmp_path, trivial_signatures):
    from backend.texture.frequencies import yarns_in_view
    from devtools.photo_like import MAX_ROTATION_DEG, PIXELS_PER_YARN
    photo = dataset.DatasetSettings(seed=3, photo_scale=1)
    quiet = open("/dev/null", "w")
    assert dataset.generate(tmp_path / "a", 1, settings=photo, compile=False, patterns=("twill0",),
                            signatures=trivial_signatures, log=quiet) == 1
    assert dataset.generate(tmp_path / "b", 1, settings=photo, compile=False, patterns=("twill0",),
                            signatures=trivial_signatures, log=quiet) == 1
    made = (tmp_path / "a" / "twill0_00000.npz").read_bytes()
    assert made == (tmp_path / "b" / "twill0_00000.npz").read_bytes()
    item = dataset.read_item(tmp_path / "a" / "twill0_00000.npz")
    truth = FabricParams.from_interchange(str(item["params"]))
    # Framed as a photographer frames a sample: the denser axis's yarns get at least 2 film pixels each.
    assert DEFAULT_RIG.film_size / yarns_in_view("twill0", truth.tiles, DEFAULT_RIG) >= PIXELS_PER_YARN[0] - 1e-6
    assert item["reflection"].shape == (init_net.WORK_SIZE, init_net.WORK_SIZE, 3)
    assert np.isfinite(item["features"]).all() and item["tiles"][-1] == pytest.approx(truth.tiles)
    # The photo is not the clean render of its truth: turned in the holder, blurred, noisy, unevenly lit.
    clean = render_pair(truth, DEFAULT_RIG, size=init_net.WORK_SIZE, spp=4, seed=0).reflection.numpy()
    photo_image = dataset._from_uint16(item["reflection"]).numpy()
    assert np.abs(photo_image - clean).mean() > 0.01
    # The item is the shot of its seed: the same draws as photo_like.photograph with that seed.
    from devtools.photo_like import photograph
    shot = photograph("twill0", random.Random(dataset.item_seed(3, "twill0", 0)), DEFAULT_RIG, 1)
    assert shot.params == truth and abs(shot.rig.sample_rotation_deg) <= MAX_ROTATION_DEG
    with pytest.raises(ValueError, match="working size"):
        dataset.generate(tmp_path / "c", 1, settings=dataset.DatasetSettings(size=128, photo_scale=2),
                         compile=False, patterns=("plain",), signatures=trivial_signatures, log=quiet)


def test_training_reads_several_dataset_folders(tiny_dataset, tmp_path, trivial_signatures):
    other = dataset.DatasetSettings(size=32, spp=1, seed=4)
    dataset.generate(tmp_path / "more", 1, settings=other, compile=False, patterns=("twill1",),
                     signatures=trivial_signatures, log=open("/dev/null", "w"))
    arrays = train.load_arrays([tiny_dataset, tmp_path / "more"], log=open("/dev/null", "w"))
    first = tiny_dataset.name
    assert arrays.names == [f"{first}/plain_00000", f"{first}/satin0_00000", "more/twill1_00000"]
    assert arrays.patterns.tolist() == [priors.PATTERNS.index(p) for p in ("plain", "satin0", "twill1")]
    assert arrays.features.shape == (3, 6, init_net.FEATURE_DIM)
