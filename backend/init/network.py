"""The initialisation network: a photo pair's weight-free features -> first fabric parameters.

The paper starts its optimisation from a network prediction (spec section 5, item 2): VGG-19 Gram
matrices of both photos into three fully connected layers. Pretrained VGG weights cannot be had
offline, so the network reads the project's own weight-free texture statistics instead
(:mod:`backend.texture.features`), taken *at a candidate lattice*: the fit proposes one (pattern, tiles)
candidate per weave preset from the photos' spectra (:func:`backend.texture.candidates.propose`), and for each
candidate the network sees

- ``harmonics``: log(m + 0.05), m the *noise-debiased* magnitude of the regional Fourier
  coefficients at that lattice's harmonics (:class:`backend.texture.features.LatticeProbe`: 3 x 3 regions x
  40 harmonics x RGB, relative to the region's mean, so they describe the texture's shape, not its
  tone; phase-invariant). :func:`debiased_magnitude` removes the power pixel noise adds, measured at
  off-lattice frequencies: the training renders have 16 samples per pixel, photos and the golden
  renders far less noise, and without it the network read clean images as thinner fabrics;
- ``colour``: the 8 x 8 area downsample (linear-light average, display encoded): tone, colour and
  the lighting gradient across the image;
- ``quantiles``: 24 luminance quantiles of the 2 x 2-pooled image (display encoded): the
  highlight distribution, pooled so that pixel noise does not widen it;

of the reflection and of the transmission photo, both at the fit's working size (256, after
:func:`backend.model.imaging.downsample_linear`), plus the candidate's pattern (one-hot) and its tiles
relative to the pattern's base density (log): 2,599 numbers (:data:`FEATURE_DIM`), stored by the
dataset. The network's input (:func:`network_input`) averages the harmonics over RGB: 1,159 numbers.

The network (:class:`InitNet`) standardises them (mean and spread of the training set, kept in the
weights file), runs three fully connected layers of 256 with LeakyReLU(0.2) (the paper's head) and
gives 27 outputs: the continuous parameters of :data:`TARGETS` as sigmoids over their declared
ranges (:data:`backend.core.params.PARAMETERS`), and a plausibility logit that this candidate's pattern is
the photos' weave (a softmax over the candidates of one pair gives the pattern probabilities).
Tiles come from the candidate (the lattice pins them far better than a network could), twist from
the pattern's prior, noise is 0.

Weights: ``backend/data/init_net.pt`` (about 2 MB), a plain dict ``{"header": JSON text,
"state_dict": tensors}`` read with ``torch.load(..., weights_only=True)``; the header carries the
feature version and sizes, so a file that does not match this code is refused rather than misread.
``python -m devtools train`` reproduces it from ``python -m devtools dataset`` (:mod:`devtools.train`,
:mod:`devtools.dataset`).

Use in the fit: :class:`NetworkStart` is the ``initial_for`` hook of :func:`backend.fit.pipeline.fit`, and its
``pattern_probabilities`` the fit's ``pattern_probabilities`` hook: candidates the network gives
less than ``FitSettings.min_pattern_probability`` get no trial fit. The network knows the paper's five
weaves; a candidate of a mirrored preset (``twill0m``, ...) is read as the preset it mirrors in the
photos mirrored left-right, under the mirrored rig (:meth:`NetworkStart._view`).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from ..core import priors
from ..core.params import SPECS, FabricParams, unflatten
from ..core.rig import CaptureRig
from ..core.weave import is_mirrored, paper_preset
from ..model.imaging import downsample_linear
from ..texture.features import LatticeProbe, luminance_quantiles
from ..texture.frequencies import lattice_of

FEATURE_VERSION = 2
WORK_SIZE = 256          # the fit's working size: features are read where the fit compares
HARMONIC_EPS = 0.05      # modulation depth below which a harmonic is mostly Monte Carlo/camera noise
COLOUR_GRID = 8
QUANTILE_POOL = 2        # quantiles of the 2 x 2 (linear) pooled image: less sensitive to pixel noise
PATTERNS = priors.PATTERNS
DEFAULT_WEIGHTS = Path(__file__).resolve().parents[1] / "data" / "init_net.pt"

# The continuous parameters the network predicts (tiles come from the lattice, twist from the prior).
TARGETS = ("roughness", "thickness", "roughness_multiple", "thickness_multiple", "height_scale", "gap_scale",
           "specular_albedo", "multiple_weight", "diffuse_reflection", "diffuse_transmission",
           "diffuse_normal_weight")
TARGET_SIZE = sum(SPECS[name].size for name in TARGETS)


class InitNetError(RuntimeError):
    """The weights file is missing, unreadable or does not match this code."""


# -- targets ---------------------------------------------------------------------------------------
def target_vector(params: FabricParams) -> np.ndarray:
    """The predicted parameters of ``params``, each scaled to [0, 1] by its declared range."""
    out = []
    for name in TARGETS:
        spec = SPECS[name]
        out += [(x - spec.lo) / (spec.hi - spec.lo) for x in params.flat(name)]
    return np.asarray(out, dtype=np.float32)


def params_from_vector(vector: Sequence[float], pattern: str, tiles: tuple[float, float]) -> FabricParams:
    """Parameters from a [0, 1] target vector, the candidate's pattern and tiles, the prior's twist."""
    values, k = {}, 0
    for name in TARGETS:
        spec = SPECS[name]
        flat = [spec.lo + float(v) * (spec.hi - spec.lo) for v in vector[k:k + spec.size]]
        values[name] = unflatten(spec, flat)
        k += spec.size
    twist = priors.typical(pattern).twist_deg
    return FabricParams.clamped_from(pattern=pattern, tiles=tiles, twist_deg=twist, noise=0.0, **values)


# -- features --------------------------------------------------------------------------------------
@dataclass
class WorkingPair:
    """A photo pair at the working size, display space, (WORK_SIZE, WORK_SIZE, 3) float32 tensors."""

    reflection: torch.Tensor
    transmission: torch.Tensor

    @classmethod
    def from_images(cls, reflection, transmission, gamma: float = 2.2) -> "WorkingPair":
        def prep(image):
            tensor = torch.as_tensor(np.asarray(image) if not isinstance(image, torch.Tensor) else image)
            return downsample_linear(tensor.detach().to(torch.float32).cpu(), WORK_SIZE, gamma)

        return cls(prep(reflection), prep(transmission))


def debiased_magnitude(magnitude: torch.Tensor, floor: torch.Tensor) -> torch.Tensor:
    """sqrt(max(|c|^2 - sigma^2, 0)): a harmonic's magnitude without the power that pixel noise adds.

    Noise adds sigma^2 to the expected power of every coefficient; ``floor`` is the median magnitude
    at off-lattice frequencies, and the median of a noise-only (Rayleigh) magnitude is
    sigma sqrt(ln 2). Without this, a 16-sample render's weak harmonics read stronger than the same
    fabric's in a clean photo, and the network learns that bias.
    """
    noise_power = floor.square() / math.log(2.0)
    return (magnitude.square() - noise_power).clamp_min(0.0).sqrt()


def _image_features(image: torch.Tensor, probe: LatticeProbe, gamma: float) -> list[torch.Tensor]:
    coefficients, floor = probe(image.clamp_min(0).pow(gamma))
    harmonics = torch.log(debiased_magnitude(coefficients.abs(), floor) + HARMONIC_EPS)
    linear = image.clamp_min(0).pow(gamma).permute(2, 0, 1)[None]
    colour = F.adaptive_avg_pool2d(linear, COLOUR_GRID)[0].clamp_min(1e-8).pow(1 / gamma)
    pooled = F.avg_pool2d(linear, QUANTILE_POOL)[0].permute(1, 2, 0)
    return [harmonics.flatten(), colour.flatten(), luminance_quantiles(pooled).clamp_min(0).pow(1 / gamma)]


def candidate_features(pair: WorkingPair, pattern: str, tiles: Sequence[float], rig: CaptureRig) -> torch.Tensor:
    """The network input (FEATURE_DIM,) for one (pattern, tiles) candidate of a working pair."""
    with torch.no_grad():
        a, b = lattice_of(tiles, rig)
        probe = LatticeProbe(WORK_SIZE, a, b, rotation_deg=rig.sample_rotation_deg, skew_deg=rig.sample_skew_deg)
        parts = [f for image in (pair.reflection, pair.transmission) for f in _image_features(image, probe, rig.gamma)]
        one_hot = torch.zeros(len(PATTERNS))
        one_hot[PATTERNS.index(pattern)] = 1.0
        base = priors.BASE_TILES[pattern]
        density = torch.tensor([math.log(tiles[0] / base[0]), math.log(tiles[1] / base[1])])
        return torch.cat(parts + [one_hot, density]).to(torch.float32)


HARMONIC_COUNT = len(LatticeProbe(8, 1.0, 1.0).harmonics)
HARMONIC_DIM = 9 * HARMONIC_COUNT * 3                 # per image: regions x harmonics x RGB
IMAGE_DIM = HARMONIC_DIM + 3 * COLOUR_GRID ** 2 + 24  # harmonics, colours, quantiles
FEATURE_DIM = 2 * IMAGE_DIM + len(PATTERNS) + 2
INPUT_DIM = FEATURE_DIM - 2 * HARMONIC_DIM * 2 // 3    # after averaging the harmonics over RGB


def network_input(features: torch.Tensor) -> torch.Tensor:
    """(..., FEATURE_DIM) -> (..., INPUT_DIM): harmonic log-magnitudes averaged over RGB.

    At the working size the weave's harmonics fold past Nyquist and are attenuated by the pixel, so
    per channel they are noisy; their mean over RGB keeps the texture's shape with a third of the
    inputs, and the network validates better on it than on every channel or on no harmonics.
    """
    parts = []
    for image in range(2):
        start = image * IMAGE_DIM
        harmonics = features[..., start:start + HARMONIC_DIM].reshape(*features.shape[:-1], -1, 3)
        parts += [harmonics.mean(-1), features[..., start + HARMONIC_DIM:start + IMAGE_DIM]]
    parts.append(features[..., 2 * IMAGE_DIM:])
    return torch.cat(parts, -1)


# -- the network -----------------------------------------------------------------------------------
class InitNet(nn.Module):
    """Standardised features -> 3 x (Linear 256, LeakyReLU 0.2) -> TARGET_SIZE sigmoids + 1 logit."""

    def __init__(self, in_dim: int = INPUT_DIM, hidden: int = 256, dropout: float = 0.1):
        super().__init__()
        self.register_buffer("mean", torch.zeros(in_dim))
        self.register_buffer("scale", torch.ones(in_dim))
        self.trunk = nn.Sequential(
            nn.Linear(in_dim, hidden), nn.LeakyReLU(0.2), nn.Dropout(dropout),
            nn.Linear(hidden, hidden), nn.LeakyReLU(0.2), nn.Dropout(dropout),
            nn.Linear(hidden, hidden), nn.LeakyReLU(0.2))
        self.head = nn.Linear(hidden, TARGET_SIZE + 1)

    def set_normalisation(self, features: torch.Tensor) -> None:
        """Standardise inputs by the training set's mean and spread (constant inputs keep scale 1);
        ``features`` (n, FEATURE_DIM)."""
        features = network_input(features)
        self.mean.copy_(features.mean(0))
        spread = features.std(0)
        self.scale.copy_(torch.where(spread > 1e-6, spread, torch.ones_like(spread)))

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Features (..., FEATURE_DIM) -> (targets in [0, 1] (..., TARGET_SIZE), plausibility logits (...,))."""
        out = self.head(self.trunk((network_input(features) - self.mean) / self.scale))
        return torch.sigmoid(out[..., :TARGET_SIZE]), out[..., TARGET_SIZE]


