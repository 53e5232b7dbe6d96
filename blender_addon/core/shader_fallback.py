"""The standard-node fallback of the Woven Fabric node group, as a small expression program.

EEVEE and GPU Cycles (without OptiX OSL) cannot run ``shaders/woven_fabric.osl``; the node group
then uses a fallback built from Math / Vector Math / Image Texture nodes that computes the same
weave geometry (spec section 3, like ``backend/model/layers.py``) from UV: band tests, the interlacing
matrix and the backend's interval tables (read from the float atlases of
:func:`shader_weave.fallback_atlases`; the per-preset constants are picked by the pattern with Math
nodes, ``pick``), gap scaling, the visible yarn (front layer, or the back
layer through a gap in front), its bent-cylinder normal and twisted fiber direction with height
scaling. It skips the tension and noise and shades with standard BSDFs (see scene/node_group.py).

The program is plain text, one assignment per line, in a tiny expression language (Python
syntax): ``+ - * / **``, unary ``-``, numbers, names, and the functions listed in
:data:`FUNCTIONS`. :func:`run` evaluates it with any *builder*: ``scene/node_group.py`` passes one
that creates shader nodes; ``tests/test_shader.py`` passes one that evaluates it on numpy arrays,
to check the fallback geometry against the backend without Blender.
"""
from __future__ import annotations

import ast
import math

from . import shader_weave

# name -> (number of arguments, kind): "math" ops map to the Math node, "vec" ops to Vector Math.
FUNCTIONS = {
    "floor": (1, "math", "FLOOR"), "fract": (1, "math", "FRACT"), "abs": (1, "math", "ABSOLUTE"),
    "sqrt": (1, "math", "SQRT"), "sin": (1, "math", "SINE"), "cos": (1, "math", "COSINE"),
    "exp": (1, "math", "EXPONENT"), "min": (2, "math", "MINIMUM"), "max": (2, "math", "MAXIMUM"),
    "mod": (2, "math", "FLOORED_MODULO"), "lt": (2, "math", "LESS_THAN"), "gt": (2, "math", "GREATER_THAN"),
    "pow": (2, "math", "POWER"),
    "vec": (3, "combine", None), "x": (1, "separate", 0), "y": (1, "separate", 1), "z": (1, "separate", 2),
    "dot": (2, "vec", "DOT_PRODUCT"), "cross": (2, "vec", "CROSS_PRODUCT"), "normalize": (1, "vec", "NORMALIZE"),
    "vadd": (2, "vec", "ADD"), "vsub": (2, "vec", "SUBTRACT"), "vmul": (2, "vec", "MULTIPLY"),
    "scale": (2, "vec", "SCALE"), "vpow": (2, "vec", "POWER"),
    "lookup": (3, "lookup", None),
    "pick": (None, "pick", None),
}
BINARY = {ast.Add: "ADD", ast.Sub: "SUBTRACT", ast.Mult: "MULTIPLY", ast.Div: "DIVIDE", ast.Pow: "POWER"}

INPUTS = ("pattern", "tiles_warp", "tiles_weft", "uv_scale", "gap_scale_warp", "gap_scale_weft",
          "twist_deg_warp", "twist_deg_weft", "height_scale_warp", "height_scale_weft", "UV", "Tangent", "Normal")
OUTPUTS = ("coverage", "vis_warp", "vis_weft", "normal", "fiber", "across", "fiber_normal")

_PROGRAM = """
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
in_warp = lt(x_in, warp_w)
in_weft = lt(y_in, weft_w)
over = x(lookup("matrix", (col + 0.5) / {A_matrix_w}, (mrow0 + row + 0.5) / {A_matrix_h}))
we = lookup("warp", (col + 0.5) / {A_warp_w}, (wrow0 + 2 * row + 1.5 - in_weft) / {A_warp_h})
w_off = mod(yr - x(we) + tile_h / 2, tile_h) - tile_h / 2
w_u = (0 - w_off) / (y(we) / 2) * umax_warp * (1 - 2 * z(we))
w_a = x_in - warp_w / 2
w_v = w_a * {pi} / (warp_w * gap_scale_warp)
w_ok = lt(abs(w_a), warp_w * gap_scale_warp / 2)
fe = lookup("weft", (row + 0.5) / {A_weft_w}, (frow0 + 2 * col + 1.5 - in_warp) / {A_weft_h})
f_off = mod(xr - x(fe) + tile_w / 2, tile_w) - tile_w / 2
f_u = f_off / (y(fe) / 2) * umax_weft * (1 - 2 * z(fe))
f_a = y_in - weft_w / 2
f_v = f_a * {pi} / (weft_w * gap_scale_weft)
f_ok = lt(abs(f_a), weft_w * gap_scale_weft / 2)
front_warp = in_warp * max(1 - in_weft, over) * w_ok
front_weft = in_weft * max(1 - in_warp, 1 - over) * f_ok
back_warp = in_warp * in_weft * (1 - over) * w_ok
back_weft = in_warp * in_weft * over * f_ok
open0 = 1 - front_warp - front_weft
vis_warp = front_warp + open0 * back_warp
vis_weft = front_weft + open0 * back_weft
coverage = vis_warp + vis_weft
uu = vis_warp * w_u + vis_weft * f_u
vv = vis_warp * w_v + vis_weft * f_v
psi = (vis_warp * twist_deg_warp + vis_weft * twist_deg_weft) * {deg}
beta = vis_warp * height_scale_warp + vis_weft * height_scale_weft + 1 - coverage
s_u = sin(uu)
c_u = cos(uu)
s_v = sin(vv)
c_v = cos(vv)
s_p = sin(psi)
c_p = cos(psi)
n1 = s_v
n2 = s_u * c_v
o1 = 0 - c_v * s_p
o2 = c_u * c_p + s_u * s_v * s_p
nx = vis_weft * n2 + (1 - vis_weft) * n1
ny = (1 - vis_weft) * n2 - vis_weft * n1
ox = vis_weft * o2 + (1 - vis_weft) * o1
oy = (1 - vis_weft) * o2 - vis_weft * o1
n_local = normalize(vec(beta * nx, beta * ny, c_u * c_v))
o_local = normalize(vec(ox, oy, beta * (c_u * s_v * s_p - s_u * c_p)))
tangent = normalize(vsub(Tangent, scale(Normal, dot(Tangent, Normal))))
bitangent = cross(Normal, tangent)
normal = normalize(vadd(vadd(scale(tangent, x(n_local)), scale(bitangent, y(n_local))), scale(Normal, z(n_local))))
fiber = normalize(vadd(vadd(scale(tangent, x(o_local)), scale(bitangent, y(o_local))), scale(Normal, z(o_local))))
fiber_normal = normalize(vsub(Normal, scale(fiber, dot(Normal, fiber))))
across = normalize(cross(fiber, fiber_normal))
"""


