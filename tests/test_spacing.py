"""The mean yarn spacing read from the phase of the lattice harmonics (backend/texture/spacing.py)."""
import math

import numpy as np
import pytest

from backend.image.spectrum import highpassed_luminance
from backend.texture import spacing
from backend.texture.lattice import Lattice, Signature, turned_frequencies

SIZE = 512
LATTICE = (40.0, 55.0)      # cycles per image across the warps and the wefts
TURN = 3.0                  # degrees
HARMONICS = Signature(m=np.array([1, 0, 1]), n=np.array([0, 1, 1]), weight=np.array([0.4, 0.4, 0.2]))


def woven(a: float, b: float, rotation_deg: float = TURN, change: float = 0.0, glow: float = 0.0,
          harmonics: Signature = HARMONICS, skew_deg: float = 0.0, centre_gain: float = 0.0) -> np.ndarray:
    """A grey (SIZE, SIZE, 3) image of the harmonics of the lattice (a, b), its yarns spaced unevenly
    across the image: x is displaced by d(x) = A sin(2 pi x / SIZE), one whole period, so the mean
    spacing is the lattice's, while the local frequency is 1 + ``change`` times it at the centre;
    plus a narrow bright ``glow`` at the centre (a transmission photo's light). The sample is turned by
    ``rotation_deg`` and sheared by ``skew_deg``. With a ``centre_gain`` g the harmonics are 1 + g
    times as strong at the centre as at the edges (a Gaussian of 60 px: the gaps a lamp lights)."""
    amplitude = -change * SIZE / (2 * math.pi)            # d'(SIZE / 2) = change
    centres = np.arange(SIZE) + 0.5
    y, x = np.meshgrid(centres, centres, indexing="ij")
    x = x + amplitude * np.sin(2 * math.pi * x / SIZE)
    image = np.full((SIZE, SIZE), 0.5)
    r2 = (y - SIZE / 2) ** 2 + (x - SIZE / 2) ** 2
    strength = (1 + centre_gain * np.exp(-r2 / (2 * 60.0 ** 2))) / (1 + centre_gain)
    for m, n, w in zip(harmonics.m, harmonics.n, harmonics.weight):
        fx, fy = turned_frequencies(m * a, n * b, rotation_deg, skew_deg)
        image += 0.25 * w * strength * np.cos(2 * math.pi * (fx * x + fy * y) / SIZE + 0.7 * m + 0.3 * n)
    image += glow * np.exp(-r2 / (2 * 12.0 ** 2))
    return np.repeat(image[..., None], 3, axis=-1)


def highpassed(image: np.ndarray) -> np.ndarray:
    """What the lattice search keeps of a photo for the mean spacing (``Spectra.highpassed``)."""
    return highpassed_luminance(image, SIZE / 64)


def test_the_whole_photo_gives_the_mean_spacing_where_its_centre_is_off():
    # The yarns are 2.5 % denser at the centre than on average: a start read there (as the windowed
    # spectrum reads) moves to the mean, on both axes of a turned sample.
    photo = highpassed(woven(*LATTICE, change=0.025))
    start = Lattice(LATTICE[0] * 1.025, LATTICE[1] * 0.985, 7.0)
    found = spacing.mean_lattice(photo, photo, start, (HARMONICS, HARMONICS), TURN).lattice
    assert (found.a, found.b) == pytest.approx(LATTICE, rel=0.002)
    assert found.score == 7.0


def test_a_harmonic_strongest_at_the_centre_still_gives_the_mean_spacing():
    # The lamp lights the gaps at the centre of a transmission photo: there the harmonics are five
    # times as strong as at the edges, and the yarns 2.5 % denser than on average. Weighted by the
    # harmonics' power, the phase steps would read the centre's spacing (1.2 % off here).
    photo = highpassed(woven(*LATTICE, change=0.025, centre_gain=4.0))
    start = Lattice(LATTICE[0] * 1.025, LATTICE[1], 1.0)
    found = spacing.mean_lattice(photo, photo, start, (HARMONICS, HARMONICS), TURN).lattice
    assert (found.a, found.b) == pytest.approx(LATTICE, rel=0.003)