def header(hidden: int, **extra) -> dict:
    """The JSON header saved beside the weights: what the features and outputs mean."""
    return {"feature_version": FEATURE_VERSION, "work_size": WORK_SIZE, "harmonic_eps": HARMONIC_EPS,
            "colour_grid": COLOUR_GRID, "quantile_pool": QUANTILE_POOL, "feature_dim": FEATURE_DIM,
            "input_dim": INPUT_DIM, "patterns": list(PATTERNS),
            "targets": list(TARGETS), "target_size": TARGET_SIZE, "hidden": hidden, **extra}


def save(net: InitNet, path: str | Path, info: dict) -> Path:
    """Writes the plain state dict and header (loadable with weights_only=True)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    hidden = net.head.in_features
    state = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save({"header": json.dumps(header(hidden, **info)), "state_dict": state}, tmp)
    tmp.replace(path)
    return path


class InitModel:
    """A loaded network and its header; predictions for candidates of a photo pair."""

    def __init__(self, net: InitNet, info: dict):
        self.net, self.info = net.eval(), info

    @classmethod
    def load(cls, path: str | Path = DEFAULT_WEIGHTS) -> "InitModel":
        path = Path(path)
        if not path.is_file():
            raise InitNetError(f"{path}: the initialisation network's weights are missing")
        try:
            blob = torch.load(path, map_location="cpu", weights_only=True)
            info = json.loads(blob["header"])
            state = blob["state_dict"]
        except Exception as exc:  # a truncated or foreign file: say which, the caller falls back
            raise InitNetError(f"{path}: cannot read the weights ({type(exc).__name__}: {exc})") from None
        expected = header(info.get("hidden", 0))
        for key in ("feature_version", "work_size", "harmonic_eps", "colour_grid", "quantile_pool", "feature_dim",
                    "input_dim", "patterns", "targets"):
            if info.get(key) != expected[key]:
                raise InitNetError(f"{path}: made for {key} = {info.get(key)!r}, this code uses {expected[key]!r}")
        net = InitNet(INPUT_DIM, hidden=int(info["hidden"]))
        try:
            net.load_state_dict(state)
        except RuntimeError as exc:
            raise InitNetError(f"{path}: weights do not fit the network ({exc})") from None
        return cls(net, info)

    def predict(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        with torch.no_grad():
            return self.net(features)

    def guess(self, pair: WorkingPair, pattern: str, tiles: Sequence[float], rig: CaptureRig) -> FabricParams:
        targets, _ = self.predict(candidate_features(pair, pattern, tiles, rig)[None])
        return params_from_vector(targets[0].tolist(), pattern, tuple(tiles))


@lru_cache(maxsize=2)
def load_model(path: str = str(DEFAULT_WEIGHTS)) -> InitModel:
    """The model of a weights file, loaded once per process."""
    return InitModel.load(path)


class NetworkStart:
    """The network's starts for one photo pair: the fit's ``initial_for`` hook (candidate -> guess)
    and its ``pattern_probabilities`` hook (candidates -> softmax of their plausibility logits)."""

    def __init__(self, reflection, transmission, rig: CaptureRig, model: InitModel | None = None):
        self.model = model or load_model()
        self.rig = rig
        self.pair = WorkingPair.from_images(reflection, transmission, rig.gamma)
        self._mirrored: tuple[WorkingPair, CaptureRig] | None = None

    def _view(self, pattern: str) -> tuple[WorkingPair, CaptureRig, str] | None:
        """(photos, rig, pattern) as the network sees a candidate of ``pattern``: a paper preset as it
        is; a mirrored one (:data:`backend.core.weave.MIRRORED_OF`) as the preset it mirrors in the
        photos mirrored left-right, under the mirrored rig (the network was trained on the paper's
        five); None for a weave the network does not know."""
        if pattern in PATTERNS:
            return self.pair, self.rig, pattern
        if not is_mirrored(pattern):
            return None
        if self._mirrored is None:
            self._mirrored = (WorkingPair(self.pair.reflection.flip(1), self.pair.transmission.flip(1)),
                              self.rig.mirrored())
        return (*self._mirrored, paper_preset(pattern))

    def __call__(self, candidate) -> FabricParams | None:
        """Custom weaves (not one of the presets the network knows) get None (the fit's prior start)."""
        view = self._view(candidate.pattern)
        if view is None:
            return None
        pair, rig, pattern = view
        guess = self.model.guess(pair, pattern, candidate.tiles, rig)
        return guess.replace(pattern=candidate.pattern)

    def pattern_probabilities(self, candidates: Sequence) -> list[float] | None:
        """One probability per candidate (a softmax over their plausibility logits); None when a
        candidate is not a preset (no opinion)."""
        views = [self._view(c.pattern) for c in candidates]
        if not candidates or any(v is None for v in views):
            return None
        features = torch.stack([candidate_features(pair, pattern, c.tiles, rig)
                                for c, (pair, rig, pattern) in zip(candidates, views)])
        _, logits = self.model.predict(features)
        return torch.softmax(logits, 0).tolist()


INIT_CHOICES = ("network", "prior")


def fit_initialiser(mode: str, reflection, transmission, rig: CaptureRig, warn: Callable[[str], None],
                    path: str | Path = DEFAULT_WEIGHTS) -> NetworkStart | None:
    """The ``initial_for`` hook for ``fit --init MODE``: the network's, or None (the prior's start).

    With ``network``, weights that are missing or do not load give a warning through ``warn`` and
    the prior's start: a fit must never fail for want of its initialisation.
    """
    if mode == "prior":
        return None
    if mode != "network":
        raise ValueError(f"--init: expected one of {', '.join(INIT_CHOICES)}, got {mode!r}")
    try:
        model = load_model(str(path))
    except InitNetError as exc:
        warn(f"{exc}; starting from the prior instead (--init prior)")
        return None
    return NetworkStart(reflection, transmission, rig, model)
