"""A slow, literal reference of the forward model (spec sections 3 and 4), for tests.

Every formula is written the way the spec states it, without the fast path's rewrites:
- the segment a point lies in is found by walking along its yarn from band edge to band edge,
  and the tension by listing all segments of that yarn;
- directions are expressed in the fiber frame (n, b = o x n, o) and sigma, D use all three
  components; G uses E1/E0 and "divide by 1 if the sum is 0"; ASGGX builds theta_i, theta_o with
  atan2 and the half vector h' explicitly;
- height scaling keeps o perpendicular with the literal k = -(n_z o_z) / (n_x o_x + n_y o_y);
- yarn variation (backend/core/variation.py): the yarn's plane-wide index straight from its band's
  position over the plane, the plain-Python hash, and each factor written where the spec's quantity is.

Geometry is plain Python per point; the BSDF is float64 torch, vectorised over points, so that
values *and* gradients can be compared with :mod:`backend.model.bsdf`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from backend.core import variation as yarn_variation
from backend.core.options import RenderOptions
from backend.core.params import FabricParams
from backend.core.weave import BACK, FRONT, WARP, WEFT, Weave

GAP = 2


@dataclass
class PointLayer:
    yarn: int
    u: float = 0.0
    v: float = 0.0
    mu: float = 0.0
    flat: bool = False
    thickness: float = 1.0     # yarn variation: factor on T and T_m
    brightness: float = 1.0    # yarn variation: factor on the albedos


# -- weave geometry --------------------------------------------------------------------------
def _pieces(weave: Weave, yarn: int, index: int):
    """Elementary stretches (start, end, layer) along a yarn, between consecutive band edges."""
    width, pitch, _ = weave.band(WEFT if yarn == WARP else WARP)
    over = weave.over(yarn, index)
    pieces = []
    for k, on_top in enumerate(over):
        pieces.append((k * pitch, k * pitch + width, FRONT if on_top else BACK))
        if width < pitch:
            pieces.append((k * pitch + width, (k + 1) * pitch, FRONT))
    return pieces, len(over) * pitch


def _all_segments(weave: Weave, yarn: int, index: int):
    """Segments [(start, length, layer)] of one yarn, by walking its pieces once around."""
    pieces, period = _pieces(weave, yarn, index)
    n = len(pieces)
    starts = [k for k in range(n) if pieces[k][2] != pieces[k - 1][2]]
    if not starts:
        return [(0.0, period, pieces[0][2])], period
    segments = []
    for s in starts:
        length, k = 0.0, s
        while True:
            length += pieces[k][1] - pieces[k][0]
            k = (k + 1) % n
            if pieces[k][2] != pieces[s][2]:
                break
        segments.append((pieces[s][0], length, pieces[s][2]))
    return segments, period


def _wrap(x: float, period: float) -> float:
    """x wrapped into [-period/2, period/2)."""
    return (x + period / 2) % period - period / 2


def _yarn_point(weave: Weave, yarn: int, index: int, along: float, across: float, xi: float, varied=None):
    segments, period = _all_segments(weave, yarn, index)
    longest = max(length for _, length, _ in segments)
    tension = [0.0 if length >= longest - 1e-9 else 1.0 for _, length, _ in segments]
    centres = [start + length / 2 for start, length, _ in segments]
    if len(segments) == 1:
        s = 0
    else:
        s = next(k for k, (start, length, _) in enumerate(segments) if (along - start) % period < length)
    _, length, layer = segments[s]
    offset = _wrap(along - centres[s], period)
    n = len(segments)
    neighbour = (s - 1) % n if offset < 0 else (s + 1) % n
    # Adjacent segments' centres are half of each length apart (a yarn of one segment: a period).
    distance = (length + segments[neighbour][1]) / 2 if n > 1 else period
    mu = tension[s] + (tension[neighbour] - tension[s]) * abs(offset) / distance
    width = weave.band(yarn)[0]
    umax = math.radians(weave.umax_deg[yarn])
    along = -offset if yarn == WARP else offset  # up the image for a warp, right for a weft
    u = (along / (length / 2)) * umax
    if layer == BACK:
        u = -u
    thickness = brightness = 1.0
    if varied is not None:  # the yarn's varied width, its centre line moved across
        xi, shift, thickness, brightness = varied
        across = across - shift
    v = across * math.pi / (width * xi)
    gap = abs(across) >= width * xi / 2
    return PointLayer(yarn, u, v, mu, width * math.sin(umax) >= length, thickness, brightness), gap


def yarn_factors(params: FabricParams, family: int, k: int, p: float):
    """(xi, shift, thickness, brightness) of yarn k of a family at along-position p (crossings)."""
    def amplitude(kind):
        return getattr(params, yarn_variation.amplitude_name(kind))[family]

    def value(kind, x, *keys):
        if amplitude(kind) <= 0:
            return 0.0
        length = getattr(params, yarn_variation.length_name(kind))[family]
        return amplitude(kind) * yarn_variation.smooth(yarn_variation.stream(kind, family), x, length, *keys)

    slub = value("slub", p, k)
    xi = max(params.gap_scale[family] * (1.0 + value("width", k) + slub), yarn_variation.XI_MIN)
    shift = value("spacing", k) * params.resolved_weave.band(family)[0]
    return xi, shift, max(1.0 + value("thickness", k) + slub, 0.0), max(1.0 + value("brightness", k), 0.0)


def point_layers(weave: Weave, X: float, Y: float, gap_scale, params: FabricParams | None = None,
                 tile=(0, 0)) -> tuple[PointLayer, PointLayer]:
    """Front and back layer at tile coordinates (X, Y) (tile units); with ``params``, their yarn
    variation in tile ``tile`` = (floor(u tu), floor(v tv))."""
    xr = (X - weave.warp_offset) % weave.tile_width
    yr = (Y - weave.weft_offset) % weave.tile_height
    col = min(int(xr // weave.warp_pitch), weave.cols - 1)
    row = min(int(yr // weave.weft_pitch), weave.rows - 1)
    x_in, y_in = xr - col * weave.warp_pitch, yr - row * weave.weft_pitch
    in_warp, in_weft = x_in < weave.warp_width, y_in < weave.weft_width
    varied = [None, None]
    if params is not None:
        right = X + tile[0] * weave.tile_width   # over the plane: to the right
        down = Y - tile[1] * weave.tile_height   # down the image
        varied = [yarn_factors(params, WARP, math.floor((right - weave.warp_offset) / weave.warp_pitch),
                               down / weave.weft_pitch),
                  yarn_factors(params, WEFT, math.floor((down - weave.weft_offset) / weave.weft_pitch),
                               right / weave.warp_pitch)]
    warp, warp_gap = _yarn_point(weave, WARP, col, yr, x_in - weave.warp_width / 2, gap_scale[0], varied[0])
    weft, weft_gap = _yarn_point(weave, WEFT, row, xr, y_in - weave.weft_width / 2, gap_scale[1], varied[1])
    gap = PointLayer(GAP)
    if in_warp and in_weft:
        warp_over = weave.matrix[row][col]
        top, bottom = ((warp, warp_gap), (weft, weft_gap)) if warp_over else ((weft, weft_gap), (warp, warp_gap))
    elif in_warp:
        top, bottom = (warp, warp_gap), (gap, True)
    elif in_weft:
        top, bottom = (weft, weft_gap), (gap, True)
    else:
        top, bottom = (gap, True), (gap, True)
    return (gap if top[1] else top[0]), (gap if bottom[1] else bottom[0])


def yarn_frame(layer: PointLayer, twist_deg) -> tuple[list[float], list[float]]:
    """(n, o) in world space before height scaling (spec 3.2)."""
    if layer.yarn == GAP:
        return [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]
    if layer.flat:
        return [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]
    u, v, psi = layer.u, layer.v, math.radians(twist_deg[layer.yarn])
    n = [math.sin(v), math.sin(u) * math.cos(v), math.cos(u) * math.cos(v)]
    o = [-math.cos(v) * math.sin(psi),
         math.cos(u) * math.cos(psi) + math.sin(u) * math.sin(v) * math.sin(psi),
         -math.sin(u) * math.cos(psi) + math.cos(u) * math.sin(v) * math.sin(psi)]
    if layer.yarn == WEFT:
        n, o = [n[1], -n[0], n[2]], [o[1], -o[0], o[2]]
    return n, o


# -- BSDF (float64 torch, vectorised over points) -------------------------------------------
def _normalize(v):
    return v / torch.linalg.norm(v, dim=0, keepdim=True)


def _dot(a, b):
    return (a * b).sum(0)


def height_scaled(n, o, beta):
    """Spec 3.3 literally: n' = normalize(beta n_xy, n_z); o keeps n' . o' = 0 through k."""
    n_s = _normalize(torch.stack((beta * n[0], beta * n[1], n[2])))
    den = n_s[0] * o[0] + n_s[1] * o[1]
    k = torch.where(den == 0, torch.ones_like(den), -(n_s[2] * o[2]) / torch.where(den == 0, torch.ones_like(den), den))
    return n_s, _normalize(torch.stack((k * o[0], k * o[1], o[2])))


