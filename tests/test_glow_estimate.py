"""The back light's glow through the gaps, read from the photos (backend.fit.optimise.Run.scan_glow)
and carried by the renderer (backend.model.render.Renderer.set_glow)."""
import dataclasses

import pytest
import torch

from backend.core.params import FabricParams
from backend.core.rig import DEFAULT_RIG
from backend.fit.optimise import GLOW_SCAN, Run
from backend.fit.pipeline import _objective
from backend.fit.settings import FitSettings
from backend.model.render import Renderer, render_pair

# A plain weave with open gaps: the back light shows through them.
OPEN = FabricParams.from_interchange(
    "plain_R_0.4,0.4_S_1.0,1.0_T_1.5,1.5_N_0.0_UV_60.0,60.0_Kd_0.3,0.3,0.3,0.3,0.3,0.3"
    "_G_0.6,0.6_Rm_0.4,0.4_Tm_1.5,1.5_W_0.5,0.5_Ks_0.5,0.5,0.5,0.5,0.5,0.5_Psi_0.0,0.0")
SIZE = 96


def _run(glow_shown: float, glow_rendered: float, size: int = SIZE, photo_samples: tuple[int, int] | None = None
         ) -> Run:
    """A run at OPEN whose renderer shows ``glow_rendered``, against photos of OPEN with
    ``glow_shown``, rendered with ``photo_samples`` (samples per pixel, seed), by default the run's
    own (then at the truth the colour term is lowest at the glow shown; with other samples the clamp
    of a pixel's few samples through gaps reads a saturated spot high)."""
    settings = FitSettings(pattern=OPEN.pattern, size=size, spp=4, compile=False, camera_blur=0.0)
    spp, seed = photo_samples or (settings.spp, settings.seed)
    photos = render_pair(OPEN, dataclasses.replace(DEFAULT_RIG, glow_strength=glow_shown), size=size, spp=spp,
                         seed=seed)
    objective = _objective(photos.reflection.numpy(), photos.transmission.numpy(),
                           dataclasses.replace(DEFAULT_RIG, glow_strength=glow_rendered), settings)
    return Run(OPEN, objective, settings, total=10, camera_blur_px=0.0)


def test_set_glow_renders_as_a_renderer_made_with_that_glow():
    """Setting the glow renders what a renderer built with it renders, and the rig it carries (and
    passes on to :meth:`Renderer.like`) says so."""
    with torch.no_grad():
        changed = Renderer(DEFAULT_RIG, 64, 4, 0)
        changed.render(OPEN)   # a kept radiance must not outlive the glow
        changed.set_glow(2.0)
        made = Renderer(dataclasses.replace(DEFAULT_RIG, glow_strength=2.0), 64, 4, 0)
        assert torch.equal(changed.render(OPEN).transmission, made.render(OPEN).transmission)
        assert changed.like(32, 4, 1).rig.glow_strength == 2.0
        none = Renderer(DEFAULT_RIG, 64, 4, 0)
        none.set_glow(0.0)
        bright = Renderer(DEFAULT_RIG, 64, 4, 0).render(OPEN).transmission
        assert none.glow is None and (none.render(OPEN).transmission <= bright).all()
    with pytest.raises(ValueError, match="glow"):
        changed.set_glow(-1.0)


@pytest.mark.parametrize("shown", [0.0, 2.0, 16.0])
def test_the_scan_reads_the_glow_the_photos_show(shown):
    """Photos of the open weave with a glow of the scan's, read at the true parameters from the
    spec's 8: the scan finds it, the run's best is the current state with its loss under it."""
    run = _run(shown, 8.0)
    assert run.scan_glow()
    assert run.objective.renderer.rig.glow_strength == shown
    assert run.best_loss == pytest.approx(run.objective.value(run.fabric, 0.0))
    assert run.best_terms["loss"] == pytest.approx(run.best_loss)


@pytest.mark.parametrize("shown", [0.0, 2.0])
def test_photos_with_many_samples_read_their_glow_at_the_fits_few(shown):
    """Photos rendered with 64 samples per pixel (another jitter), read by a run at 4: the glow's
    Monte Carlo speckle differs, its block means do not, and the scan reads the strength shown
    (the whole loss reads a stronger or weaker one here: its spectrum term sees the speckle)."""
    run = _run(shown, 8.0, size=128, photo_samples=(64, 7))
    assert run.scan_glow() and run.objective.renderer.rig.glow_strength == shown


def test_the_scan_keeps_the_glow_it_has_where_that_is_the_photos():
    run = _run(8.0, 8.0)
    assert 8.0 in GLOW_SCAN and not run.scan_glow()
    assert run.objective.renderer.rig.glow_strength == 8.0


@pytest.mark.parametrize("estimate", [False, True])
def test_a_fit_reads_the_glow_only_where_asked(estimate):
    """A short fit of photos of the open weave without glow (rendered with the fit's own samples):
    asked (``estimate_glow``), its first discrete search reads a strength of the scan below the rig's
    and the result says so (the fit at 64 px is far from the truth: not necessarily none); otherwise
    the result keeps the rig's."""
    from backend.fit.pipeline import fit

    settings = FitSettings(pattern="plain", size=64, spp=4, iterations=27, trial_iterations=1, compile=False,
                           camera_blur=0.0, sample_rotation=0.0, estimate_variation=False, spacing_warp=False,
                           estimate_glow=estimate)
    photos = render_pair(OPEN, dataclasses.replace(DEFAULT_RIG, glow_strength=0.0), size=64, spp=settings.spp,
                         seed=settings.seed)
    result = fit(photos.reflection.numpy(), photos.transmission.numpy(), settings=settings)
    if estimate:
        assert result.glow_strength in GLOW_SCAN and result.glow_strength < DEFAULT_RIG.glow_strength
    else:
        assert result.glow_strength == DEFAULT_RIG.glow_strength
