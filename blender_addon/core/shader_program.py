"""The tiny expression language of the standard-node fallback's program (no bpy).

A program is plain text, one assignment per line (Python syntax): ``+ - * / **``, unary ``-``,
numbers, names, and the functions of :data:`FUNCTIONS`. :func:`run` evaluates it with any
*builder*: ``scene/fallback_group.py`` passes one that creates shader nodes, the tests one that
evaluates it on numpy arrays (to check the fallback against the backend without Blender). The
programs themselves: core/shader_fallback.py (geometry and Cycles' closures), core/shader_dye.py
(colour) and core/shader_eevee.py (EEVEE's closures).
"""
from __future__ import annotations

import ast

# name -> (number of arguments, kind, op): "math" ops map to the Math node, "vec" ops to Vector Math,
# "hsv" to the Hue/Saturation/Value node (colour, hue input, saturation, value; factor 1).
FUNCTIONS = {
    "floor": (1, "math", "FLOOR"), "fract": (1, "math", "FRACT"), "abs": (1, "math", "ABSOLUTE"),
    "sqrt": (1, "math", "SQRT"), "sin": (1, "math", "SINE"), "cos": (1, "math", "COSINE"),
    "asin": (1, "math", "ARCSINE"), "atan": (1, "math", "ARCTANGENT"),
    "exp": (1, "math", "EXPONENT"), "min": (2, "math", "MINIMUM"), "max": (2, "math", "MAXIMUM"),
    "mod": (2, "math", "FLOORED_MODULO"), "lt": (2, "math", "LESS_THAN"), "gt": (2, "math", "GREATER_THAN"),
    "pow": (2, "math", "POWER"),
    "vec": (3, "combine", None), "x": (1, "separate", 0), "y": (1, "separate", 1), "z": (1, "separate", 2),
    "dot": (2, "vec", "DOT_PRODUCT"), "cross": (2, "vec", "CROSS_PRODUCT"), "normalize": (1, "vec", "NORMALIZE"),
    "vadd": (2, "vec", "ADD"), "vsub": (2, "vec", "SUBTRACT"), "vmul": (2, "vec", "MULTIPLY"),
    "vdiv": (2, "vec", "DIVIDE"), "vmax": (2, "vec", "MAXIMUM"),
    "scale": (2, "vec", "SCALE"), "vpow": (2, "vec", "POWER"),
    "hsv": (4, "hsv", None),
    "lookup": (3, "lookup", None),
    "pick": (None, "pick", None),
}
BINARY = {ast.Add: "ADD", ast.Sub: "SUBTRACT", ast.Mult: "MULTIPLY", ast.Div: "DIVIDE", ast.Pow: "POWER"}


def parse(text: str) -> list[tuple[str, str]]:
    """(name, expression) of each ``name = expression`` line of a program (blank lines skipped)."""
    out = []
    for line in text.strip().splitlines():
        if line.strip():
            name, expr = line.split("=", 1)
            out.append((name.strip(), expr.strip()))
    return out


def run(builder, env: dict, assignments) -> dict:
    """Evaluates the assignments with `builder` starting from `env` (inputs); returns the final env.

    A builder provides: ``const(x)``, ``math(op, *args)`` (Math node ops), ``vec(op, *args)``
    (Vector Math ops; DOT_PRODUCT returns a scalar), ``combine(x, y, z)``, ``separate(v, i)``,
    ``hsv(colour, hue, saturation, value)``, ``lookup(atlas_name, u, v)`` (an RGB value, as a vector)
    and ``pick(index, values)`` (``values[round(index)]``, the index clamped to the list).
    """
    env = dict(env)
    for name, expr in assignments:
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
        return _emit_call(node, b, env)
    raise SyntaxError(f"fallback program: unsupported expression {ast.dump(node)}")


def _emit_call(node, b, env):
    """A call of one of :data:`FUNCTIONS` (checked by the caller) as the builder's node."""
    n, kind, op = FUNCTIONS[node.func.id]
    if kind == "pick":
        if len(node.args) < 2 or not all(isinstance(a, ast.Constant) for a in node.args[1:]):
            raise TypeError("fallback program: pick takes an index and constant values")
        return b.pick(_emit(node.args[0], b, env), [float(a.value) for a in node.args[1:]])
    if len(node.args) != n:
        raise TypeError(f"fallback program: {node.func.id} takes {n} arguments")
    args = [_emit(a, b, env) for a in node.args]
    if kind in ("math", "vec"):
        return getattr(b, kind)(op, *args)
    if kind == "separate":
        return b.separate(args[0], op)
    return getattr(b, kind)(*args)  # combine, hsv, lookup
