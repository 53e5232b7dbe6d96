"""The standard-node fallback of the Woven Fabric node group, as a small expression program.

EEVEE and GPU Cycles (without OptiX OSL) cannot run ``shaders/woven_fabric.osl``; the node group
then uses a fallback built from Math / Vector Math / Image Texture nodes. Its program has these parts.

Geometry (spec section 3, like ``backend/model/layers.py`` and ``yarn.py``), from UV: band tests,
the interlacing matrix and the backend's interval tables (read from the float atlases of
:func:`shader_weave.fallback_atlases`; the per-preset constants are picked by the pattern with Math
nodes, ``pick``), gap scaling, the tension mu of each yarn (linear between segment centres), and
the bent-cylinder normal and twisted fiber direction of the warp and of the weft at the point,
height-scaled. Layer 0 (front) and layer 1 (back) take the yarn the weave puts there (seen from
behind the two swap and z is mirrored, as in the OSL shader). It skips the noise (spec 4.6) and the
flat segments (none in the presets).

Yarn variation (the backend's core/variation.py, :func:`variation_text`): written here with the same
hash and factors as the backend and the OSL shader (each yarn's plane-wide index and along-yarn
position from UV; the hash is integers below 2^24, so Blender's float32 Math nodes, floored modulo,
compute it exactly: tests/test_variation.py evaluates it against the backend), but left out of the
built node group (:data:`FALLBACK_VARIATION`): it is about 1,060 more nodes, 2,470 instead of 1,410,
and building the group took 72 s instead of 18 s. So EEVEE and GPU Cycles show no yarn variation.

Shading (spec section 4, the OSL shader's approximation in standard closures). Everything that
depends on the view direction wi (the Geometry node's Incoming) is computed exactly per layer k;
the dependence on the light direction wo is left to the closures:

- reflection, single (SGGX) and multiple (ASGGX) scattering: an anisotropic GGX Glossy BSDF with
  roughness alpha along the fiber and 1 across, on the normal Nc (the most upward normal
  perpendicular to the fiber leaned towards z by the lobe's alpha^2: alpha for the single, alpha_m for
  the multiple), weighted by (exact lobe / closure) at the mirror direction of wi about the lobe's Nc;
- transmission, single and multiple: Cycles, a Hair BSDF (transmission, roughness
  r = asin(0.5 alpha / sqrt(1 - alpha^2)), azimuthal roughness 1, tangent = the fiber) weighted so
  that its peak is the exact lobe at the straight-through direction wo = -wi, times the OSL shader's
  factors (0.3 + 0.7 alpha^2 single, TT_CONE multiple); the multiple lobe turns into a Translucent BSDF
  of weight pi f_m(-wi) / |wi_z| (its straight-through value) as alpha_m grows (TT_GLOW); the forward
  scattering (backend/model/asggx.py) as in the OSL shader: those two carry A_k's least value
  (1 - k) / (1 + k), a second Hair BSDF (azimuthal roughness acos(2 k / (1 + k^2))) the peaked rest;
- two layers (4.5): the back layer's reflection lobes carry att0(wi) att0(wo*), the transmission
  lobes att1(wi) (front layer) and att0(wi) (back layer), att = exp(-T sigma(w) / |w_z|);
- diffuse: (1 - w) k_d^r diffuse(N) + w k_d^r diffuse(n), n the front yarn's normal (the back one's
  through a gap in front); in transmission (1 - w) k_d^t translucent(N) + w k_d^t c translucent(N) with
  the product c = max(0, -wo . n0) max(0, -wo . n1) / |wo_z| of spec 4.5 taken at wo = -wi. (A Translucent
  BSDF on n itself would do the light-side cosine exactly, as the OSL shader does, but Cycles' SVM bends
  the normal of a translucent closure like a glossy one's, ``maybe_ensure_valid_specular_reflection``,
  which made it too bright);
- gaps (both layers open): the node group mixes in a Transparent BSDF by ``coverage``.

Colour (core/shader_dye.py): the yarns' albedos dyed (core/dye.py), per yarn direction, by the
yarn-dyed stripes, the recolour and the colour map. EEVEE's three closures: core/shader_eevee.py.

The program is written in core/shader_program.py's expression language; :func:`run` evaluates it
with a builder (scene/fallback_group.py builds nodes, the tests evaluate it on numpy arrays).
"""
from __future__ import annotations

