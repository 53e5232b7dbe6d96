"""The "Woven Fabric fallback" node group (bpy layer): the standard-node program of
core/shader_fallback.py built as Math / Vector Math / Environment Texture nodes, ending in the closures of
its two outputs, ``BSDF`` (Cycles without OSL) and ``EEVEE`` (see node_group.py for where they go)."""
from __future__ import annotations

import math

import bpy

from ..core import shader_fallback, shader_params
from .fallback_atlases import atlas_images
from .group_interface import sync_interface

FALLBACK_GROUP_NAME = "Woven Fabric fallback"
GROUP_MARK = "woven_fabric_group"  # on both groups: "main" or "fallback"
# The fallback group's outputs: Cycles without OSL (hair transmission closures) and EEVEE (which
# lights no hair closure on a surface: translucent ones instead, see core/shader_fallback.py).
FALLBACK_OUTPUTS = ("BSDF", "EEVEE")


class _NodeBuilder:
    """Builds the fallback program's expressions as shader nodes (see shader_program.run)."""

    def __init__(self, tree, images: dict):
        self.tree, self.images = tree, images
        self.depth: dict = {}
        self.column_rows: dict = {}
        self.separated: dict = {}
        self.steps: dict = {}

    def _place(self, node, args):
        depth = 1 + max([self.depth.get(a.as_pointer(), 0) for a in args if hasattr(a, "as_pointer")] + [0])
        row = self.column_rows.get(depth, 0)
        self.column_rows[depth] = row + 1
        node.location = (depth * 180.0, -row * 60.0)
        node.hide = True
        for out in node.outputs:
            self.depth[out.as_pointer()] = depth

    def _feed(self, socket, value):
        if isinstance(value, (int, float)):
            socket.default_value = float(value)
        elif isinstance(value, tuple):
            socket.default_value = value
        else:
            self.tree.links.new(value, socket)

    def const(self, x):
        return float(x)

    def math(self, op, *args):
        if all(isinstance(a, float) for a in args) and op in _FOLD:  # constant subexpression
            return float(_FOLD[op](*args))
        node = self.tree.nodes.new("ShaderNodeMath")
        node.operation = op
        node.use_clamp = False
        for i, a in enumerate(args):
            self._feed(node.inputs[i], a)
        self._place(node, args)
        return node.outputs[0]

    def vec(self, op, *args):
        node = self.tree.nodes.new("ShaderNodeVectorMath")
        node.operation = op
        if op == "SCALE":
            self._feed(node.inputs[0], args[0])
            self._feed(node.inputs["Scale"], args[1])
        else:
            for i, a in enumerate(args):
                self._feed(node.inputs[i], a)
        self._place(node, args)
        return node.outputs["Value"] if op == "DOT_PRODUCT" else node.outputs["Vector"]

    def combine(self, x, y, z):
        node = self.tree.nodes.new("ShaderNodeCombineXYZ")
        for i, a in enumerate((x, y, z)):
            self._feed(node.inputs[i], a)
        self._place(node, (x, y, z))
        return node.outputs[0]

    def separate(self, v, i):
        key = v.as_pointer()
        node = self.separated.get(key)
        if node is None:
            node = self.tree.nodes.new("ShaderNodeSeparateXYZ")
            self.tree.links.new(v, node.inputs[0])
            self._place(node, (v,))
            self.separated[key] = node
        return node.outputs[i]

    def hsv(self, colour, hue, saturation, value):
        node = self.tree.nodes.new("ShaderNodeHueSaturation")
        for name, arg in (("Hue", hue), ("Saturation", saturation), ("Value", value), ("Fac", 1.0),
                          ("Color", colour)):
            self._feed(node.inputs[name], arg)
        self._place(node, (colour, hue, saturation, value))
        return node.outputs["Color"]

    def pick(self, index, values):
        """values[round(index)]: a sum of steps, index > k - 1/2 adding values[k] - values[k - 1]."""
        if isinstance(index, float):
            return values[min(max(int(round(index)), 0), len(values) - 1)]
        result = values[0]
        for k in range(1, len(values)):
            if values[k] != values[k - 1]:
                result = self.math("MULTIPLY_ADD", self._step(index, k), values[k] - values[k - 1], result)
        return result

    def _step(self, index, k):
        key = (index.as_pointer(), k)
        if key not in self.steps:
            self.steps[key] = self.math("GREATER_THAN", index, k - 0.5)
        return self.steps[key]

    def lookup(self, name, u, v):
        """The atlas texel at (u, v), read by an Environment Texture node: Blender offers every Image
        Texture node of a material (in its groups too) as a texture-paint slot, and the atlases are
        lookup tables, not paint. Its equirectangular direction of azimuth pi - 2 pi u and elevation
        pi (v - 1/2) reads the texel at (u, v); u and v clamped to the first and last texel centres
        read what an Image Texture's Closest / EXTEND read (and keep the azimuth off the seam)."""
        image = self.images[name]
        width, height = image.size
        u = self.math("MINIMUM", self.math("MAXIMUM", u, 0.5 / width), 1.0 - 0.5 / width)
        v = self.math("MINIMUM", self.math("MAXIMUM", v, 0.5 / height), 1.0 - 0.5 / height)
        azimuth = self.math("MULTIPLY_ADD", u, -2.0 * math.pi, math.pi)
        elevation = self.math("MULTIPLY_ADD", v, math.pi, -0.5 * math.pi)
        level = self.math("COSINE", elevation)
        direction = self.combine(self.math("MULTIPLY", self.math("COSINE", azimuth), level),
                                 self.math("MULTIPLY", self.math("SINE", azimuth), level), self.math("SINE", elevation))
        node = self.tree.nodes.new("ShaderNodeTexEnvironment")
        node.image = image
        node.interpolation = "Closest"
        node.projection = "EQUIRECTANGULAR"
        self.tree.links.new(direction, node.inputs["Vector"])
        self._place(node, (direction,))
        return node.outputs["Color"]


