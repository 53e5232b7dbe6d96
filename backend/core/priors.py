"""The paper's dataset priors per weave pattern (spec section 5, item 4), and the fit's priors.

Sampling (``sample``) draws a parameter set as the paper's training data does; ``typical`` gives
the centre of each distribution (the starting point of a fit without the network). Per pattern
(warp, weft):

- tiles: plain (173, 173), twill0 (122, 80), twill1 (80, 122), satin0 (80, 160), satin1 (160, 80),
  times a common scale (twill U(0.7, 1.8), satin U(0.7, 1.5), plain U(0.7, 1.3)) and a per-axis
  U(0.9, 1.1) (plain: tv = tu);
- twill: T U(1, 4), beta U(1, 2), alpha U(0.7, 1)^2, xi U(0.85, 0.95);
- plain: T U(0.5, 3), beta U(0.2, 2), alpha U(0.1, 0.7)^2, xi U(0.6, 0.9), warp = weft;
- satin0: T warp U(2, 4), weft U(0.5, 2); beta U(0.2, 1); alpha warp U(0.7, 1)^2, weft
  U(0.2, 0.7)^2; xi U(0.85, 0.95); satin1 and twill0 swap warp and weft values;
- alpha_m = alpha U(0.5, 1.5); T_m = T U(0.5, 1.5); w U(0, 1); w_m U(0.01, 2); colours uniform,
  k_s = k_d_yarn ^ U(0, 1) with a random per-yarn colour k_d_yarn;
- twist -30 degrees for twills, 0 otherwise; noise 0.

The fit's Gaussian priors (spec section 5, item 3): height_scale (mu, s) plain (1, 1), twill (1, 0.5),
satin (0.1, 0.5); gap_scale plain (0.75, 0.1), twill and satin (0.9, 0.05). Beyond the spec, the
multiple-scattering roughness keeps to the dataset's ratio of the single-scattering one
(:data:`MULTIPLE_ROUGHNESS_RATIO`): a half-Gaussian on log(alpha_m / alpha) outside it.

A mirrored preset (``twill0m``, ... :data:`backend.core.weave.MIRRORED_OF`) has every prior of the
preset it mirrors.
"""
from __future__ import annotations

import math
import random

from . import variation
from .params import PARAMETERS, SPECS, FabricParams
from .weave import MIRRORED_OF, paper_preset

BASE_TILES = {"plain": (173.0, 173.0), "twill0": (122.0, 80.0), "twill1": (80.0, 122.0),
              "satin0": (80.0, 160.0), "satin1": (160.0, 80.0)}
TILE_SCALE = {"plain": (0.7, 1.3), "twill": (0.7, 1.8), "satin": (0.7, 1.5)}
HEIGHT_PRIOR = {"plain": (1.0, 1.0), "twill": (1.0, 0.5), "satin": (0.1, 0.5)}
GAP_PRIOR = {"plain": (0.75, 0.1), "twill": (0.9, 0.05), "satin": (0.9, 0.05)}
MULTIPLE_ROUGHNESS_RATIO = (0.5, 1.5)  # alpha_m / alpha: the dataset draws it uniformly from this range (``sample``)
MULTIPLE_ROUGHNESS_SPREAD = 0.25       # s of the half-Gaussian on log(alpha_m / alpha) beyond that range


def family(pattern: str) -> str:
    """plain, twill or satin (custom weaves are treated as twills)."""
    for name in ("plain", "twill", "satin"):
        if pattern.startswith(name):
            return name
    return "twill"


def swapped(pattern: str) -> bool:
    """Patterns whose warp and weft prior values are swapped relative to satin0/twill1."""
    return paper_preset(pattern) in ("satin1", "twill0")


def tile_range(pattern: str, margin: float = 1.15) -> tuple[tuple[float, float], tuple[float, float]]:
    """(tu range, tv range) the prior can produce, widened by ``margin`` on both sides."""
    lo, hi = TILE_SCALE[family(pattern)]
    tu, tv = BASE_TILES.get(paper_preset(pattern), (120.0, 120.0))
    return ((tu * lo * 0.9 / margin, tu * hi * 1.1 * margin), (tv * lo * 0.9 / margin, tv * hi * 1.1 * margin))


def _yarn_ranges(pattern: str) -> dict:
    fam = family(pattern)
    if fam == "plain":
        ranges = {"thickness": ((0.5, 3.0),) * 2, "height_scale": ((0.2, 2.0),) * 2,
                  "sqrt_roughness": ((0.1, 0.7),) * 2, "gap_scale": ((0.6, 0.9),) * 2}
    elif fam == "twill":
        ranges = {"thickness": ((1.0, 4.0),) * 2, "height_scale": ((1.0, 2.0),) * 2,
                  "sqrt_roughness": ((0.7, 1.0),) * 2, "gap_scale": ((0.85, 0.95),) * 2}
    else:
        ranges = {"thickness": ((2.0, 4.0), (0.5, 2.0)), "height_scale": ((0.2, 1.0),) * 2,
                  "sqrt_roughness": ((0.7, 1.0), (0.2, 0.7)), "gap_scale": ((0.85, 0.95),) * 2}
    if swapped(pattern):
        ranges = {k: (v[1], v[0]) for k, v in ranges.items()}
    return ranges