import math

from . import declarations, shader_dye, shader_eevee, shader_program, shader_weave

LAYERS = (0, 1)

# Blender's Glossy BSDF (GGX, Blender 5.0, node_glossy_bsdf.osl and its SVM twin) has alpha = r^2 (1 - an)
# along its tangent and r^2 / (1 - an) across, anisotropy an > 0 (clamped to 0.99; measured: highlights
# of a tangent along y are narrow in y). r = alpha^(1/4) and an = 1 - sqrt(alpha) give alpha along the
# fiber and 1 across, the SGGX fiber distribution, for every alpha >= 1e-4. EEVEE ignores the anisotropy:
# an isotropic GGX of alpha r^2 = sqrt(alpha) with the same D at the mirror direction.
# The OSL shader's transmission constants (shaders/woven_fabric.osl; a test keeps the two equal):
# single-scattering wedge vs cone 0.3 + 0.7 alpha^2 (fitted to the backend in the capture rig, golden cases).
# Multiple scattering: a wide ASGGX lobe is nearly uniform around its cone (spec 4.3), which Cycles' hair
# transmission (a Cauchy in azimuth) cannot be; seen from a point it is a cosine glow of the lobe's value at
# wo = -wi. So the lobe is the hair cone, weight TT_CONE times its peak, blended into a translucent closure
# of that straight-through value as alpha_m goes from TT_GLOW[0] to TT_GLOW[1]. Fitted to the exact lobe of
# one flat fibre in the capture rig, not to any parameter set the validation uses.
# Whether the built node group shows the yarn variation (module docstring): off, its nodes made building
# the group four times slower; program(variation=True) is what it would build.
FALLBACK_VARIATION = False
TT_SINGLE = (0.3, 0.7)
TT_CONE = 1.25
TT_GLOW = (0.25, 0.95)

_GEOMETRY = """
{header}
su = x(UV) * tiles_warp * uv_scale
sv = y(UV) * tiles_weft * uv_scale
X = fract(su) * tile_w
Y = (1 - fract(sv)) * tile_h
xr = mod(X - warp_off, tile_w)
yr = mod(Y - weft_off, tile_h)
col = min(floor(xr / warp_p), cols - 1)
row = min(floor(yr / weft_p), rows - 1)
x_in = xr - col * warp_p
y_in = yr - row * weft_p
{variation}
in_warp = lt(x_in, warp_w)
in_weft = lt(y_in, weft_w)
over = x(lookup("matrix", (col + 0.5) / {A_matrix_w}, (mrow0 + row + 0.5) / {A_matrix_h}))
{warp}
{weft}
front_warp = in_warp * max(1 - in_weft, over) * w_ok
front_weft = in_weft * max(1 - in_warp, 1 - over) * f_ok
back_warp = in_warp * in_weft * (1 - over) * w_ok
back_weft = in_warp * in_weft * over * f_ok
bf = Backfacing
y0w = front_warp + bf * (back_warp - front_warp)
y0f = front_weft + bf * (back_weft - front_weft)
y1w = back_warp + bf * (front_warp - back_warp)
y1f = back_weft + bf * (front_weft - back_weft)
coverage = max(y0w + y0f, y1w + y1f)
mirror = 1 - 2 * bf
n_face = scale(Normal, mirror)
tangent = normalize(vsub(Tangent, scale(n_face, dot(Tangent, n_face))))
bitangent = cross(n_face, tangent)
"""

