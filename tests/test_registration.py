"""Registering a photo pair whose photos were framed differently (the phone moved between the shots)."""
import math

import cv2
import numpy as np
import pytest

from backend.app.report import write_report
from backend.core import priors
from backend.core.rig import DEFAULT_RIG
from backend.image import registration
from backend.image.photos import load_pair
from backend.image.png import write_png
from backend.image.registration import Registration, magnified, register
from backend.model.render import render_pair

PARAMS = priors.typical("twill1").replace(tiles=(30.0, 40.0))


@pytest.fixture(scope="module")
def pair():
    rendered = render_pair(PARAMS, size=512, spp=8, seed=4)
    return rendered.reflection.numpy(), rendered.transmission.numpy()


def turn(degrees: float) -> np.ndarray:
    t = math.radians(degrees)
    return np.array([[math.cos(t), -math.sin(t)], [math.sin(t), math.cos(t)]])


def loaded_moved(folder, pair, zoom: float, degrees: float):
    """The pair loaded with its transmission photo taken with the phone moved (turned and zoomed), and
    that moved photo."""
    reflection, transmission = pair
    moved = np.clip(magnified(transmission, turn(degrees) / zoom), 0, 1)
    write_png(folder / "s_R.png", reflection)
    write_png(folder / "s_T.png", moved)
    return load_pair(folder / "s_R.png", folder / "s_T.png"), moved


def test_a_pair_framed_alike_is_left_alone(pair):
    reflection, transmission = pair
    out_r, out_t, done = register(reflection, transmission, 1.0)
    assert done is None and out_r is reflection and out_t is transmission


@pytest.mark.parametrize("zoom, degrees", [(1.10, 1.0), (1 / 1.08, -1.5)])
def test_the_photo_showing_more_fabric_is_magnified_onto_the_others_framing(tmp_path, pair, zoom, degrees):
    # The transmission photo taken with the phone moved: T'(x) = T(c + M (x - c)), M = turn / zoom,
    # whose lattice is the reflection's seen through M^T. Registration must find A = M^-T and
    # magnify whichever photo shows more fabric, so that both show one lattice again.
    reflection, transmission = pair
    photos, moved = loaded_moved(tmp_path, pair, zoom, degrees)
    info = photos.info["registration"]
    assert info is not None and info["moved"] == ("reflection" if zoom > 1 else "transmission")
    assert info["start"] == "framing check"
    np.testing.assert_allclose(info["matrix"], np.linalg.inv(turn(degrees) / zoom).T, atol=0.004)
    assert info["magnification"] == pytest.approx(max(zoom, 1 / zoom), rel=0.004)
    assert any("framed differently" in w and f"magnified {info['magnification']:.3f}x" in w for w in photos.warnings)
    # One framing again: zoomed in, the transmission photo shows less fabric, and the reflection photo
    # gets the same move; zoomed out, the transmission photo is moved back (two bilinear resamplings).
    if zoom > 1:
        got, want, before = photos.reflection, magnified(reflection, turn(degrees) / zoom), reflection
    else:
        got, want, before = photos.transmission, transmission, moved
    # (A is found to about 0.3 %, which still leaves the yarns a fraction of a pixel apart at the edges,
    # and moved back, the transmission photo has been resampled twice: 0.29 and 0.43 of the error before)
    assert np.abs(got - want).mean() < 0.5 * np.abs(before - want).mean()


@pytest.mark.parametrize("check_scale", [0.69, 1.0])
def test_a_move_the_framing_checks_scale_misses_is_found_from_a_scan_of_starts(pair, check_scale):
    """The framing check can read the ratio of two different harmonics of the lattice (0.69: a satin's
    or a plain weave's two photos show different ones), or none (1.0) for a small move: where its scale
    gives no clear map, the scan of starting magnifications finds the move."""
    reflection, transmission = pair
    zoom, degrees = 1.04, -1.2
    moved = np.clip(magnified(transmission, turn(degrees) / zoom), 0, 1)
    _, _, done = register(reflection, moved, check_scale)
    assert done is not None and done.moved == "reflection" and done.to_dict()["start"] == "scan"
    np.testing.assert_allclose(done.matrix, np.linalg.inv(turn(degrees) / zoom).T, atol=0.004)


