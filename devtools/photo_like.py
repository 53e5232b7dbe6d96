"""A sample photographed by a phone: the photo-like pairs of the fit benchmark and of the network's
photo-like training items.

One shot of a weave preset, all drawn from one seeded generator ``rng`` in this order:

1. parameters from the spec's dataset prior (:func:`backend.core.priors.sample`);
2. the framing (:func:`framed`): the yarns at U(2, 4) film pixels each on the denser axis, as in the
   real photos, where the prior's densities would give most weaves fewer than 2;
3. the sample turned by U(-5, 5) degrees in the holder (the rig's ``sample_rotation_deg``);
4. one phone (:meth:`devtools.phone.PhoneEffects.draw`: non-uniform yarn spacing, light
   falloff, blur 0.5-2 film pixels, exposure and white balance, shot and read noise, JPEG quality);
5. the seed of the render's sample positions.

With ``variation_rng``, the sample's yarns vary (:func:`backend.core.priors.sample_variation`: each
kind's amplitude and correlation length, warp and weft apart, from the declared priors), drawn from
that generator of its own, so the set's other draws stay the regular set's. With ``forward_rng``, the
yarns scatter forward (:func:`backend.core.priors.sample_forward`), drawn the same way.

With ``move_rng``, the phone also moves between the shots (:func:`moved_reflection`): the
reflection photo is taken from a little further away and turned (up to :data:`MOVE_SCALE` and
:data:`MAX_MOVE_TURN_DEG`), as a hand-held phone's second shot is. The move is drawn from its own
generator, so a set's unmoved shots stay what they were.

The rig renders the turned sample at ``phone_scale`` times the film's resolution with one sample per
phone pixel (``phone_scale``\\ :sup:`2` per film pixel), the phone turns each radiance into its photo
at that resolution, JPEG-compresses it there and it is area-resized to the film
(:func:`devtools.phone.phone_jpeg`). The benchmark photographs at :data:`PHONE_SCALE` (a 2048-px
crop of a 12 MP photo); the training set at 2, which costs a quarter as much (a 1024-px crop: the
same blur, noise level and JPEG, with its blocks twice as large in film pixels).
"""
from __future__ import annotations

import dataclasses
import random
from dataclasses import dataclass

import numpy as np
import torch

from backend.core import priors
from backend.core.params import FabricParams
from backend.core.rig import CaptureRig
from backend.model.render import Renderer
from backend.texture.frequencies import yarns_in_view

from .phone import PhoneEffects, phone_jpeg

MAX_ROTATION_DEG = 5.0
MOVE_SCALE = (1.0, 1.1)             # how much denser the moved reflection shows the yarn lattice
MAX_MOVE_TURN_DEG = 2.0             # and how far it is turned
PHONE_SCALE = 4                     # phone pixels per film pixel (a 2048-px crop of a 12 MP photo)
PIXELS_PER_YARN = (2.0, 4.0)        # film pixels per yarn on the denser axis, as a photographer frames it


def framed(params: FabricParams, pixels_per_yarn: float, rig: CaptureRig) -> FabricParams:
    """``params`` with the tiles scaled (both axes alike) so that the denser axis's yarns get
    ``pixels_per_yarn`` film pixels, or as they are where they get more already. The prior's
    densities are the paper's 512-px training renders, which alias most of them (0.7-2.7 px per
    yarn); a photographer frames the sample so the phone resolves its weave, or the photo shows none
    (and the fit refuses it as featureless)."""
    yarns = yarns_in_view(params.pattern, params.tiles, rig)
    shrink = min(1.0, rig.film_size / pixels_per_yarn / yarns)
    return params.replace(tiles=tuple(t * shrink for t in params.tiles))


