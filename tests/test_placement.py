"""How the sample lies in the holder: rotation and skew (shear) in the renderer's geometry, in the
lattice's frequency maps, and as the fit reads them from a photo pair."""
import dataclasses
import json
import math

import numpy as np
import pytest
import torch

from backend.core import priors
from backend.core.rig import DEFAULT_RIG, CaptureRig, RigError
from backend.image import spectrum
from backend.image.spectrum import Peak
from backend.model.camera import CameraSamples
from backend.model.geometry import GeometryKey, sample_geometry
from backend.model.layers import WeaveLookup
from backend.model.render import Renderer
from backend.texture import frequencies, lattice, placement, signatures, spacing
from backend.texture.gates import GATES
from backend.texture.placement.peaked import peak_pair_turns
from backend.texture.placement.votes import yarn_turn
from backend.texture.spectra import Spectra


def test_fabric_frequencies_undo_turned_frequencies_with_a_skew():
    rng = np.random.default_rng(5)
    f1, f2 = rng.uniform(-80, 80, 50), rng.uniform(-80, 80, 50)
    for rotation, skew in ((0.0, 0.0), (2.0, 0.0), (-3.0, 4.0), (1.5, -6.0)):
        fx, fy = frequencies.turned_frequencies(f1, f2, rotation, skew)
        back = frequencies.fabric_frequencies(fx, fy, rotation, skew)
        np.testing.assert_allclose(back, (f1, f2), atol=1e-9)
    # no skew: a rotation keeps lengths; a skew does not
    fx, fy = frequencies.turned_frequencies(f1, f2, 3.0)
    np.testing.assert_allclose(np.hypot(fx, fy), np.hypot(f1, f2))
    fx, fy = frequencies.turned_frequencies(f1, f2, 3.0, 4.0)
    assert np.abs(np.hypot(fx, fy) - np.hypot(f1, f2)).max() > 0.5


def test_a_sheared_samples_yarns_run_along_their_own_angles():
    # Warps run along R(rotation + skew / 2) y, wefts along R(rotation - skew / 2) x: read from the
    # fiber directions of a twill without twist (the fiber lies along its yarn, tilted only in z).
    rig = CaptureRig(sample_rotation_deg=1.5, sample_skew_deg=4.0)
    warp_deg, weft_deg = rig.yarn_angles_deg
    assert (warp_deg, weft_deg) == (3.5, -0.5)
    params = priors.typical("twill0").replace(tiles=(30.0, 30.0), twist_deg=(0.0, 0.0))
    rng = np.random.default_rng(2)
    xs, ys = rng.uniform(0, rig.view_size, 400), rng.uniform(-rig.view_size, 0, 400)
    chunk = CameraSamples(rig, 512, 1, dtype=torch.float64).at_points(torch.tensor(xs), torch.tensor(ys))
    key = GeometryKey(params.pattern, params.tiles, params.gap_scale, params.twist_deg, 0.0, True, 2)
    geometry = sample_geometry(chunk, WeaveLookup(params.resolved_weave, dtype=torch.float64), rig, key, torch.float64)
    seen = {"warp": 0, "weft": 0}
    for layer in geometry.layers:
        for kind, mask, expected in (("warp", layer.warp, 90.0 + warp_deg), ("weft", layer.weft, weft_deg)):
            fiber = layer.fiber[:, mask > 0]
            angle = torch.rad2deg(torch.atan2(fiber[1], fiber[0])) % 180.0
            np.testing.assert_allclose(angle.numpy(), expected % 180.0, atol=1e-6)
            seen[kind] += fiber.shape[1]
    assert min(seen.values()) > 50


