"""The colour part of the standard-node fallback's program: yarn-dyed stripes and the dye (no bpy).

The dye of core/dye.py as program lines (core/shader_program.py's language), the same formula the
OSL shader computes (shaders/woven_fabric.osl, ``wf_dye``):

- each yarn's global index, counted along the cloth (warps along U, wefts along V):
  ``floor(u tu cols - warp_offset / warp_pitch)`` for the warp at the point and
  ``floor(-v tv rows - weft_offset / weft_pitch)`` for the weft (tu, tv: tiles times uv scale; the
  same yarn boundaries as the weave's column and row, see core/shader_fallback.py);
- its stripe (core/sett.py): the stripe whose threads hold ``index mod (sum of the counts)``, a sum
  of steps; no threads at all: the base colour C0;
- the target T (recolour, then the colour map), the dye factor T / max(C0, floor) scaled so that no
  albedo of that yarn passes 1, and the yarn's k_s and k_m times it (``ks_warp``, ``km_warp``,
  ``ks_weft``, ``km_weft``);
- :data:`DIFFUSE` (after the layers): the diffuse albedos ``kd_r``, ``kd_t`` times the factor of the
  yarn in front (the back one through a gap in front).
"""
from __future__ import annotations

from . import dye, sett

# The dye factor of each yarn direction; {d} is warp or weft, {index} its global yarn index.
_DIRECTION = """
{d}_end0 = 0
{ends}
{d}_total = {d}_end{n}
{d}_pos = mod({index}, max({d}_total, 1))
{d}_stripe = {d}_stripe_1_colour
{steps}
{d}_paint = vadd(base, scale(vsub({d}_stripe, base), gt({d}_total, 0.5)))
{d}_hsv = hsv({d}_paint, 0.5 + recolour_hue / 360, recolour_saturation, recolour_value)
{d}_target = vadd(scale(vmul({d}_hsv, colour_map), 1 - colour_map_replace), scale(colour_map, colour_map_replace))
{d}_f = vdiv({d}_target, base_safe)
{d}_albedo = vmax(vmax(specular_albedo_{d}, km_{d}_fit), vmax(diffuse_reflection, diffuse_transmission))
{d}_reach = vmul({d}_f, {d}_albedo)
{d}_dye = scale({d}_f, 1 / max(max(max(x({d}_reach), y({d}_reach)), z({d}_reach)), 1))
ks_{d} = vmul(specular_albedo_{d}, {d}_dye)
km_{d} = vmul(km_{d}_fit, {d}_dye)
"""

_BASE = f"""
inv_wm = 1 / max(multiple_weight, 0.01)
km_warp_fit = vpow(specular_albedo_warp, vec(inv_wm, inv_wm, inv_wm))
km_weft_fit = vpow(specular_albedo_weft, vec(inv_wm, inv_wm, inv_wm))
ks_sum = vadd(specular_albedo_warp, specular_albedo_weft)
km_sum = vadd(km_warp_fit, km_weft_fit)
specular_part = scale(vadd(ks_sum, km_sum), {dye.SPECULAR_WEIGHT / 4.0!r})
base = vadd(specular_part, scale(diffuse_reflection, {dye.DIFFUSE_WEIGHT!r}))
base_safe = vmax(base, vec({dye.BASE_FLOOR!r}, {dye.BASE_FLOOR!r}, {dye.BASE_FLOOR!r}))
warp_index = floor(su * cols - warp_off / warp_p)
weft_index = floor(0 - sv * rows - weft_off / weft_p)
"""

# After the layers (y0, y1 and their warp / weft shares): the diffuse albedos dyed by the front yarn.
DIFFUSE = """
front_warp_share = y0w + (1 - y0) * y1w
front_weft_share = y0f + (1 - y0) * y1f
front_dye = vadd(scale(warp_dye, front_warp_share), scale(weft_dye, front_weft_share))
kd_r = vmul(diffuse_reflection, front_dye)
kd_t = vmul(diffuse_transmission, front_dye)
"""


def _direction(direction: str) -> str:
    d = direction
    ends = "\n".join(f"{d}_end{k + 1} = {d}_end{k} + {d}_stripe_{k + 1}_threads" for k in range(sett.STRIPES))
    steps = "\n".join(f"{d}_stripe = vadd({d}_stripe, scale(vsub({d}_stripe_{k + 1}_colour, {d}_stripe_{k}_colour), "
                      f"gt({d}_pos, {d}_end{k} - 0.5)))" for k in range(1, sett.STRIPES))
    return _DIRECTION.format(d=d, ends=ends, n=sett.STRIPES, steps=steps, index=f"{d}_index")


def program_text() -> str:
    """The lines giving the dyed ``ks_*`` / ``km_*`` (after the geometry: su, sv, cols, rows and the
    bands' offsets and pitches); :data:`DIFFUSE` follows the layers."""
    return _BASE + "".join(_direction(d) for d in sett.DIRECTIONS)