_FOLD = {
    "ADD": lambda a, b: a + b, "SUBTRACT": lambda a, b: a - b, "MULTIPLY": lambda a, b: a * b,
    "DIVIDE": lambda a, b: a / b if b else 0.0, "MINIMUM": min, "MAXIMUM": max,
    "SINE": math.sin, "COSINE": math.cos, "SQRT": lambda a: math.sqrt(max(a, 0.0)), "EXPONENT": math.exp,
    "ARCTANGENT": math.atan, "POWER": lambda a, b: a ** b if a > 0 else 0.0, "MULTIPLY_ADD": lambda a, b, c: a * b + c,
}


def build_fallback_group():
    tree = bpy.data.node_groups.get(FALLBACK_GROUP_NAME)
    if tree is None:
        tree = bpy.data.node_groups.new(FALLBACK_GROUP_NAME, "ShaderNodeTree")
    tree[GROUP_MARK] = "fallback"
    sync_interface(tree, FALLBACK_OUTPUTS, readable=False)
    tree.nodes.clear()
    nodes, links = tree.nodes, tree.links
    group_in = nodes.new("NodeGroupInput")
    group_in.location = (-400, 0)
    group_out = nodes.new("NodeGroupOutput")
    uvmap = nodes.new("ShaderNodeUVMap")
    uvmap.location = (-400, 300)
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    tangent.location = (-400, 400)
    geometry = nodes.new("ShaderNodeNewGeometry")
    geometry.location = (-400, 500)

    builder = _NodeBuilder(tree, atlas_images())
    env = {s.osl: group_in.outputs[s.name] for s in shader_params.socket_specs()}
    env.update(UV=uvmap.outputs["UV"], Tangent=tangent.outputs["Tangent"], Normal=geometry.outputs["Normal"],
               Incoming=geometry.outputs["Incoming"], Backfacing=geometry.outputs["Backfacing"])
    env = shader_fallback.run(builder, env)
    x0 = 180.0 * (max(builder.column_rows) + 2)
    row = iter(range(0, -10000, -120))

    def bsdf(kind, **inputs):
        node = nodes.new(kind)
        node.location = (x0, next(row))
        for name, value in inputs.items():
            builder._feed(node.inputs[name], env[value] if isinstance(value, str) else value)
        return node

    def glossy(lobe, k):
        node = bsdf("ShaderNodeBsdfAnisotropic", Color=f"gloss_{lobe}_color{k}", Roughness=f"gloss_{lobe}_rough{k}",
                    Anisotropy=f"gloss_{lobe}_aniso{k}", Normal=f"gloss_normal{k}", Tangent=f"gloss_tangent{k}")
        node.distribution = "GGX"
        return node

    def hair(lobe, k):
        node = bsdf("ShaderNodeBsdfHair", Color=f"hair_{lobe}_color{k}", RoughnessU=f"hair_{lobe}_rough{k}",
                    RoughnessV=1.0, Offset=0.0, Tangent=f"fiber{k}")
        node.component = "Transmission"
        return node

    diffuse = [bsdf("ShaderNodeBsdfDiffuse", Color="diffuse_flat"),
               bsdf("ShaderNodeBsdfDiffuse", Color="diffuse_yarn", Normal="n_main")]
    gloss = [glossy(lobe, k) for k in shader_fallback.LAYERS for lobe in ("s", "m")]
    cycles = diffuse + gloss + [bsdf("ShaderNodeBsdfTranslucent", Color="translucent")]
    cycles += [hair(lobe, k) for k in shader_fallback.LAYERS for lobe in ("s", "m")]
    eevee_gloss = bsdf("ShaderNodeBsdfAnisotropic", Color="eevee_gloss", Roughness="eevee_gloss_rough",
                       Normal="eevee_gloss_normal")
    eevee_gloss.distribution = "GGX"
    eevee = [bsdf("ShaderNodeBsdfDiffuse", Color="eevee_diffuse", Normal="eevee_diffuse_normal"), eevee_gloss,
             bsdf("ShaderNodeBsdfTranslucent", Color="eevee_translucent", Normal="eevee_translucent_normal")]
    transparent = nodes.new("ShaderNodeBsdfTransparent")
    transparent.location = (x0 + 800, 200)
    for y, (name, closures) in enumerate(zip(FALLBACK_OUTPUTS, (cycles, eevee))):
        total = closures[0].outputs[0]
        for i, node in enumerate(closures[1:], 1):
            add = nodes.new("ShaderNodeAddShader")
            add.location = (x0 + 200 + 40 * i, -600 * y - 40 * i)
            links.new(total, add.inputs[0])
            links.new(node.outputs[0], add.inputs[1])
            total = add.outputs[0]
        mix = nodes.new("ShaderNodeMixShader")
        mix.location = (x0 + 1000, -600 * y)
        builder._feed(mix.inputs[0], env["coverage"])
        links.new(transparent.outputs[0], mix.inputs[1])
        links.new(total, mix.inputs[2])
        links.new(mix.outputs[0], group_out.inputs[name])
    group_out.location = (x0 + 1200, 0)
    return tree
