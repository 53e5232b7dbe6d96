"""EEVEE's part of the standard-node fallback's program: three closures per pixel (no bpy).

EEVEE merges more than three closures of a material, lights no hair closure on a surface and has no
anisotropic Glossy, so the fallback's ``EEVEE`` output is one Diffuse, one Glossy and one
Translucent BSDF (scene/fallback_group.py), their inputs computed here from the Cycles closures'
weights (core/shader_fallback.py):

- Diffuse: k_d^r on the normal mix (1 - w) N + w n (its length the weight), n the front yarn's;
- Glossy: the sum of the four lobes' colours (both layers, single and multiple scattering), their
  roughness the colour-weighted mean of theirs, on the front layer's colour-weighted mean of its two
  lobes' normals (each leaned by its own roughness) where it is a yarn, else the back layer's;
- Translucent: each hair closure's share as the lesser of its energy (its weight: the closure is a
  normalised density) and the weight whose value at wo = -wi is its peak (pi f / |wi_z|), plus the
  multiple lobe's glow and the diffuse transmission; the colour is the square root of that sum. The
  forward scattering (backend/model/asggx.py) only moves the multiple lobe's light around the fibre
  (its mean over the azimuth is 1), which a Translucent BSDF, even in azimuth, cannot show: EEVEE
  keeps that lobe as at k = 0.

EEVEE measured with Blender 5.0, material thickness mode "Slab", thickness 0: a Translucent BSDF of
colour k lit from behind renders k^2 |cos| / pi (the light crosses the sheet's two faces), and the
translucent closures of a material are summed before that square; with more than three closures EEVEE
merges them and the transmission grows further. Hence one Translucent closure of colour sqrt(sum).

What EEVEE does not draw: the fibres' transmission streak through a back light (a cross on a plain
weave, a band on a satin), the largest part of its difference from the backend. Routes measured and
left (Blender 5.0, the rig's back light): a Refraction BSDF at IOR 1 is a one-pixel spike whose
height jumps with its roughness; a Glossy BSDF whose normal lies in the fabric's plane across the
fibre (its lobe peaks where wi + wo lies along that normal: on the fibre's transmission cone) is lit
from behind, but the sheet shadows it into speckle, it renders black where the view is square to that
normal (the streak's middle), and it would be a fourth closure; a Translucent BSDF's normal, which
could carry the light's direction into nodes through Shader to RGB, is not read there (every normal
gave the same values, in steps of 1/64).
"""
from __future__ import annotations

import math

# EEVEE's diffuse transmission: the yarn term's n . wi / wi_z (spec 4.5's 1 / |w_z| at wo = -wi) grows
# without bound at grazing views, bright specks on the silhouettes of a backlit drape; it is capped
# here, above what the rig's views (near the fabric's normal) reach.
EEVEE_TRANSLUCENT_CAP = 2.0

# The bent normals (McAuley 2015; glTF KHR_materials_anisotropy in three.js and Babylon.js): EEVEE's
# isotropic Glossy gets the yarn's normal bent towards the view's component across the front fiber,
# by EEVEE_GLOSS_BEND times (1 - its roughness), so the highlight follows the fibres; its roughness is
# the lobes' mean raised to EEVEE_ROUGHNESS_POWER (wider: the fiber lobe spreads across). The
# Translucent BSDF's normal leans towards the view by EEVEE_TRANSLUCENT_BEND (its lobe towards the
# straight-through direction, where the yarns' transmission peaks). Chosen on the tuning draws of
# tools/validate_shader.py (a numpy model of the three closures in the rig, then EEVEE renders).
EEVEE_GLOSS_BEND = 0.5
EEVEE_ROUGHNESS_POWER = 0.75
EEVEE_TRANSLUCENT_BEND = 0.3

