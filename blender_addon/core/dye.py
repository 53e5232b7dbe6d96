"""Colour as dye: how painted colour, a whole-fabric recolour and yarn-dyed stripes recolour a fit (no bpy).

A fit's colour sits mostly in the yarns' specular albedos k_s (and k_m = k_s^(1/w_m), the multiple
scattering's); the diffuse albedos k_d^r, k_d^t may be near zero. Painting must recolour all of
them together, as a dye colours the fibre, keeping what makes the cloth this cloth: the sheen (the
lobes), the translucency and the contrast between warp, weft and their noise.

Every render (Cycles OSL, the standard-node fallback, EEVEE) is linear in the albedos, per colour
channel, with weights that do not depend on the channel. So scaling every albedo's channel c by a
factor f_c scales the rendered colour's channel c by f_c. The dye:

1. the fabric's base colour, its colour as an artist sees it (:func:`base_colour`)::

       C0 = SPECULAR_WEIGHT * mean(k_s, k_m over warp and weft) + DIFFUSE_WEIGHT * k_d^r

   the equivalent Lambertian albedo of the capture rig's reflection (weights fitted by least
   squares to the backend's renders of prior draws); it names the asset's colour tag;
2. each yarn's target colour T: its stripe colour P (core/sett.py) or, undyed, C0; recoloured by
   the hue shift, saturation and value factors (Blender's Hue/Saturation/Value node, :func:`recolour`);
   then the colour map m (the painted colour layer, white where unpainted) multiplies it, or where
   the map's replace factor r is 1 replaces it::

       T = (1 - r) HSV(P) m + r m

3. the dye factor f = T / max(C0, BASE_FLOOR) per channel, times the largest common factor s <= 1
   that keeps every dyed albedo of the yarn in [0, 1]: s = min(1, 1 / max_c max_k f_c k_c) over
   k in k_s, k_m (that yarn's) and k_d^r, k_d^t (:func:`dye_factor`);
4. every albedo of the yarn times s f: k_s, k_m and, where the yarn is in front (or seen through a
   gap in front), k_d^r and k_d^t.

So the cloth renders T on average: painting pure red (1, 0, 0) zeroes every green and blue albedo
(red cloth in every renderer), painting C0 itself gives f = 1 (nothing changes), and the ratios
between the yarns' albedos (the weave contrast, sheen against body) stay. A channel the fit has no
light in (C0 under BASE_FLOOR) cannot be dyed up from nothing: the floor keeps f finite there.
"""
from __future__ import annotations

import colorsys
import math

# C0's weights: the backend's reflection in the capture rig as a Lambertian albedo, least squares over
# 40 prior draws (all five weaves); mean absolute residual 0.08 per channel.
SPECULAR_WEIGHT = 0.5
DIFFUSE_WEIGHT = 0.85
BASE_FLOOR = 1e-4  # the least base colour a channel is divided by (a fit with no light in a channel)
# The recolour sockets' neutral values: no hue shift (degrees), saturation and value factors of 1.
NEUTRAL_RECOLOUR = (0.0, 1.0, 1.0)

RGB = tuple[float, float, float]


def multiple_albedo(specular: RGB, multiple_weight: float) -> RGB:
    """k_m = k_s^(1 / w_m) (spec 4.3), w_m at least 0.01 as in the shader."""
    exponent = 1.0 / max(float(multiple_weight), 0.01)
    return tuple(max(float(c), 0.0) ** exponent for c in specular)


def base_colour(params: dict) -> RGB:
    """C0 of a params.json dict (module docstring, step 1), linear RGB."""
    specular = [tuple(map(float, params["specular_albedo"][yarn])) for yarn in (0, 1)]
    multiple = [multiple_albedo(k, params.get("multiple_weight", 1.0)) for k in specular]
    diffuse = tuple(float(c) for c in params["diffuse_reflection"])
    return tuple(SPECULAR_WEIGHT * (specular[0][c] + specular[1][c] + multiple[0][c] + multiple[1][c]) / 4.0
                 + DIFFUSE_WEIGHT * diffuse[c] for c in range(3))


def recolour(colour: RGB, hue_deg: float = 0.0, saturation: float = 1.0, value: float = 1.0) -> RGB:
    """Blender's Hue/Saturation/Value node (factor 1, hue input 0.5 + hue_deg / 360): the hue turned,
    the saturation scaled (at most 1), the value scaled; negative channels clamped to 0."""
    h, s, v = colorsys.rgb_to_hsv(*colour)
    h = math.fmod(h + hue_deg / 360.0 + 1.0, 1.0)
    out = colorsys.hsv_to_rgb(h, min(max(s * saturation, 0.0), 1.0), v * value)
    return tuple(max(c, 0.0) for c in out)


def target_colour(stripe: RGB | None, base: RGB, recolour_hsv=NEUTRAL_RECOLOUR, colour_map: RGB = (1.0, 1.0, 1.0),
                  replace: float = 0.0) -> RGB:
    """T (module docstring, step 2) of a yarn of stripe colour ``stripe`` (None: undyed, the base colour)."""
    dyed = recolour(base if stripe is None else stripe, *recolour_hsv)
    return tuple((1.0 - replace) * dyed[c] * colour_map[c] + replace * colour_map[c] for c in range(3))


def dye_factor(target: RGB, base: RGB, albedos) -> RGB:
    """s f (module docstring, step 3): T / max(C0, floor), scaled down so that no albedo of ``albedos``
    (the yarn's k_s, k_m, k_d^r, k_d^t) leaves [0, 1]."""
    factor = [target[c] / max(base[c], BASE_FLOOR) for c in range(3)]
    largest = max(factor[c] * float(k[c]) for k in albedos for c in range(3))
    scale = 1.0 / max(largest, 1.0)
    return tuple(f * scale for f in factor)


def dyed(albedo: RGB, factor: RGB) -> RGB:
    return tuple(float(a) * f for a, f in zip(albedo, factor))