def _fiber_frame(w, n, b, o):
    return _dot(w, n), _dot(w, b), _dot(w, o)


def _sigma(w1, w2, w3, alpha):
    return torch.sqrt(w1 ** 2 + w2 ** 2 + alpha ** 2 * w3 ** 2)


def _ndf(w1, w2, w3, alpha):
    return 1.0 / (math.pi * alpha * (w1 ** 2 + w2 ** 2 + w3 ** 2 / alpha ** 2) ** 2)


def _cos_or_one(c):
    return torch.where(c == 0, torch.ones_like(c), c)


def _g_literal(T, a_i, a_o):
    e1 = a_i.clamp_min(0) + a_o.clamp_min(0)
    e0 = a_i.clamp_max(0) + a_o.clamp_max(0)
    total = a_i + a_o
    return (torch.exp(T * e0) - torch.exp(-T * e1)) / torch.where(total == 0, torch.ones_like(total), total)


def _forward_azimuth(wi, wo, o, k):
    """The forward scattering's wrapped Cauchy (backend.model.asggx) literally: the angle between the
    parts of wo and of -wi across the fiber, 1 where wi and wo lie on one side of the fabric."""
    def across(w):
        v = w - _dot(w, o)[None] * o
        return v / torch.linalg.norm(v, dim=0, keepdim=True).clamp_min(1e-300)

    phi = torch.arccos(_dot(across(wo), -across(wi)).clamp(-1.0, 1.0))
    factor = (1 - k ** 2) / (1 + k ** 2 - 2 * k * torch.cos(phi))
    return torch.where(wi[2] * wo[2] < 0, factor, torch.ones_like(factor))


