"""The standard-node fallback's program evaluated on numpy arrays (no bpy): what its nodes compute,
for the tests (tests/test_shader.py, tests/test_dye.py) and the EEVEE model (tools/eevee_model.py).

:class:`NumpyBuilder` is a builder for core/shader_program.py (scalars: (S,), vectors: (3, S)),
doing what Blender's Math, Vector Math, Hue/Saturation/Value and closest-interpolated Image Texture
nodes do; :func:`fallback_env` gives the program's inputs for a parameter set at points of the
capture rig's plane.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from backend.core.rig import DEFAULT_RIG  # noqa: E402  (torch-free)
from blender_addon.core import shader_params, shader_weave  # noqa: E402


def _normalize(v):
    n = np.sqrt((v * v).sum(0))
    return np.where(n > 0, v / np.where(n > 0, n, 1), 0.0)


def _safe_divide(p, q):
    return np.where(q != 0, p / np.where(q != 0, q, 1), 0.0)


MATH = {
    "ADD": lambda p, q: p + q, "SUBTRACT": lambda p, q: p - q, "MULTIPLY": lambda p, q: p * q,
    "DIVIDE": _safe_divide, "POWER": lambda p, q: np.power(p, q), "FLOOR": np.floor,
    "FRACT": lambda p: p - np.floor(p), "ABSOLUTE": np.abs, "SQRT": lambda p: np.sqrt(np.maximum(p, 0)),
    "SINE": np.sin, "COSINE": np.cos, "ARCSINE": lambda p: np.arcsin(np.clip(p, -1, 1)), "ARCTANGENT": np.arctan,
    "EXPONENT": np.exp, "MINIMUM": np.minimum, "MAXIMUM": np.maximum,
    "FLOORED_MODULO": lambda p, q: np.where(q != 0, p - q * np.floor(_safe_divide(p, q)), 0.0),
    "LESS_THAN": lambda p, q: (p < q).astype(np.float64),
    "GREATER_THAN": lambda p, q: (p > q).astype(np.float64),
}
VECTOR = {
    "DOT_PRODUCT": lambda p, q: (p * q).sum(0),
    "CROSS_PRODUCT": lambda p, q: np.stack([p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2],
                                            p[0] * q[1] - p[1] * q[0]]),
    "NORMALIZE": _normalize, "ADD": lambda p, q: p + q, "SUBTRACT": lambda p, q: p - q,
    "MULTIPLY": lambda p, q: p * q, "DIVIDE": _safe_divide, "MAXIMUM": np.maximum,
    "SCALE": lambda p, s: p * s, "POWER": lambda p, q: np.power(p, q),
}


def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    """Blender's rgb_to_hsv (Cycles util/color.h) on (3, S) arrays: h in [0, 1)."""
    r, g, b = rgb
    cmax, cmin = rgb.max(0), rgb.min(0)
    delta = cmax - cmin
    s = np.where(cmax != 0, delta / np.where(cmax != 0, cmax, 1), 0.0)
    c = (cmax - rgb) / np.where(delta != 0, delta, 1)
    h = np.where(r == cmax, c[2] - c[1], np.where(g == cmax, 2 + c[0] - c[2], 4 + c[1] - c[0])) / 6
    h = np.where(s != 0, np.where(h < 0, h + 1, h), 0.0)
    return np.stack([h, s, cmax])


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """Blender's hsv_to_rgb on (3, S) arrays."""
    h, s, v = hsv
    h6 = np.where(h == 1, 0.0, h) * 6
    i = np.floor(h6)
    f = h6 - i
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    table = [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)]
    out = np.stack(table[5])
    for k in range(4, -1, -1):
        out = np.where(i == k, np.stack(table[k]), out)
    return np.where(s != 0, out, np.stack([v, v, v]))


def hue_saturation_value(colour, hue, saturation, value) -> np.ndarray:
    """Blender's Hue/Saturation/Value node at factor 1 (svm/hsv.h): hue input 0.5 is no turn."""
    h, s, v = rgb_to_hsv(np.asarray(colour, dtype=np.float64))
    h, s, v = np.broadcast_arrays(np.mod(h + hue + 0.5, 1.0), np.clip(s * saturation, 0, 1), v * value)
    hsv = np.stack([h, s, v])
    return np.maximum(hsv_to_rgb(hsv), 0.0)


class NumpyBuilder:
    """Evaluates the program on numpy arrays (scalars: (S,), vectors: (3, S)), like the nodes do."""

    def __init__(self):
        self.atlases = {name: (w, h, np.asarray(px, dtype=np.float64).reshape(h, w, 3))
                        for name, (w, h, px) in shader_weave.fallback_atlases().items()}

    def const(self, x):
        return np.float64(x)

    def math(self, op, *a):
        return MATH[op](*a)

    def vec(self, op, *a):
        return VECTOR[op](*a)

    def combine(self, x, y, z):
        v = np.stack(np.broadcast_arrays(x, y, z)).astype(np.float64)
        return v.reshape(3, 1) if v.ndim == 1 else v  # a constant vector broadcasts over the samples

    def separate(self, v, i):
        return v[i]

    def hsv(self, colour, hue, saturation, value):
        return hue_saturation_value(colour, hue, saturation, value)

    def pick(self, index, values):
        return np.asarray(values)[np.clip(np.round(index), 0, len(values) - 1).astype(int)]

    def lookup(self, name, u, v):
        w, h, img = self.atlases[name]
        u, v = np.broadcast_arrays(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))
        px = np.clip(np.floor(u * w), 0, w - 1).astype(int)
        py = np.clip(np.floor(v * h), 0, h - 1).astype(int)
        return np.moveaxis(img[py, px], -1, 0)


def fallback_env(params: dict, x, y, wi, extra: dict | None = None) -> dict:
    """The program's inputs for a params.json dict at rig points (x, y) seen from directions wi (3, S);
    ``extra``: socket name -> value for the sockets params.json has none of (dye, stripes)."""
    S = len(x)
    values = dict(shader_params.socket_values(params), **(extra or {}))
    env = {}
    for s in shader_params.socket_specs():
        v = values.get(s.name, s.default)
        env[s.osl] = np.asarray(v, dtype=np.float64).reshape(3, 1) if isinstance(v, (tuple, list)) else np.float64(v)
    env.update(UV=np.stack([x / 10, y / 10 + 1, np.zeros(S)]), Tangent=np.tile([[1.0], [0.0], [0.0]], S),
               Normal=np.tile([[0.0], [0.0], [1.0]], S), Incoming=wi, Backfacing=np.zeros(S))
    return env


def rig_points(rng, S):
    """S random points of the rig's visible square and the unit directions to the camera there."""
    V = DEFAULT_RIG.view_size
    x, y = rng.uniform(0, V, S), rng.uniform(-V, 0, S)
    wi = np.asarray(DEFAULT_RIG.camera_position(), dtype=np.float64)[:, None] - np.stack([x, y, np.zeros(S)])
    return x, y, wi / np.linalg.norm(wi, axis=0)