def test_an_even_lattice_stays_where_it_is():
    photo = highpassed(woven(*LATTICE))
    found = spacing.mean_lattice(photo, photo, Lattice(*LATTICE, 1.0), (HARMONICS, HARMONICS), TURN).lattice
    assert (found.a, found.b) == pytest.approx(LATTICE, rel=2e-4)


def test_the_light_near_a_low_harmonic_is_kept_out():
    # A coarse lattice whose strongest harmonic (0, 1) lies 16 cycles per image from DC, beside a
    # bright glow: the glow's power below the high-pass would pull that harmonic's phase (read as
    # -10 % on a photo-like satin before the light counted as a neighbour).
    coarse = (33.0, 16.0)
    strong_low = Signature(m=np.array([0, 1, 1]), n=np.array([1, 0, 1]), weight=np.array([0.6, 0.2, 0.2]))
    photo = highpassed(woven(*coarse, glow=0.4, harmonics=strong_low))
    found = spacing.mean_lattice(photo, photo, Lattice(*coarse, 1.0), (strong_low, strong_low), TURN).lattice
    assert (found.a, found.b) == pytest.approx(coarse, rel=0.003)


def test_the_reflection_stands_in_where_the_transmission_shows_no_lattice():
    reflection, blank = highpassed(woven(*LATTICE, change=0.025)), highpassed(np.full((SIZE, SIZE, 3), 0.4))
    start = Lattice(LATTICE[0] * 1.025, LATTICE[1], 1.0)
    read = spacing.mean_lattice(blank, reflection, start, (HARMONICS, HARMONICS), TURN)
    from_reflection = read.lattice
    assert (from_reflection.a, from_reflection.b) == pytest.approx(LATTICE, rel=0.002)
    assert not read.from_transmission
    # and the transmission is what is read when it shows the lattice
    other = highpassed(woven(LATTICE[0] * 1.01, LATTICE[1] * 1.01))
    read = spacing.mean_lattice(other, reflection, start, (HARMONICS, HARMONICS), TURN)
    from_transmission = read.lattice
    assert read.from_transmission
    assert (from_transmission.a, from_transmission.b) == pytest.approx((LATTICE[0] * 1.01, LATTICE[1] * 1.01),
                                                                       rel=0.002)


def test_a_placement_read_a_little_off_does_not_leak_one_axis_into_the_other():
    # The sample is turned 3 degrees; the placement says 2.2. Read at the angles as given, the
    # strong diagonal harmonic (1, 1) would mix b's frequency into a's; the yarn vectors' lengths do not.
    diagonal = Signature(m=np.array([1, 0, 1]), n=np.array([0, 1, 1]), weight=np.array([0.2, 0.2, 0.6]))
    photo = highpassed(woven(*LATTICE, change=0.025, harmonics=diagonal))
    start = Lattice(LATTICE[0] * 1.02, LATTICE[1] * 1.01, 1.0)
    found = spacing.mean_lattice(photo, photo, start, (diagonal, diagonal), TURN - 0.8).lattice
    assert (found.a, found.b) == pytest.approx(LATTICE, rel=0.002)


@pytest.mark.parametrize("truth, given", [((TURN, 0.0), (TURN - 0.8, 0.0)),     # a turn read 0.8 degrees off
                                          ((-1.5, 2.0), (-0.9, 2.0))])         # a shear's turn 0.6 off
def test_the_yarn_vectors_show_the_placement_where_it_was_read_off(truth, given):
    # The directions of the solved yarn vectors are the yarns' angles over the whole photo, uneven
    # spacing and all; the candidates' consensus of them moves the placement (candidates.yarn_turn).
    photo = highpassed(woven(*LATTICE, rotation_deg=truth[0], skew_deg=truth[1], change=0.025))
    start = Lattice(LATTICE[0] * 1.02, LATTICE[1] * 1.01, 1.0)
    read = spacing.mean_lattice(photo, photo, start, (HARMONICS, HARMONICS), *given)
    assert read.placement == pytest.approx(truth, abs=0.03)
    assert read.from_transmission
    # and nothing is read where the harmonics do not pin both vectors
    lone = Signature(m=np.array([1]), n=np.array([0]), weight=np.array([1.0]))
    assert spacing.mean_lattice(photo, photo, start, (lone, lone), *given).placement is None