def layer_lobes(wi, wo, n, o, alpha, T, alpha_m, T_m, ks, km, lobe: str, forward=None):
    """f_s + f_m (3, S) and att(wi), att(wo) of one layer, literally."""
    b = torch.linalg.cross(o, n, dim=0)
    wi_f, wo_f = _fiber_frame(wi, n, b, o), _fiber_frame(wo, n, b, o)
    h = wi + wo
    h_len = torch.linalg.norm(h, dim=0, keepdim=True)
    h = torch.where(h_len > 0, h / torch.where(h_len > 0, h_len, torch.ones_like(h_len)),
                    torch.tensor([[0.0], [0.0], [1.0]], dtype=h.dtype))
    h_f = _fiber_frame(h, n, b, o)
    wi_z, wo_z = _cos_or_one(wi[2]), _cos_or_one(wo[2])
    a_i, a_o = _sigma(*wi_f, alpha) / wi_z, _sigma(*wo_f, alpha) / wo_z
    f_s = ks * (_ndf(*h_f, alpha) * _g_literal(T, a_i, a_o) / (4 * wi_z.abs()))[None]
    if lobe == "asggx":
        th_i = torch.atan2(wi_f[2], torch.sqrt(wi_f[0] ** 2 + wi_f[1] ** 2))
        th_o = torch.atan2(wo_f[2], torch.sqrt(wo_f[0] ** 2 + wo_f[1] ** 2))
        th = (th_i + th_o) / 2
        d_m = _ndf(torch.cos(th), torch.zeros_like(th), torch.sin(th), alpha_m)
        if forward is not None:
            d_m = d_m * _forward_azimuth(wi, wo, o, forward)
        f_m = km * (d_m * _g_literal(T_m, a_i, a_o) / (2 * wi_z.abs()))[None]
    else:
        a_im, a_om = _sigma(*wi_f, alpha_m) / wi_z, _sigma(*wo_f, alpha_m) / wo_z
        f_m = km * (_ndf(*h_f, alpha_m) * _g_literal(T_m, a_im, a_om) / (4 * wi_z.abs()))[None]
    att_i = torch.exp(-T * _sigma(*wi_f, alpha) / wi_z.abs())
    att_o = torch.exp(-T * _sigma(*wo_f, alpha) / wo_z.abs())
    return f_s + f_m, att_i, att_o