def sample(pattern: str, rng: random.Random) -> FabricParams:
    """One parameter set drawn from the dataset prior of ``pattern``."""
    fam = family(pattern)
    ranges = _yarn_ranges(pattern)
    same = fam == "plain"

    def pair(key, transform=lambda x: x):
        first = transform(rng.uniform(*ranges[key][0]))
        return (first, first) if same else (first, transform(rng.uniform(*ranges[key][1])))

    roughness = pair("sqrt_roughness", lambda x: x * x)
    thickness = pair("thickness")
    base = BASE_TILES[paper_preset(pattern)]
    scale = rng.uniform(*TILE_SCALE[fam])
    tu = base[0] * scale * rng.uniform(0.9, 1.1)
    tv = tu if same else base[1] * scale * rng.uniform(0.9, 1.1)
    yarn_colour = [[rng.random() for _ in range(3)] for _ in range(2)]
    if same:
        yarn_colour[1] = yarn_colour[0]
    exponent = rng.random()
    specular = tuple(tuple(c ** exponent for c in yarn) for yarn in yarn_colour)
    twist = -30.0 if fam == "twill" else 0.0
    return FabricParams.clamped_from(
        pattern=pattern, tiles=(tu, tv), roughness=roughness, thickness=thickness,
        roughness_multiple=tuple(r * rng.uniform(*MULTIPLE_ROUGHNESS_RATIO) for r in roughness),
        thickness_multiple=tuple(t * rng.uniform(0.5, 1.5) for t in thickness),
        height_scale=pair("height_scale"), gap_scale=pair("gap_scale"), twist_deg=(twist, twist),
        specular_albedo=specular, multiple_weight=rng.uniform(0.01, 2.0),
        diffuse_reflection=tuple(rng.random() for _ in range(3)),
        diffuse_transmission=tuple(rng.random() for _ in range(3)),
        diffuse_normal_weight=rng.random(), noise=0.0)


def sample_variation(rng: random.Random) -> dict[str, tuple[float, float]]:
    """Yarn variation drawn from the declared priors (each ParamSpec's ``prior``, uniform), warp and
    weft apart: ``{name: (warp, weft)}`` for every amplitude and correlation length."""
    return {spec.name: _declared_draw(spec, rng) for spec in PARAMETERS if spec.name in variation.PARAMETER_NAMES}


def sample_forward(rng: random.Random) -> dict[str, tuple[float, float]]:
    """The forward scattering drawn from its declared prior (uniform), warp and weft apart."""
    return {"forward_scattering": _declared_draw(SPECS["forward_scattering"], rng)}


def _declared_draw(spec, rng: random.Random) -> tuple[float, float]:
    """(warp, weft), each uniform in the ParamSpec's ``prior``."""
    return rng.uniform(*spec.prior), rng.uniform(*spec.prior)


def typical(pattern: str) -> FabricParams:
    """The centre of the prior of ``pattern`` (mid-grey colours)."""
    ranges = _yarn_ranges(pattern)

    def centre(key, transform=lambda x: x):
        return tuple(transform(sum(r) / 2) for r in ranges[key])

    roughness = centre("sqrt_roughness", lambda x: x * x)
    thickness = centre("thickness")
    fam = family(pattern)
    scale = sum(TILE_SCALE[fam]) / 2
    base = BASE_TILES[paper_preset(pattern)]
    twist = -30.0 if fam == "twill" else 0.0
    return FabricParams(
        pattern=pattern, tiles=(base[0] * scale, base[1] * scale), roughness=roughness, thickness=thickness,
        roughness_multiple=roughness, thickness_multiple=thickness, height_scale=centre("height_scale"),
        gap_scale=centre("gap_scale"), twist_deg=(twist, twist), specular_albedo=((0.5,) * 3, (0.5,) * 3),
        multiple_weight=1.0, diffuse_reflection=(0.3,) * 3, diffuse_transmission=(0.3,) * 3,
        diffuse_normal_weight=0.5, noise=0.0)


def prior_nll(pattern: str, height_scale, gap_scale, roughness, roughness_multiple):
    """The fit's prior (tensors of warp/weft values): the mean over warp/weft of

        (x - mu)^2 / (2 s^2)                                   for height and gap scale,
        (distance of log(alpha_m / alpha) from log(MULTIPLE_ROUGHNESS_RATIO))^2 / (2 s^2)
                                                               with s = MULTIPLE_ROUGHNESS_SPREAD.

    The ratio term is 0 over the dataset's range. Without it a fit of a real photo can drive one
    yarn's multiple-scattering lobe to its lower bound under a rough single-scattering one: a
    razor-thin lobe that draws a streak across the back-lit render, through the light, that the
    photo does not have."""
    fam = family(pattern)
    (mh, sh), (mg, sg) = HEIGHT_PRIOR[fam], GAP_PRIOR[fam]
    lo, hi = (math.log(r) for r in MULTIPLE_ROUGHNESS_RATIO)
    log_ratio = roughness_multiple.log() - roughness.log()
    outside = (lo - log_ratio).clamp_min(0) + (log_ratio - hi).clamp_min(0)
    return (((height_scale - mh) ** 2).mean() / (2 * sh * sh) + ((gap_scale - mg) ** 2).mean() / (2 * sg * sg)
            + (outside ** 2).mean() / (2 * MULTIPLE_ROUGHNESS_SPREAD ** 2))


PATTERNS = tuple(BASE_TILES)
"""The paper's five patterns: those of its dataset and of the initialisation network."""
FIT_PATTERNS = PATTERNS + tuple(MIRRORED_OF)
"""The patterns a fit chooses among: the paper's five and their mirror images, each mirrored
pattern with the priors of the one it mirrors (a mirror changes no yarn's shape or density)."""