# One yarn direction at the point (backend/model/layers.py WeaveLookup._yarn; yarn.py local_frame and
# scale_height): the interval entry (centre, length, layer) and its tension entry (mu, mu before, mu
# after; distances to the neighbours' centres), u, v, the gap test, n and o (a weft's rotated by
# (x, y, z) -> (y, -x, z)), height-scaled by beta.
_YARN = """
{p}at = ({index} + 0.5) / {A_w}
{p}row = ({row0} + 2 * {cross} + 1.5 - {in_cross}) / {A_h}
{p}e = lookup("{name}", {p}at, {p}row)
{p}et = lookup("{name}_tension", {p}at, {p}row)
{p}ed = lookup("{name}_distance", {p}at, {p}row)
{p}off = mod({along} - x({p}e) + {period} / 2, {period}) - {period} / 2
{p}before = lt({p}off, 0)
{p}mu_there = {p}before * y({p}et) + (1 - {p}before) * z({p}et)
{p}dist = {p}before * x({p}ed) + (1 - {p}before) * y({p}ed)
{p}mu = x({p}et) + ({p}mu_there - x({p}et)) * abs({p}off) / {p}dist
{p}tension = (s_min + (1 - {p}mu) * (1 - s_min)){thick}
{p}u = {p}off / (y({p}e) / 2) * {umax} * ({sign} - 2 * {sign} * z({p}e))
{p}a = {across} - {width} / 2{shift}
{p}v = {p}a * {pi} / ({width} * {xi})
{p}ok = lt(abs({p}a), {width} * {xi} / 2)
{p}su = sin({p}u)
{p}cu = cos({p}u)
{p}sv = sin({p}v)
{p}cv = cos({p}v)
{p}sp = sin(twist_deg_{name} * {deg})
{p}cp = cos(twist_deg_{name} * {deg})
{p}n2 = {p}su * {p}cv
{p}o1 = 0 - {p}cv * {p}sp
{p}o2 = {p}cu * {p}cp + {p}su * {p}sv * {p}sp
{p}n = normalize(vec(height_scale_{name} * ({nx}), height_scale_{name} * ({ny}), {p}cu * {p}cv))
{p}o = normalize(vec({ox}, ({oy}), height_scale_{name} * ({p}cu * {p}sv * {p}sp - {p}su * {p}cp)))
"""
_YARNS = {
    "warp": dict(p="w_", index="col", cross="row", in_cross="in_weft", row0="wrow0", along="yr", period="tile_h",
                 across="x_in", width="warp_w", umax="umax_warp", sign="-1", nx="w_sv", ny="w_n2", ox="w_o1",
                 oy="w_o2"),
    "weft": dict(p="f_", index="row", cross="col", in_cross="in_warp", row0="frow0", along="xr", period="tile_w",
                 across="y_in", width="weft_w", umax="umax_weft", sign="1", nx="f_n2", ny="0 - f_sv", ox="f_o2",
                 oy="0 - f_o1"),
}


def _sigma(c: str, a: str) -> str:
    """SGGX projected area of a direction at cosine c to the fiber (spec 4.1)."""
    return f"sqrt(max(1 - (1 - {a} * {a}) * {c} * {c}, 0.000000000001))"


def _ndf(c2: str, a: str) -> str:
    """SGGX fiber D at squared cosine c2 to the fiber: 1 / (pi a (1 + (1 / a^2 - 1) c2)^2)."""
    return f"1 / ({math.pi!r} * {a} * (1 + (1 / ({a} * {a}) - 1) * {c2}) ** 2)"


def _world(v: str) -> str:
    return f"vadd(vadd(scale(tangent, x({v})), scale(bitangent, y({v}))), scale(Normal, z({v})))"


def _ggx(k: int, lobe: str, ax: str) -> str:
    """Lines giving ``g{lobe}{k}_ggx``, what Blender's GGX closure (normal Nc, tangent oc, alpha ax along
    it and 1 across, no Fresnel) evaluates to at (wi, wo) of the lobe's mirror direction: D(h) G2 /
    (4 wi . Nc), height-correlated Smith G2, 0 where either direction is below Nc."""
    q = f"{lobe}{k}"
    p = f"g{q}_"
    return f"""
{p}hx = dot(h{q}, oc{q}) / {ax}
{p}q = {p}hx * {p}hx + hb{q} * hb{q} + hn{q} * hn{q}
{p}ti = ({ax} * {ax} * wio{q} * wio{q} + wib{q} * wib{q}) / (cin{q} * cin{q})
{p}to = ({ax} * {ax} * woo{q} * woo{q} + wob{q} * wob{q}) / (con{q} * con{q})
{p}g2 = 1 / (1 + 0.5 * (sqrt(1 + {p}ti) - 1) + 0.5 * (sqrt(1 + {p}to) - 1))
{p}ggx = lit{q} * {p}g2 / ({math.pi!r} * {ax} * {p}q * {p}q * 4 * cin{q})
"""