def test_a_sheared_renders_peaks_sit_on_its_turned_lattice():
    # The renderer's geometry and the lattice's frequency map must describe the same shear: every
    # strong spectral peak of a sheared render turns back to a whole harmonic (m a, n b).
    rig = CaptureRig(sample_rotation_deg=1.0, sample_skew_deg=4.0)
    params = priors.typical("twill0").replace(tiles=(12.0, 12.0))
    with torch.no_grad():
        pair = Renderer(rig, 512, 4).render(params)
    a, b = frequencies.lattice_of(params.tiles, rig)
    for image in (pair.reflection.numpy(), pair.transmission.numpy()):
        peaks = spectrum.spectral_peaks(image)[:8]
        fx, fy = np.array([p.fx for p in peaks]), np.array([p.fy for p in peaks])

        def off_lattice(skew):
            f1, f2 = frequencies.fabric_frequencies(fx, fy, 1.0, skew)
            return np.abs(f1 - a * np.round(f1 / a)) + np.abs(f2 - b * np.round(f2 / b))

        assert off_lattice(4.0).max() < 0.5          # cycles per image
        assert off_lattice(0.0).mean() > 1.0         # the shear is not negligible


def test_the_sample_skew_is_read_from_the_spectra():
    # (An unsheared sample reads skew 0: test_fit's test_the_sample_rotation_is_read_from_the_spectra.)
    params = priors.typical("twill0").replace(tiles=(18.0, 24.0))
    rig = CaptureRig(sample_rotation_deg=-1.5, sample_skew_deg=3.5)
    with torch.no_grad():
        pair = Renderer(rig, 512, 8, seed=3).render(params)
    spectra = Spectra.of([pair.reflection.numpy(), pair.transmission.numpy()])
    found = placement.estimate(spectra, CaptureRig(), priors.FIT_PATTERNS)
    assert found.rotation_deg == pytest.approx(rig.sample_rotation_deg, abs=0.25)
    assert found.skew_deg == pytest.approx(rig.sample_skew_deg, abs=0.3)
    # the fit's candidates: the sheared placement, and the weave's own lattice at it
    (rotation, skew), found = placement.place(spectra, CaptureRig(), ("twill0",), None)
    assert (rotation, skew) == pytest.approx((-1.5, 3.5), abs=0.3)
    assert found[0].tiles == pytest.approx(params.tiles, rel=0.01)
    (rotation, skew), found = placement.place(spectra, CaptureRig(), ("twill0",), 0.5)
    assert (rotation, skew) == (0.5, 0.0)  # a given rotation keeps the rig's skew


def test_the_placement_is_the_same_on_any_number_of_threads():
    # The lattice search scores patterns, angles and hypotheses on up to `workers` threads; each is
    # independent of the others, so the numbers must not move.
    params = priors.typical("twill1").replace(tiles=(20.0, 26.0))
    with torch.no_grad():
        pair = Renderer(CaptureRig(sample_rotation_deg=2.0), 512, 4, seed=5).render(params)
    images = [pair.reflection.numpy(), pair.transmission.numpy()]
    spectra = Spectra.of(images)
    on_threads = Spectra.of(images, workers=2)  # each photo's spectrum on its own thread
    assert on_threads.peaks == spectra.peaks and on_threads.coarse == spectra.coarse
    for mine, theirs in zip(spectra.maps + spectra.highpassed, on_threads.maps + on_threads.highpassed):
        assert np.array_equal(mine, theirs)
    patterns = ("plain", "twill0", "twill1", "satin0")
    found = {}
    for workers in (1, 3):
        found[workers] = placement.place(spectra, CaptureRig(), patterns, None, workers=workers)
    assert found[1][0] == pytest.approx((2.0, 0.0), abs=0.3)  # a turn read (both paths of placed ran)
    assert found[1] == found[3]


@pytest.mark.parametrize("skew", [11.0, float("nan"), "2"])
def test_a_skew_out_of_range_is_refused_by_name(skew):
    with pytest.raises(RigError, match="sample_skew_deg"):
        CaptureRig(sample_skew_deg=skew)
    assert math.isfinite(CaptureRig(sample_skew_deg=-10.0).sample_skew_deg)


