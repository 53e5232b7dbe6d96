"""The fit's reading of the photos' uneven yarn spacing (:mod:`backend.model.spacing_warp`).

The warp a photo shows is read against a render of the fabric as the fit has it: a harmonic's
phase also drifts across the photo with the light (a highlight's place on a yarn follows the half
vector), and the render drifts alike, so only what the photo shows beyond the render is the
yarns' (:func:`backend.texture.uneven_spacing.read_warp`). The drift depends on the fabric
(roughness, twist, height), so the warp is read again as the fit goes on
(:meth:`backend.fit.optimise.Run.update_warp`), each time against a render that already shows the
warp read so far:

    warp_{k + 1} = warp_k + read(photos, render(best parameters, warp_k))

A warp is one of the sample's, so both photos show it alike: the first is read only where each
photo's own reading agrees with the other's (:data:`backend.texture.uneven_spacing.AGREEMENT`;
where the two photos' phases differ in more than a shared warp, a phone that moved between the
shots or a texture the model does not make, a warp read from both at once fits neither), and the
later readings refine it from both at once. The same readings stretch the tiles where the photos
show the lattice denser or sparser than the render, evenly over the photo
(:mod:`backend.texture.uneven_spacing`: the placement's mean spacing, read from the photos alone,
leans to where the harmonics show most and carries the light's phase drift). Each reading is tried
before it is kept (:meth:`backend.fit.optimise.Run.update_warp`): the stretched tiles at once, by
the loss at the best parameters, the warp over a few steps.
"""
from __future__ import annotations

import torch

from ..core.params import FabricParams
from ..image.spectrum import highpassed_luminance
from ..model.spacing_warp import SpacingWarp
from ..texture.frequencies import lattice_of
from ..texture.signatures import signatures
from ..texture.uneven_spacing import WarpReading, read_warp
from .objective import Objective

HIGHPASS_FRACTION = 1 / 64  # of the image's side: the high-pass of the photos' spectra (texture.lattice.Spectra)


def reread(objective: Objective, params: FabricParams, camera_blur_px: float
           ) -> tuple[SpacingWarp | None, tuple[float, float]]:
    """(warp, tiles): the objective's warp plus what the photos show beyond a render of ``params``
    under it, and ``params``' tiles stretched as the photos show them against that render (module
    docstring); each as it is where nothing more is read."""
    warp = objective.renderer.warp
    with torch.no_grad():
        pair, _ = objective.rendered(params, camera_blur_px)
    size = objective.target.size
    photos = (objective.target.reflection, objective.target.transmission)
    renders = (pair.reflection, pair.transmission)
    rig = objective.rig
    found = signatures(rig, (params.pattern,))[params.pattern]
    readings = [WarpReading(*(highpassed_luminance(image.detach().cpu().numpy(), size * HIGHPASS_FRACTION)
                              for image in (photo, render)), signature)
                for photo, render, signature in zip(photos, renders, found)]
    a, b = lattice_of(params.tiles, rig)
    more = read_warp(readings, a, b, rig.sample_rotation_deg, rig.sample_skew_deg, rig.film_size,
                     agreeing=warp is None)
    if more is None:
        return warp, params.tiles
    tiles = tuple(t * (1.0 + s) for t, s in zip(params.tiles, more.stretch))
    if more.warp is None:
        return warp, tiles
    return (more.warp if warp is None else warp + more.warp), tiles