# Per layer k (j the other): the translucent weights of the single and the multiple lobe.
_LAYER = """
eevee_s{k} = min(hair_s_weight{k}, {pi!r} * ts{k} * att{j} / wiz)
eevee_m{k} = (1 - glow{k}) * min(cone_m{k}, {pi_cone!r} * tm{k} * att{j} / wiz) + glow_m{k}
"""

_CLOSURES = """
eevee_m = vadd(scale(Normal, 1 - diffuse_normal_weight), scale(n_main, diffuse_normal_weight))
eevee_diffuse_normal = normalize(eevee_m)
eevee_diffuse = scale(kd_r, sqrt(dot(eevee_m, eevee_m)))
eevee_0 = vadd(scale(ks0, eevee_s0), scale(km0, eevee_m0))
eevee_1 = vadd(scale(ks1, eevee_s1), scale(km1, eevee_m1))
yarn_t_eevee = diffuse_normal_weight * other * min(yarn_cos, {cap!r})
translucent_eevee = vadd(scale(kd_t, 1 - diffuse_normal_weight), scale(kd_t, yarn_t_eevee))
eevee_t = vadd(translucent_eevee, vadd(eevee_0, eevee_1))
eevee_translucent = vpow(eevee_t, vec(0.5, 0.5, 0.5))
eevee_gloss = vadd(vadd(gloss_s_color0, gloss_m_color0), vadd(gloss_s_color1, gloss_m_color1))
gw_s0 = dot(gloss_s_color0, vec(1, 1, 1))
gw_m0 = dot(gloss_m_color0, vec(1, 1, 1))
gw_s1 = dot(gloss_s_color1, vec(1, 1, 1))
gw_m1 = dot(gloss_m_color1, vec(1, 1, 1))
gw_rough = gw_s0 * gloss_s_rough0 + gw_m0 * gloss_m_rough0 + gw_s1 * gloss_s_rough1 + gw_m1 * gloss_m_rough1
eevee_gloss_rough = pow(gw_rough / (gw_s0 + gw_m0 + gw_s1 + gw_m1), {rough_power!r})
gloss_n0 = normalize(vadd(scale(gloss_s_normal0, gw_s0 + 0.000001), scale(gloss_m_normal0, gw_m0)))
gloss_n1 = normalize(vadd(scale(gloss_s_normal1, gw_s1 + 0.000001), scale(gloss_m_normal1, gw_m1)))
gloss_flat_normal = normalize(vadd(scale(gloss_n0, y0), scale(gloss_n1, 1 - y0)))
eevee_fiber = normalize(vadd(vadd(scale(fiber0, y0), scale(fiber1, 1 - y0)), scale(Normal, 0.0001)))
view_across = vsub(Incoming, scale(eevee_fiber, dot(Incoming, eevee_fiber)))
eevee_across = normalize(vadd(view_across, scale(Normal, 0.0001)))
gloss_bend = {bend!r} * (1 - eevee_gloss_rough)
eevee_gloss_normal = normalize(vadd(gloss_flat_normal, scale(vsub(eevee_across, gloss_flat_normal), gloss_bend)))
translucent_bend = {translucent_bend!r}
eevee_translucent_normal = normalize(vadd(Normal, scale(vsub(Incoming, Normal), translucent_bend)))
"""


def layer_text(k: int, tt_cone: float) -> str:
    """Layer k's EEVEE translucent weights (after that layer's Cycles weights; ``tt_cone``: the
    multiple lobe's cone weight, shader_fallback.TT_CONE)."""
    return _LAYER.format(k=k, j=1 - k, pi=math.pi, pi_cone=math.pi * tt_cone)


def closures_text(bend: float = EEVEE_GLOSS_BEND, translucent_bend: float = EEVEE_TRANSLUCENT_BEND,
                  rough_power: float = EEVEE_ROUGHNESS_POWER) -> str:
    """The EEVEE closures' inputs (after the diffuse terms)."""
    return _CLOSURES.format(cap=EEVEE_TRANSLUCENT_CAP, bend=bend, translucent_bend=translucent_bend,
                            rough_power=rough_power)