def test_signatures_are_rendered_once_per_placement_and_only_for_the_patterns_asked(monkeypatch):
    monkeypatch.setattr(signatures, "_SIGNATURES", type(signatures._SIGNATURES)())  # this test's own cache
    rendered = []
    render = Renderer.render
    monkeypatch.setattr(Renderer, "render", lambda self, params, *args, **kwargs: rendered.append(params.pattern)
                        or render(self, params, *args, **kwargs))
    rig = CaptureRig(front_intensity=250.0)  # not the default rig, whose signatures ship
    alone = signatures.signatures(rig, ("twill1",))  # a fit of a given pattern
    assert rendered == ["twill1"]
    placed = dataclasses.replace(rig, sample_rotation_deg=1.25, sample_skew_deg=3.0)
    together = signatures.signatures(placed, ("plain", "twill1"))
    assert rendered == ["twill1", "plain"]  # rendered unturned and unsheared: a placed rig shares the entries
    assert together["twill1"] is alone["twill1"]
    turned = signatures.signatures(dataclasses.replace(DEFAULT_RIG, sample_rotation_deg=-2.0), ("satin0",))
    assert turned["satin0"] is signatures.signatures(DEFAULT_RIG, ("satin0",))["satin0"]
    assert rendered == ["twill1", "plain"]  # the default rig's, turned: the shipped ones
    # ... with the numbers of a render of every pattern by one renderer, whatever was rendered with it
    monkeypatch.setattr(signatures, "_SIGNATURES", type(signatures._SIGNATURES)())
    every = signatures.signatures(rig)
    assert rendered[2:] == list(priors.FIT_PATTERNS) and list(every) == list(priors.FIT_PATTERNS)
    for pattern in ("plain", "twill1"):
        for mine, theirs in zip(together[pattern], every[pattern]):
            for field in ("m", "n", "weight"):
                np.testing.assert_array_equal(getattr(mine, field), getattr(theirs, field))


def test_the_default_rigs_signatures_ship_with_the_backend_and_are_its_renders(monkeypatch, tmp_path):
    """Every fit's placement compares the default rig's unturned signatures: they are read from
    backend/data/signatures.json, not rendered, and they are what the renderer makes of them now
    (a change to the renderer or the presets that moves them needs the file written again:
    python -m devtools signatures)."""
    monkeypatch.setattr(signatures, "_SIGNATURES", type(signatures._SIGNATURES)())
    rendered = []
    render = Renderer.render
    monkeypatch.setattr(Renderer, "render", lambda self, params, *args, **kwargs: rendered.append(params.pattern)
                        or render(self, params, *args, **kwargs))
    shipped = signatures.signatures(DEFAULT_RIG)
    assert rendered == [] and list(shipped) == list(priors.FIT_PATTERNS)
    fresh = signatures.rendered_signatures(DEFAULT_RIG, priors.FIT_PATTERNS)
    for pattern in priors.FIT_PATTERNS:
        for mine, theirs in zip(shipped[pattern], fresh[DEFAULT_RIG, pattern]):
            ours = {(int(m), int(n)): w for m, n, w in zip(mine.m, mine.n, mine.weight)}
            now = {(int(m), int(n)): w for m, n, w in zip(theirs.m, theirs.n, theirs.weight)}
            for harmonic in ours.keys() | now.keys():  # the weakest may trade places within rounding
                assert ours.get(harmonic, 0.0) == pytest.approx(now.get(harmonic, 0.0), rel=1e-4, abs=1e-4), \
                    (pattern, harmonic)
    # no file, or one for another density: rendered as before
    assert signatures.shipped_signatures(tmp_path / "missing.json") == {}
    other = json.loads(signatures.SHIPPED_SIGNATURES.read_text())
    other["density"] = 2 * other["density"]
    (tmp_path / "other.json").write_text(json.dumps(other))
    assert signatures.shipped_signatures(tmp_path / "other.json") == {}


def reading(placement, from_transmission=True):
    return spacing.MeanSpacing(lattice.Lattice(40.0, 50.0, 1.0), placement, from_transmission)