@dataclass(frozen=True)
class Shot:
    """One photographed pair: the truth and the two 8-bit display-space photos at the film's size."""

    params: FabricParams
    rig: CaptureRig          # the rig with the sample's true rotation and the phone's blur
    phone: PhoneEffects
    reflection: np.ndarray   # (film, film, 3) float64 in [0, 1], multiples of 1/255
    transmission: np.ndarray
    move: "PhoneMove | None" = None  # the phone's move before the reflection shot (truth: the transmission's framing)


@dataclass(frozen=True)
class PhoneMove:
    """The reflection photo's framing against the transmission's: its yarn lattice ``scale`` times
    as dense and turned by ``turn_deg`` in the image (k_R = scale turn(turn_deg) k_T, the map
    :class:`backend.image.registration.Registration` reads; the sample turned by -turn_deg)."""

    scale: float
    turn_deg: float

    @classmethod
    def draw(cls, rng: random.Random) -> "PhoneMove":
        return cls(rng.uniform(*MOVE_SCALE), rng.uniform(-MAX_MOVE_TURN_DEG, MAX_MOVE_TURN_DEG))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def moved_reflection(params: FabricParams, rig: CaptureRig, move: PhoneMove) -> tuple[FabricParams, CaptureRig]:
    """The sample as the moved phone frames it: the tiles ``move.scale`` times as many in view and
    the sample turned so that its lattice turns by ``move.turn_deg`` in the image. The zoom is about
    the tile coordinates' origin, not the image centre, so the moved photo's weave is shifted as well,
    which a phone's move does too. A render, not a resampled photo: the moved photo shows fabric past
    the other's edges, and resampling would soften its weave. (The lamps stay where they were against
    the camera; a turn of 2 degrees moves the highlights across the yarns by as much.)"""
    return (params.replace(tiles=tuple(t * move.scale for t in params.tiles)),
            dataclasses.replace(rig, sample_rotation_deg=rig.sample_rotation_deg - move.turn_deg))


def photograph(pattern: str, rng: random.Random, rig: CaptureRig, phone_scale: int = PHONE_SCALE,
               move_rng: random.Random | None = None, without: tuple[str, ...] = (),
               variation_rng: random.Random | None = None, forward_rng: random.Random | None = None) -> Shot:
    """A sample of ``pattern`` drawn and photographed as the module docstring says, by a phone
    without the effects named in ``without`` (:meth:`devtools.phone.PhoneEffects.without`: drawn,
    then taken away)."""
    params = framed(priors.sample(pattern, rng), rng.uniform(*PIXELS_PER_YARN), rig)
    if variation_rng is not None:
        params = params.replace(**priors.sample_variation(variation_rng))
    if forward_rng is not None:
        params = params.replace(**priors.sample_forward(forward_rng))
    placed = dataclasses.replace(rig, sample_rotation_deg=rng.uniform(-MAX_ROTATION_DEG, MAX_ROTATION_DEG),
                                 camera_blur_px=0.0)
    phone = PhoneEffects.draw(rng).without(*without)
    render_seed = rng.randrange(1 << 20)
    size = rig.film_size * phone_scale
    with torch.no_grad():
        pair = Renderer(placed, size=size, spp=1, seed=render_seed).render(params)
        radiances = [pair.reflection_radiance, pair.transmission_radiance]
        move = None if move_rng is None else PhoneMove.draw(move_rng)
        if move is not None:
            moved_params, moved_rig = moved_reflection(params, placed, move)
            moved_pair = Renderer(moved_rig, size=size, spp=1, seed=render_seed).render(moved_params)
            radiances[0] = moved_pair.reflection_radiance
    photos = [phone_jpeg(phone.apply(radiance, photo, placed), phone.jpeg_quality, rig.film_size)
              for photo, radiance in enumerate(radiances)]
    # What an 8-bit file holds: the benchmark writes these as PNGs, the training set uses them as read.
    reflection, transmission = (np.round(p * 255) / 255 for p in photos)
    truth_rig = dataclasses.replace(placed, camera_blur_px=round(phone.blur_px, 4))
    return Shot(params, truth_rig, phone, reflection, transmission, move)