def test_a_pair_framed_alike_is_left_alone_whatever_scale_the_check_read(pair):
    reflection, transmission = pair
    for check_scale in (0.69, 0.9, 1.15, 1.5):
        out_r, out_t, done = register(reflection, transmission, check_scale)
        assert done is None and out_r is reflection and out_t is transmission


def test_a_map_only_the_scan_finds_needs_more_peaks_than_one_from_the_checks_scale(pair, monkeypatch):
    """SCANNED_MIN_MATCHES: of the scan's many starts, a map that a few peaks agree with can be chance;
    from the framing check's own scale MIN_MATCHES do."""
    reflection, transmission = pair
    zoom = 1.05
    matrix = zoom * np.eye(2)

    def fitted(*args, matches):
        return matrix, matches, 0.2, 6.0, float(matches)

    for matches in (registration.MIN_MATCHES, registration.SCANNED_MIN_MATCHES - 1, registration.SCANNED_MIN_MATCHES):
        monkeypatch.setattr(registration, "_fitted_map", lambda *a, m=matches: fitted(*a, matches=m))
        from_check = register(reflection, transmission, zoom)[2]
        from_scan = register(reflection, transmission, 0.69)[2]  # no start from a scale past MAX_MAGNIFICATION
        assert from_check is not None and from_check.matches == matches
        assert (from_scan is not None) == (matches >= registration.SCANNED_MIN_MATCHES)


def test_shear_is_zero_for_a_turn_and_a_zoom_and_measures_what_is_left():
    assert registration.shear(1.07 * turn(1.3)) == pytest.approx(0.0, abs=1e-12)
    stretched = turn(0.5) @ np.diag([1.05, 1.02])  # 3 % more along x than along y
    # its nearest similarity is the mean zoom; what is left is +-1.5 % on the two axes
    assert registration.shear(stretched) == pytest.approx(math.hypot(0.015, 0.015) / 1.035, rel=1e-6)


def test_a_map_only_the_scan_finds_must_be_a_turn_and_a_zoom(pair, monkeypatch):
    """SCANNED_MAX_SHEAR: a phone moved between the shots turns and zooms the framing; a map that some
    harmonics agree with by chance can shear it, and from the scan it is refused."""
    reflection, transmission = pair
    limit = registration.SCANNED_MAX_SHEAR
    for shear_part, kept in ((0.5 * limit, True), (2.0 * limit, False)):
        matrix = 1.05 * turn(1.0) @ np.diag([1 + shear_part / math.sqrt(2), 1 - shear_part / math.sqrt(2)])
        monkeypatch.setattr(registration, "_fitted_map", lambda *a, m=matrix: (m, 9, 0.2, 6.0, 9.0))
        assert (register(reflection, transmission, 0.69)[2] is not None) == kept
        assert register(reflection, transmission, 1.05)[2] is not None  # from the check's scale: as before


def test_the_scanned_starts_reach_every_magnification_the_registration_allows():
    """Every magnification in [1 / MAX_MAGNIFICATION, MAX_MAGNIFICATION] lies within half a start step
    (in log) of a scanned start: well inside START_TOLERANCE, the first matching's reach."""
    starts = np.log(registration.scanned_starts())
    span = math.log(registration.MAX_MAGNIFICATION)
    assert starts[0] == pytest.approx(-span) and starts[-1] >= span - registration.START_SCAN_STEP / 2
    assert np.diff(starts).max() <= registration.START_SCAN_STEP + 1e-12
    assert registration.START_SCAN_STEP <= registration.START_TOLERANCE / 2


def test_the_photos_are_loaded_alike_on_any_number_of_threads(tmp_path, pair):
    # load_pair reads the two photos' spectra (weave check, registration) on up to ``workers`` threads:
    # the same photos, warnings and record as on one.
    photos, _ = loaded_moved(tmp_path, pair, 1.10, 1.0)
    threaded = load_pair(tmp_path / "s_R.png", tmp_path / "s_T.png", workers=2)
    assert photos.info["registration"] is not None  # the registration's reading ran
    assert threaded.info == photos.info and threaded.warnings == photos.warnings
    assert np.array_equal(threaded.reflection, photos.reflection)
    assert np.array_equal(threaded.transmission, photos.transmission)