def test_the_turn_is_the_candidates_consensus_of_their_yarn_vectors():
    placed = (2.0, 0.0)
    agreeing = [reading((2.61, 0.05)), reading((2.7, -0.1)), reading((2.64, 0.2))]
    wrong_pattern = reading((3.9, 3.1))      # sheared by degrees: its harmonics are not in the photo
    unsolved = reading(None)
    assert yarn_turn(agreeing + [wrong_pattern, unsolved], placed) == pytest.approx(2.64)
    # votes that disagree, or none, show no turn (the placement stays as it was read)
    assert yarn_turn([reading((2.6, 0.0)), reading((2.2, 0.1))], placed) is None
    assert yarn_turn([wrong_pattern, unsolved], placed) is None
    # a reading further than vote_reach_deg is not a correction of this placement
    assert yarn_turn([reading((4.0, 0.0))], placed) is None
    # the transmission's readings outvote those that needed the reflection
    glints = [reading((2.3, 0.0), from_transmission=False)] * 3
    assert yarn_turn(glints + [reading((2.5, 0.0))], placed) == 2.5
    assert yarn_turn(glints, placed) == 2.3
    assert yarn_turn(glints, placed, reflection_votes=None) is None
    assert yarn_turn(glints[:1], placed, reflection_votes=2) is None
    assert yarn_turn(glints[:2], placed, reflection_votes=2) == 2.3
    # a sheared placement keeps its skew; its votes are those sheared alike
    assert yarn_turn([reading((1.2, 3.6)), reading((1.1, 0.0))], (1.0, 3.5)) == 1.2


def test_two_strong_peaks_read_as_low_harmonics_pin_the_turn():
    # A plain at 2-3 px per yarn can leave only its (1, 1) and (-1, 1) harmonics and an aliased
    # yarn harmonic standing; taken as two harmonics of one lattice, any two of them give the turn.
    a, b, turn = 99.0, 97.5, -2.9

    def peak(m, n, strength):
        fx, fy = frequencies.turned_frequencies(m * a, n * b, turn)
        sign = 1.0 if fy > 0 or (fy == 0 and fx > 0) else -1.0  # the half plane spectral_peaks keeps
        return Peak(sign * fx, sign * fy, strength)

    aliased = Peak(512 - 2 * a, 6.0, 5.0)
    spectra = Spectra(512, [[peak(1, 1, 7.0), aliased, peak(-1, 1, 6.5)], []], [], [])
    found = peak_pair_turns(spectra, (10.0, 240.0), (10.0, 240.0))
    assert any(np.allclose(hypothesis, (a, b, turn), atol=1e-6) for hypothesis in found)
    assert all(abs(t) <= GATES.scan_deg for _, _, t in found)
    # the mirror turn is not read: u and v each keep their own angle
    assert not any(np.allclose(hypothesis, (a, b, -turn), atol=0.05) for hypothesis in found)


def test_a_photo_of_noise_alone_shows_no_weave_and_does_not_place_the_sample():
    # The strongest peak of a noise spectrum stays under chance_peakness (a false alarm of 1e-6 per
    # photo, so none in these); a weave's photo stands far above it.
    rng = np.random.default_rng(11)
    noise = [np.clip(0.5 + 0.05 * rng.standard_normal((256, 256, 3)), 0, 1) for _ in range(8)]
    chance = spectrum.chance_peakness(256)
    assert 3.7 < chance < 3.9
    assert max(spectrum.spectral_peaks(image)[0].strength for image in noise) < chance
    # A plain turned -2.5 degrees seen in reflection only: the transmission is noise.
    rig = CaptureRig(sample_rotation_deg=-2.5)
    params = priors.typical("plain").replace(tiles=(40.0, 40.0))
    with torch.no_grad():
        reflection = Renderer(rig, 256, 8, seed=2).render(params).reflection.numpy()
    spectra = Spectra.of([reflection, noise[0]])
    assert spectra.shows_weave == [True, False]
    weave = spectra.of_the_weave()
    assert len(weave.maps) == len(weave.peaks) == len(weave.highpassed) == 1 and weave.maps[0] is spectra.maps[0]
    found = placement.estimate(spectra, CaptureRig(), priors.FIT_PATTERNS)
    alone = placement.estimate(Spectra.of([reflection]), CaptureRig(), priors.FIT_PATTERNS)
    assert (found.rotation_deg, found.lattice) == (alone.rotation_deg, alone.lattice)
    assert found.rotation_deg == pytest.approx(-2.5, abs=0.25)
    # both photos show a weave, or neither: the spectra stay as they are
    both_weave = Spectra.of([reflection, reflection])
    assert both_weave.of_the_weave() is both_weave
    both_noise = Spectra.of(noise[:2])
    assert both_noise.of_the_weave() is both_noise
