"""What a fit is asked to do and what it returns."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from ..core.params import PARAMETERS, FabricParams
from ..model.photo_light import PhotoLight
from ..model.spacing_warp import SpacingWarp
from ..texture.features import LossWeights

OPTIMISED = tuple(s.name for s in PARAMETERS if s.optimised)
# stage, iteration, total, loss, eta_s; the optimiser adds since_best= and patience= (keywords: the
# steps since its best loss last moved, and the steps without a new best after which it ends)
Progress = Callable[..., None]


class FitCancelled(Exception):
    """Raised from inside the loop when the caller asks to stop; carries the best parameters so far."""

    def __init__(self, params: FabricParams | None):
        super().__init__("cancelled")
        self.params = params


@dataclass(frozen=True)
class FitSettings:
    """What a fit is asked to do. The fit command's options set some of these fields (each option's
    ``setting`` in backend.core.fit_options, through backend.app.folder.fit_settings); the others
    are the library's own tuning, which tests and the developer tools change."""

    pattern: str = "auto"            # a preset name, or "auto" to choose by comparing fits
    iterations: int | None = None    # None: 150 at 256 px, 100 above (backend.fit.search.iterations_for)
    size: int | None = None          # working size of the loss (photos are area-downsampled to it);
                                     # None: chosen from the yarn lattice (backend.fit.search.working_size);
                                     # above 256 px the search still runs at 256 px (coarse to fine)
    spp: int | None = None           # samples per pixel; None: 16 at 256 px, the same samples per image above
    seed: int = 0
    trials: int = 5                  # candidates given a short fit in the search stage
    trial_iterations: int = 20
    duel_iterations: int = 10        # steps at the working size of the winner and of its face twin (a dense weave)
    duel_margin: float = 0.2         # the face twin goes on only where its loss is this much lower after them
    spectrum_weight: float = 1.0     # weight of the spectrum mismatch when choosing between trials
    min_pattern_probability: float = 0.02  # candidates the network rules out get no trial fit
    first_search: int = 25           # the iteration after which the first discrete search runs (each search
                                     # evaluates the loss 20 times: as much as 19 Adam steps at 512 px)
    search_every: int = 25           # iterations from one discrete search to the next (0: no searches)
    max_searches: int = 3            # discrete searches in a run at most (each costs as much at 256 px, 16 spp, as at
                                     # 512 px, 4 spp: the same million samples)
    patience: int = 20               # the optimisation ends after this many steps without a new best loss, once
                                     # a discrete search has had its turn, at the schedule's last learning rate
                                     # (above it, it goes on from its best at that rate; 0: it runs every iteration)
    plateau_window: int = 10         # once no discrete search is left and plateau_window steps have passed since
    plateau_gain: float = 5e-4       # the last, the optimisation ends where its best loss gained less than
                                     # plateau_gain of itself over the last plateau_window steps (0: never;
                                     # backend.fit.pipeline.plateaued)
    gradient_period: int = 4         # the optimisation's steps take their gradients through every gradient_period-th
                                     # block of film rows, a block further on each step (backend.model.render.
                                     # GradientShare; 1: all); the short runs whose ends are compared take all
    lr: float = 0.02                 # Adam step as a fraction of each parameter's range
    weights: LossWeights = LossWeights()
    prior_weight: float = 0.002
    device: str = "cpu"
    compile: bool = False            # torch.compile the renderer (the fit command decides: backend.app.environment)
    vgg_weights: str | None = None   # adds the paper's VGG-19 Gram loss (user-supplied weights)
    gram_weight: float = 1.0
    camera_blur: float | None = None  # film pixels; None: estimated from the photos
    blur_ceiling: bool = False       # an estimated blur at most BLUR_ALLOWANCE_PX above the photos' reading
                                     # (backend.fit.search.blur_range; fit option --blur-ceiling photos)
    sample_rotation: float | None = None  # degrees; None: read from the photos' spectra
    light_falloff: bool = True       # solve each photo's smooth light falloff (backend.model.photo_light)
    subpixel_blur: bool | None = False  # the camera blur of the loss's renders on sub-pixels (True), on the pixel
                                     # means (False), or on sub-pixels only below AUTO_SUBPIXEL_BELOW_PX
                                     # (None; backend.model.render)
    spacing_warp: bool = True        # read the photos' uneven yarn spacing at each discrete search (backend.fit.warp)
    warp_trial_steps: int = 5        # steps a warp read is tried for before it is kept or undone (Run.update_warp)
    estimate_glow: bool = False      # the back light's glow through the gaps read at the first discrete search
                                     # (Run.scan_glow; fit option --glow fit), else the rig's
    estimate_variation: bool = True  # read the yarn variation the photos show after the optimisation
                                     # (backend.fit.variation_estimate)
    settle_steps: int = 10           # steps from the varied parameters where a variation is kept: the
                                     # albedos and thicknesses make up for the means it moves


@dataclass
class FitResult:
    params: FabricParams
    loss: float
    terms: dict[str, float]
    candidates: list[dict]
    history: list[tuple[int, float]]
    timings: dict[str, float] = field(default_factory=dict)
    camera_blur_px: float = 0.0
    sample_rotation_deg: float = 0.0
    sample_skew_deg: float = 0.0
    light: PhotoLight = PhotoLight()  # the photos' light falloff at the best parameters
    size: int = 0                    # the working size, samples per pixel and iterations the fit used
    spp: int = 0
    iterations: int = 0
    steps: int = 0                   # of those iterations, the steps it ran (fewer where it converged)
    warp: SpacingWarp | None = None  # the photos' uneven yarn spacing the renders show (None: even)
    variation: dict | None = None    # the variation reading (VariationEstimate.to_dict; None: not read)
    glow_strength: float = 8.0       # the back light's glow through the gaps the renders show (the rig's unless read)
    camera_blur_range: tuple[float, float] | None = None  # the blurs the fit could estimate (None: fixed)