def _reflection(k: int, lobe: str, rough: str, albedo: str) -> str:
    """Layer k's glossy closure of one lobe (``s`` single, roughness a; ``m`` multiple, am): its normal Nc
    leaned from N' towards z by the lobe's roughness squared, the mirror direction of wi about it, the
    exact lobe there (``fs{k}`` / ``fm{k}``), the closure's value there and the closure's colour,
    roughness, anisotropy, normal and tangent."""
    j = 1 - k
    q = f"{lobe}{k}"
    behind = "1" if k == 0 else f"att{j} * exp(0 - T{j} * {_sigma(f'dot(wo{q}, o{j})', f'a{j}')} / woz{q})"
    if lobe == "s":
        exact = f"""ch{k} = dot(h{q}, o{k})
fs{k} = {_ndf(f"ch{k} * ch{k}", f"a{k}")} * (1 - exp(0 - T{k} * sr{q})) / sr{q} / (4 * wiz)"""
    else:
        exact = f"""across{k} = sqrt(max((1 - ci{k} * ci{k}) * (1 - co{q} * co{q}), 0))
s2{k} = min(max(0.5 * (1 + ci{k} * co{q} - across{k}), 0), 1)
fm{k} = {_ndf(f"s2{k}", f"am{k}")} * (1 - exp(0 - Tm{k} * sr{q})) / sr{q} / (2 * wiz)"""
    return f"""
Nc{q} = normalize(vadd(Np{k}, scale(vsub(vec(0, 0, 1), Np{k}), {rough} * {rough})))
oc{q} = normalize(vsub(o{k}, scale(Nc{q}, dot(o{k}, Nc{q}))))
bc{q} = cross(Nc{q}, oc{q})
cin{q} = dot(wi, Nc{q})
wr{q} = vsub(scale(Nc{q}, 2 * cin{q}), wi)
wo{q} = normalize(vec(x(wr{q}), y(wr{q}), max(z(wr{q}), 0.05)))
woz{q} = z(wo{q})
con{q} = dot(wo{q}, Nc{q})
lit{q} = gt(cin{q}, 0.0001) * gt(con{q}, 0)
co{q} = dot(wo{q}, o{k})
Ao{q} = {_sigma(f"co{q}", f"a{k}")} / woz{q}
h{q} = normalize(vadd(wi, wo{q}))
hb{q} = dot(h{q}, bc{q})
hn{q} = dot(h{q}, Nc{q})
wio{q} = dot(wi, oc{q})
wib{q} = dot(wi, bc{q})
woo{q} = dot(wo{q}, oc{q})
wob{q} = dot(wo{q}, bc{q})
sr{q} = Ai{k} + Ao{q}
{exact}
{_ggx(k, lobe, rough)}
behind{q} = {behind}
gloss_{lobe}_color{k} = scale({albedo}, f{lobe}{k} / g{q}_ggx * behind{q})
gloss_{lobe}_rough{k} = sqrt(sqrt({rough}))
gloss_{lobe}_aniso{k} = 1 - sqrt({rough})
gloss_{lobe}_normal{k} = normalize({_world(f"Nc{q}")})
gloss_{lobe}_tangent{k} = normalize({_world(f"oc{q}")})
"""