# Names the program gives the header values (shader_weave.FALLBACK_HEADER).
_HEADER_NAMES = {"warp_width": "warp_w", "warp_pitch": "warp_p", "warp_offset": "warp_off", "weft_width": "weft_w",
                 "weft_pitch": "weft_p", "weft_offset": "weft_off", "tile_width": "tile_w", "tile_height": "tile_h",
                 "matrix_row0": "mrow0", "warp_row0": "wrow0", "weft_row0": "frow0"}


def program() -> list[tuple[str, str]]:
    """The fallback geometry program: (name, expression) assignments, tables filled in."""
    atlases = shader_weave.fallback_atlases()
    sizes = {f"A_{name}_w": w for name, (w, h, _) in atlases.items()}
    sizes.update({f"A_{name}_h": h for name, (w, h, _) in atlases.items()})
    header = "\n".join(f"{_HEADER_NAMES.get(name, name)} = pick(pattern, {', '.join(repr(v) for v in values)})"
                        for name, values in shader_weave.fallback_header().items() if name != "s_min")
    return parse(_PROGRAM.format(header=header, pi=repr(math.pi), deg=repr(math.pi / 180.0), **sizes))


def parse(text: str) -> list[tuple[str, str]]:
    """(name, expression) of each ``name = expression`` line of a program."""
    out = []
    for line in text.strip().splitlines():
        name, expr = line.split("=", 1)
        out.append((name.strip(), expr.strip()))
    return out


def run(builder, env: dict, assignments=None) -> dict:
    """Evaluates the program with `builder` starting from `env` (inputs); returns the final env.

    A builder provides: ``const(x)``, ``math(op, *args)`` (Math node ops), ``vec(op, *args)``
    (Vector Math ops; DOT_PRODUCT returns a scalar), ``combine(x, y, z)``, ``separate(v, i)``,
    ``lookup(atlas_name, u, v)`` (an RGB value, as a vector) and ``pick(index, values)``
    (``values[round(index)]``, the index clamped to the list).
    """
    env = dict(env)
    for name, expr in assignments or program():
        env[name] = _emit(ast.parse(expr, mode="eval").body, builder, env)
    return env


def _emit(node, b, env):
    if isinstance(node, ast.Constant):
        if isinstance(node.value, str):
            return node.value
        return b.const(float(node.value))
    if isinstance(node, ast.Name):
        if node.id not in env:
            raise NameError(f"fallback program: unknown name {node.id!r}")
        return env[node.id]
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        return b.math("SUBTRACT", b.const(0.0), _emit(node.operand, b, env))
    if isinstance(node, ast.BinOp) and type(node.op) in BINARY:
        return b.math(BINARY[type(node.op)], _emit(node.left, b, env), _emit(node.right, b, env))
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in FUNCTIONS:
        n, kind, op = FUNCTIONS[node.func.id]
        if kind == "pick":
            if len(node.args) < 2 or not all(isinstance(a, ast.Constant) for a in node.args[1:]):
                raise TypeError("fallback program: pick takes an index and constant values")
            return b.pick(_emit(node.args[0], b, env), [float(a.value) for a in node.args[1:]])
        if len(node.args) != n:
            raise TypeError(f"fallback program: {node.func.id} takes {n} arguments")
        args = [_emit(a, b, env) for a in node.args]
        if kind == "math":
            return b.math(op, *args)
        if kind == "vec":
            return b.vec(op, *args)
        if kind == "combine":
            return b.combine(*args)
        if kind == "separate":
            return b.separate(args[0], op)
        if kind == "lookup":
            return b.lookup(*args)
    raise SyntaxError(f"fallback program: unsupported expression {ast.dump(node)}")