def radiance(params: dict, weave: Weave, layers: list[list[PointLayer]], wi, lights, options: RenderOptions):
    """Radiance (3, S) for each light in ``lights`` [(wo (3, S), irradiance (S,))] and the no-yarn mask.

    params: float64 tensors by parameter name (shapes as in ParamTensors); layers[k][p]: layer k at
    point p. The first light is the front (reflection), the second the back (transmission).
    """
    count = options.layers
    twist = [float(x) for x in params["twist_deg"]]
    ks_all = params["specular_albedo"]
    km_all = torch.where(ks_all > 0, ks_all.clamp_min(1e-300) ** (1 / params["multiple_weight"]),
                         torch.zeros_like(ks_all))
    s_min = weave.s_min if options.tension else 1.0
    per_layer = []
    for k in range(count):
        pts = [layer[k] for layer in layers]
        frames = [yarn_frame(p, twist) for p in pts]
        n = torch.tensor([f[0] for f in frames], dtype=torch.float64).T
        o = torch.tensor([f[1] for f in frames], dtype=torch.float64).T
        yarn = torch.tensor([p.yarn for p in pts])
        is_yarn = yarn != GAP
        idx = yarn.clamp(max=1)

        def per_yarn(name, fill):
            return torch.where(is_yarn, params[name][idx], torch.full_like(params[name][idx], fill))

        tension = torch.tensor([(s_min + (1 - p.mu) * (1 - s_min)) * p.thickness for p in pts], dtype=torch.float64)
        bright = torch.tensor([p.brightness for p in pts], dtype=torch.float64)[None]
        none = torch.zeros(3, len(pts), dtype=torch.float64)
        beta = per_yarn("height_scale", 1.0)
        n, o = height_scaled(n, o, beta)
        lobe_args = dict(alpha=per_yarn("roughness", 1.0), T=per_yarn("thickness", 0.0) * tension,
                         alpha_m=per_yarn("roughness_multiple", 1.0), T_m=per_yarn("thickness_multiple", 0.0) * tension,
                         forward=per_yarn("forward_scattering", 0.0),
                         ks=torch.where(is_yarn[None], ks_all[idx].T * bright, none),
                         km=torch.where(is_yarn[None], km_all[idx].T * bright, none))
        per_layer.append((n, o, is_yarn, lobe_args))
    # the diffuse term's brightness: the yarn seen (front, else back through a gap in front)
    seen = [next((layer[k].brightness for k in range(count) if layer[k].yarn != GAP), 1.0) for layer in layers]
    seen = torch.tensor(seen, dtype=torch.float64)[None]
    no_yarn = torch.ones(len(layers), dtype=torch.bool)
    for _, _, is_yarn, _ in per_layer:
        no_yarn &= ~is_yarn
    out = []
    for which, (wo, irradiance) in enumerate(lights):
        lobes = []
        for n, o, is_yarn, args in per_layer:
            f, att_i, att_o = layer_lobes(wi, wo, n, o, lobe=options.multiple_lobe, **args)
            ones = torch.ones_like(att_i)
            lobes.append((torch.where(is_yarn[None], f, torch.zeros_like(f)), torch.where(is_yarn, att_i, ones),
                          torch.where(is_yarn, att_o, ones), _dot(wo, n), is_yarn))
        if which == 0:
            value = lobes[0][0] if count == 1 else lobes[0][0] + lobes[1][0] * (lobes[0][2] * lobes[0][1])[None]
        else:
            value = lobes[0][0] if count == 1 else lobes[0][0] * lobes[1][2][None] + lobes[1][0] * lobes[0][1][None]
        if options.diffuse:
            if which == 0:
                c = torch.where(lobes[0][4], lobes[0][3].clamp_min(0),
                                lobes[1][3].clamp_min(0) if count == 2 else torch.zeros_like(lobes[0][3]))
                kd = params["diffuse_reflection"]
            else:
                c = torch.ones_like(lobes[0][3])
                for _, _, _, cos_n, is_yarn in lobes:
                    c = c * torch.where(is_yarn, (-cos_n).clamp_min(0), torch.ones_like(cos_n))
                kd = params["diffuse_transmission"]
            w = params["diffuse_normal_weight"]
            diffuse = kd[:, None] * (((1 - w) * wo[2].abs() + w * c) / math.pi)[None] * seen
            value = value + torch.where(no_yarn[None], torch.zeros_like(diffuse), diffuse)
        out.append(value * irradiance[None])
    return out, no_yarn