def _layer(k: int) -> str:
    """Layer k's closure weights (k = 0 front, 1 back; ``j`` the other layer)."""
    j = 1 - k
    return f"""
n{k} = vec(x(n{k}t), y(n{k}t), z(n{k}t) * mirror)
o{k} = vec(x(o{k}t), y(o{k}t), z(o{k}t) * mirror)
np{k} = vadd(vec(0 - x(o{k}) * z(o{k}), 0 - y(o{k}) * z(o{k}), 1 - z(o{k}) * z(o{k})), scale(n{k}, 0.0001))
Np{k} = normalize(np{k})
{_reflection(k, "s", f"a{k}", f"ks{k}")}
{_reflection(k, "m", f"am{k}", f"km{k}")}
th{k} = asin(min(max(ci{k}, -1), 1))
cth{k} = max(cos(th{k}), 0.0001)
hair_s_rough{k} = {_hair_roughness(f"a{k}")}
hair_m_rough{k} = {_hair_roughness(f"am{k}")}
ts{k} = ({TT_SINGLE[0]!r} + {TT_SINGLE[1]!r} * a{k} * a{k}) * T{k} * exp(0 - T{k} * Ai{k}) / (4 * piz * a{k})
tm{k} = Tm{k} * exp(0 - Tm{k} * Ai{k}) / (2 * piz * am{k})
glow{k} = min(max((am{k} - {TT_GLOW[0]!r}) / {TT_GLOW[1] - TT_GLOW[0]!r}, 0), 1)
hair_s_weight{k} = ts{k} / {_hair_peak(f"hair_s_rough{k}", f"th{k}", f"cth{k}")} * att{j}
cone_m{k} = {TT_CONE!r} * tm{k} / {_hair_peak(f"hair_m_rough{k}", f"th{k}", f"cth{k}")} * att{j}
least{k} = (1 - fw{k}) / (1 + fw{k})
hair_m_weight{k} = (1 - glow{k}) * cone_m{k} * least{k}
glow_m{k} = glow{k} * {math.pi!r} * tm{k} * att{j} / wiz
hair_f_rough{k} = min(max({math.pi / 2!r} - asin(2 * fw{k} / (1 + fw{k} * fw{k})), 0.001), 1)
rest{k} = 4 * fw{k} / (1 - fw{k} * fw{k})
hair_f_weight{k} = rest{k} * tm{k} / {_hair_peak(f"hair_m_rough{k}", f"th{k}", f"cth{k}", f"hair_f_rough{k}")} * att{j}
hair_s_color{k} = scale(ks{k}, hair_s_weight{k})
hair_m_color{k} = scale(km{k}, hair_m_weight{k})
hair_f_color{k} = scale(km{k}, hair_f_weight{k})
fiber{k} = normalize({_world(f"o{k}")})
"""


def _hair_roughness(a: str) -> str:
    """Cauchy width of the hair lobe for D_alpha: asin(0.5 a / sqrt(1 - a^2)) in [0.001, 1] (the Cauchy
    then has the integral of D_alpha at equal peak for a sharp lobe)."""
    return f"min(max(asin(min(0.5 * {a} / sqrt(max(1 - {a} * {a}, 0.000001)), 1)), 0.001), 1)"


def _hair_peak(r: str, th: str, cth: str, rv: str | None = None) -> str:
    """Peak of Cycles' hair transmission (roughness r, azimuthal roughness rv, None: 1) at theta_h = 0:
    1 / (2 rv atan(pi / (2 rv))) / (2 r (atan((pi/2 + th) / 2r) - atan((th - pi/2) / 2r)) cos th)."""
    half = math.pi / 2
    azimuth = repr(1.0 / (2.0 * math.atan(half))) if rv is None else f"(1 / (2 * {rv} * atan({half!r} / {rv})))"
    return (f"({azimuth} / (2 * {r} * (atan(({half!r} + {th}) / (2 * {r}))"
            f" - atan(({th} - {half!r}) / (2 * {r}))) * {cth}))")


# Per-layer parameters (gaps: alpha 1, T 0) and the view-side quantities both lobes share.
_PARAMS = """
wi = vec(dot(Incoming, tangent), dot(Incoming, bitangent), dot(Incoming, Normal))
wiz = max(z(wi), 0.0001)
piz = {pi} * wiz
"""
_LAYER_PARAMS = """
y{k} = y{k}w + y{k}f
n{k}t = vadd(vadd(scale(w_n, y{k}w), scale(f_n, y{k}f)), vec(0, 0, 1 - y{k}))
o{k}t = vadd(vadd(scale(w_o, y{k}w), scale(f_o, y{k}f)), vec(0, 1 - y{k}, 0))
a{k} = y{k}w * roughness_warp + y{k}f * roughness_weft + 1 - y{k}
am{k} = y{k}w * roughness_multiple_warp + y{k}f * roughness_multiple_weft + 1 - y{k}
T{k} = y{k}w * thickness_warp * w_tension + y{k}f * thickness_weft * f_tension
Tm{k} = y{k}w * thickness_multiple_warp * w_tension + y{k}f * thickness_multiple_weft * f_tension
fw{k} = y{k}w * forward_scattering_warp + y{k}f * forward_scattering_weft
ks{k} = vadd(scale(ks_warp, y{k}w{w_bright}), scale(ks_weft, y{k}f{f_bright}))
km{k} = vadd(scale(km_warp, y{k}w{w_bright}), scale(km_weft, y{k}f{f_bright}))
ci{k} = dot(wi, vec(x(o{k}t), y(o{k}t), z(o{k}t) * mirror))
Ai{k} = {sigma} / wiz
att{k} = exp(0 - T{k} * Ai{k})
"""