def test_the_report_says_the_photos_were_registered(tmp_path, pair):
    metrics = {"reflection": {"flip": 0.1, "colour_l1": 0.01, "spectrum_corr": 0.5},
               "transmission": {"flip": 0.1, "colour_l1": 0.01, "spectrum_corr": 0.5}}
    registration = {"moved": "reflection", "magnification": 1.148, "turn_deg": 1.09}
    heights, outlined = [], []
    for given in (None, registration):
        compared = None if given is None else ((38, 38, 436, 436), (0, 0, 512, 512))
        path = write_report(tmp_path / f"report_{given is None}.png", pair, pair, metrics, PARAMS, DEFAULT_RIG, 60.0,
                            [], registration=given, compared=compared)
        image = cv2.imread(str(path))
        heights.append(image.shape[0])
        green = (image[..., 1] > 200) & (image[..., 0] < 100) & (image[..., 2] < 100)
        outlined.append(int(green.sum()))
    assert heights[1] > heights[0]  # one more header line
    # the compared part of the reflection outlined on its three panels (4 x 272 px each), not the transmission's
    assert outlined[0] < 50 and 3 * 4 * 250 < outlined[1] - outlined[0] < 3 * 4 * 300


@pytest.mark.parametrize("zoom, degrees", [(1.10, 1.0), (1 / 1.08, -1.5)])
def test_re_renders_are_compared_with_each_photo_as_it_was_taken(tmp_path, pair, zoom, degrees):
    # A perfect fit renders the registered photos; carried back, its re-renders must lie on the photos
    # as taken (not magnified, whose resampling would flatter the comparison), cropped to what the fit saw.
    photos, _ = loaded_moved(tmp_path, pair, zoom, degrees)
    index = 0 if photos.registration.moved == "reflection" else 1
    renders = (photos.reflection, photos.transmission)
    taken, carried = framed = photos.in_own_framing(renders)
    assert taken[index] is photos.taken[index] and carried[1 - index] is renders[1 - index]
    compared = photos.as_compared(framed)
    margin = photos.registration.seen_margin(512)
    assert 0 < margin < 512 * (1 - 1 / max(zoom, 1 / zoom)) / 2 + 512 * math.radians(abs(degrees)) + 2
    np.testing.assert_array_equal(compared[1 - index][0], taken[1 - index])
    photo, render = compared[index]
    assert photo.shape == render.shape == (512 - 2 * margin, 512 - 2 * margin, 3)
    np.testing.assert_array_equal(photo, taken[index][margin:512 - margin, margin:512 - margin])
    inside = np.abs(render - photo).mean()
    # the registered image against the photo as taken: the lattice apart by the move
    apart = np.abs(renders[index][margin:512 - margin, margin:512 - margin] - photo).mean()
    assert inside < 0.35 * apart


@pytest.mark.parametrize("matrix", [[[1.05, 0.02], [-0.03, 0.98]], [[0.9, 0.0], [0.0, 0.93]],
                                    [[1.0, -0.0016], [-0.0226, 1.0]]])  # the last: the dev real satin1's
def test_the_seen_margin_is_the_largest_centred_square_the_registered_image_holds(matrix):
    done = Registration(tuple(map(tuple, matrix)), 6, 0.1, 3.0)
    size = 256
    centre = (size - 1) / 2

    def inside(margin):  # every pixel of the centred square maps into the registered image
        y = np.stack(np.meshgrid(np.arange(margin, size - margin), np.arange(margin, size - margin)), -1) - centre
        x = y.reshape(-1, 2) @ np.linalg.inv(done.photo_map).T
        return bool((np.abs(x) <= centre + 1e-9).all())

    margin = done.seen_margin(size)
    assert inside(margin) and (margin == 0 or not inside(margin - 1))