def render_points(params: FabricParams | dict, x, y, rig, options: RenderOptions = RenderOptions(), tensors=None):
    """Reference radiance at world points (x, y lists of floats); returns (R, T, no_yarn).

    ``tensors`` may give float64 parameter tensors (e.g. requiring gradients) to use instead of
    the values of ``params``.
    """
    weave = params.resolved_weave
    if tensors is None:
        tensors = {name: torch.tensor(getattr(params, name), dtype=torch.float64)
                   for name in ("roughness", "thickness", "roughness_multiple", "thickness_multiple",
                                "forward_scattering", "height_scale", "specular_albedo", "multiple_weight",
                                "diffuse_reflection", "diffuse_transmission", "diffuse_normal_weight")}
    tensors = dict(tensors, twist_deg=torch.tensor(params.twist_deg, dtype=torch.float64))
    # A sample turned by theta about the view centre: evaluate everything in the fabric's own frame
    # (positions and directions turned back by theta), where the weave is the unrotated one.
    theta = math.radians(rig.sample_rotation_deg)
    cx, cy = rig.view_centre

    def to_fabric(vx, vy):
        return math.cos(theta) * vx + math.sin(theta) * vy, -math.sin(theta) * vx + math.cos(theta) * vy

    layers = []
    for px, py in zip(x, y):
        fx, fy = to_fabric(px - cx, py - cy)
        u, v = (cx + fx) / rig.plane_size, (cy + fy) / rig.plane_size + 1
        s = (u * params.tiles[0]) % 1.0
        t = 1.0 - (v * params.tiles[1]) % 1.0
        tile = (math.floor(u * params.tiles[0]), math.floor(v * params.tiles[1]))
        layers.append(point_layers(weave, s * weave.tile_width, t * weave.tile_height, params.gap_scale, params, tile))
    p = torch.tensor([list(x), list(y), [0.0] * len(x)], dtype=torch.float64)
    cam = torch.tensor(rig.camera_position(), dtype=torch.float64)[:, None]
    rotate_back = torch.tensor([[math.cos(theta), math.sin(theta), 0.0], [-math.sin(theta), math.cos(theta), 0.0],
                                [0.0, 0.0, 1.0]], dtype=torch.float64)
    wi = rotate_back @ _normalize(cam - p)
    lights = []
    for which in ("front", "back"):
        to_light = torch.tensor(rig.light_position(which), dtype=torch.float64)[:, None] - p
        dist2 = (to_light ** 2).sum(0)
        lights.append((rotate_back @ _normalize(to_light), rig.intensity(which) / dist2))
    (r, t), no_yarn = radiance(tensors, weave, layers, wi, lights, options)
    return r, t, no_yarn


def lattice_coefficients(image: torch.Tensor, probe) -> torch.Tensor:
    """The Hann-windowed Fourier coefficients of :class:`backend.texture.features.LatticeProbe`'s
    regions, literally: per region (i, j) and probe frequency (fx, fy),
    sum over the region of w(y) w(x) e^{-2 pi i (fx x + fy y) / size} image[y, x, c], divided by
    the region's mean. (regions^2, lattice harmonics and off-lattice probes, channels), complex128."""
    from backend.texture.lattice import turned_frequencies

    harmonics = probe.harmonics
    ms = torch.tensor([m for m, _ in harmonics] + [m + 0.5 for m, _ in harmonics], dtype=torch.float64)
    ns = torch.tensor([n for _, n in harmonics] + [n + 0.5 for _, n in harmonics], dtype=torch.float64)
    fx, fy = turned_frequencies(ms * probe.a, ns * probe.b, probe.rotation_deg, probe.skew_deg)
    image = image.to(torch.float64)
    out = []
    for i in range(probe.regions):
        for j in range(probe.regions):
            y0, y1, x0, x1 = probe.bounds[i], probe.bounds[i + 1], probe.bounds[j], probe.bounds[j + 1]
            wy = torch.hann_window(y1 - y0 + 2, periodic=False, dtype=torch.float64)[1:-1]
            wx = torch.hann_window(x1 - x0 + 2, periodic=False, dtype=torch.float64)[1:-1]
            ys, xs = torch.arange(y0, y1, dtype=torch.float64), torch.arange(x0, x1, dtype=torch.float64)
            phase = fy[:, None, None] * ys[None, :, None] + fx[:, None, None] * xs[None, None, :]
            kernel = torch.exp(-2j * math.pi * phase / probe.size) * (wy[:, None] * wx[None, :]) / (wy.sum() * wx.sum())
            patch = image[y0:y1, x0:x1]
            coeff = (kernel[..., None] * patch[None]).sum(dim=(1, 2))
            out.append(coeff / patch.mean(dim=(0, 1)).clamp_min(1e-4))
    return torch.stack(out)