# The yarn variation's brightness of the yarn seen, on the diffuse albedos (after shader_dye.DIFFUSE).
_SEEN_BRIGHTNESS = """
seen_bright = front_warp_share * w_bright + front_weft_share * f_bright + 1 - front_warp_share - front_weft_share
kd_r = scale(kd_r, seen_bright)
kd_t = scale(kd_t, seen_bright)
"""

_DIFFUSE = """
nm = vadd(scale(n0, y0), scale(n1, 1 - y0))
n_main = normalize({n_main})
other = y0 * y1 * max(dot(wi, n1), 0) + 1 - y0 * y1
diffuse_flat = scale(kd_r, 1 - diffuse_normal_weight)
diffuse_yarn = scale(kd_r, diffuse_normal_weight)
yarn_cos = max(dot(wi, nm), 0) / wiz
yarn_t = diffuse_normal_weight * other * yarn_cos
translucent_diffuse = vadd(scale(kd_t, 1 - diffuse_normal_weight), scale(kd_t, yarn_t))
translucent = vadd(translucent_diffuse, vadd(scale(km0, glow_m0 * least0), scale(km1, glow_m1 * least1)))
"""


def _permute(name: str, x: str) -> str:
    """Lines giving ``name`` = R(x) of core/variation.py: ((x + offset) mod p)^3 mod p."""
    v = declarations.variation()
    m = repr(float(v.HASH_MODULUS))
    return (f"{name}_y = mod({x} + {float(v.HASH_OFFSET)!r}, {m})\n"
            f"{name} = mod(mod({name}_y * {name}_y, {m}) * {name}_y, {m})\n")


def _hash_key(name: str, h: str, key: str) -> str:
    """Lines giving ``name`` = R(R(h + lo(key)) + hi(key)) (the key split, ``key_lo``/``key_hi``, given)."""
    return _permute(f"{name}_a", f"{h} + {key}_lo") + _permute(name, f"{name}_a + {key}_hi")


def _split(key: str, value: str) -> str:
    """Lines giving ``key_lo`` = value mod p and ``key_hi`` = ((value - lo) / p) mod p."""
    m = repr(float(declarations.variation().HASH_MODULUS))
    return f"{key}_lo = mod({value}, {m})\n{key}_hi = mod(({value} - {key}_lo) / {m}, {m})\n"


def _smooth(name: str, stream: int, x: str, length: str, yarn: str | None) -> str:
    """Lines giving ``name`` = g(x) of core/variation.py at knots every ``length`` (keys: ``yarn``, the knot)."""
    v = declarations.variation()
    m = float(v.HASH_MODULUS)
    text = f"{name}_t = {x} / {length}\n{name}_j0 = floor({name}_t)\n{name}_f = {name}_t - {name}_j0\n"
    text += f"{name}_w = {name}_f * {name}_f * (3 - 2 * {name}_f)\n{name}_j1 = {name}_j0 + 1\n"
    starts = [repr(float(v.start(stream, c))) for c in (0, 1)]
    if yarn is not None:  # the yarn's key first: shared by both knots
        text += _split(f"{name}_k", yarn)
        for c in (0, 1):
            text += _hash_key(f"{name}_p{c}", starts[c], f"{name}_k")
        starts = [f"{name}_p{c}" for c in (0, 1)]
    for knot in ("j0", "j1"):
        text += _split(f"{name}_{knot}", f"{name}_{knot}")
        for c in (0, 1):
            text += _hash_key(f"{name}_{knot}h{c}", starts[c], f"{name}_{knot}")
        text += (f"{name}_{knot}g = (({name}_{knot}h0 + {name}_{knot}h1 + 1) / {m!r} - 1) * {v.GAUSS_SCALE!r}\n")
    return text + (f"{name} = ((1 - {name}_w) * {name}_j0g + {name}_w * {name}_j1g) / "
                   f"sqrt((1 - {name}_w) * (1 - {name}_w) + {name}_w * {name}_w)\n")


def variation_text() -> str:
    """The yarn variation's lines (core/variation.py): per yarn family (``w_``, ``f_``) the varied gap scale
    ``xi``, the slide ``shift`` (tile units), and the ``thick`` and ``bright`` factors, from the yarn's
    index ``k_warp`` / ``k_weft`` and position ``p_warp`` / ``p_weft``."""
    v = declarations.variation()
    text = """v_right = X + floor(su) * tile_w
v_down = Y - floor(sv) * tile_h
k_warp = (floor(su) + floor((X - warp_off) / tile_w)) * cols + col
k_weft = (floor((Y - weft_off) / tile_h) - floor(sv)) * rows + row
p_warp = v_down / weft_p
p_weft = v_right / warp_p
"""
    for family, (name, p, width) in enumerate((("warp", "w_", "warp_w"), ("weft", "f_", "weft_w"))):
        g = {}
        for kind in v.KINDS:
            amplitude, length = f"{v.amplitude_name(kind)}_{name}", f"{v.length_name(kind)}_{name}"
            along = kind not in v.ACROSS_YARNS
            text += _smooth(f"{p}g_{kind}", v.stream(kind, family), f"p_{name}" if along else f"k_{name}", length,
                            f"k_{name}" if along else None)
            g[kind] = f"{amplitude} * {p}g_{kind}"
        text += (f"{p}xi = max(gap_scale_{name} * (1 + {g['width']} + {g['slub']}), {v.XI_MIN!r})\n"
                 f"{p}shift = {g['spacing']} * {width}\n"
                 f"{p}thick = max(1 + {g['thickness']} + {g['slub']}, 0)\n"
                 f"{p}bright = max(1 + {g['brightness']}, 0)\n")
    return text


# Names the program gives the header values (shader_weave.FALLBACK_HEADER).
_HEADER_NAMES = {"warp_width": "warp_w", "warp_pitch": "warp_p", "warp_offset": "warp_off", "weft_width": "weft_w",
                 "weft_pitch": "weft_p", "weft_offset": "weft_off", "tile_width": "tile_w", "tile_height": "tile_h",
                 "matrix_row0": "mrow0", "warp_row0": "wrow0", "weft_row0": "frow0"}


def program(variation: bool = FALLBACK_VARIATION) -> list[tuple[str, str]]:
    """The fallback program: (name, expression) assignments, tables filled in; ``variation``: with the
    yarn variation's lines (:func:`variation_text`)."""
    atlases = shader_weave.fallback_atlases()
    sizes = {f"A_{name}_w": w for name, (w, h, _) in atlases.items()}
    sizes.update({f"A_{name}_h": h for name, (w, h, _) in atlases.items()})
    header = "\n".join(f"{_HEADER_NAMES.get(name, name)} = pick(pattern, {', '.join(repr(v) for v in values)})"
                        for name, values in shader_weave.fallback_header().items())
    def varied(name: str, p: str) -> dict:  # the yarn variation's factors in a yarn's lines, or none
        if not variation:
            return dict(xi=f"gap_scale_{name}", shift="", thick="")
        return dict(xi=f"{p}xi", shift=f" - {p}shift", thick=f" * {p}thick")

    yarns = {name: _YARN.format(name=name, pi=repr(math.pi), deg=repr(math.pi / 180.0), A_w=sizes[f"A_{name}_w"],
                                A_h=sizes[f"A_{name}_h"], **fields, **varied(name, fields["p"]))
             for name, fields in _YARNS.items()}
    text = _GEOMETRY.format(header=header, variation=variation_text() if variation else "", **yarns, **sizes)
    text += shader_dye.program_text() + _PARAMS.format(pi=repr(math.pi))
    bright = dict(w_bright=" * w_bright", f_bright=" * f_bright") if variation else dict(w_bright="", f_bright="")
    text += "".join(_LAYER_PARAMS.format(k=k, sigma=_sigma(f"ci{k}", f"a{k}"), **bright) for k in LAYERS)
    text += "".join(_layer(k) + shader_eevee.layer_text(k, TT_CONE) for k in LAYERS)
    text += shader_dye.DIFFUSE + (_SEEN_BRIGHTNESS if variation else "")
    text += _DIFFUSE.format(n_main=_world("nm")) + shader_eevee.closures_text()
    return shader_program.parse(text)


def run(builder, env: dict, variation: bool = FALLBACK_VARIATION) -> dict:
    """The fallback program evaluated with ``builder`` from the inputs ``env`` (shader_program.run)."""
    return shader_program.run(builder, env, program(variation))
