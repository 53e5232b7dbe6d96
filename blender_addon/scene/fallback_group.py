"""The "Woven Fabric fallback" node group (bpy layer): the standard-node program of
core/shader_fallback.py built as Math / Vector Math / Environment Texture nodes, ending in the closures of
its two outputs, ``BSDF`` (Cycles without OSL) and ``EEVEE`` (see node_group.py for where they go).

The program's 1,500 nodes are built into part groups of at most :data:`PART_NODES` nodes each
(``.Woven Fabric fallback part 01`` ...), group nodes inside the fallback group, a value that one part
computes and another reads passing through their interfaces. Why: Blender updates a node tree after
each change made from Python, in time that grows with the tree, so one tree of n nodes takes time
growing with n squared to build (measured, Blender 5.0: 12.6 s for the program in one tree). Renderers
inline groups: the parts shade exactly as one tree would."""
from __future__ import annotations

import math

import bpy

from ..core import shader_fallback, shader_params
from .fallback_atlases import atlas_images
from .group_interface import socket_by_identifier, sync_interface

FALLBACK_GROUP_NAME = "Woven Fabric fallback"
GROUP_MARK = "woven_fabric_group"  # on both groups: "main" or "fallback"
# The fallback group's outputs: Cycles without OSL (hair transmission closures) and EEVEE (which
# lights no hair closure on a surface: translucent ones instead, see core/shader_fallback.py).
FALLBACK_OUTPUTS = ("BSDF", "EEVEE")


# The most nodes one part group holds (see the module docstring); chosen by the build time.
PART_NODES = 150
PART_PREFIX = ".Woven Fabric fallback part"   # a leading dot keeps the parts out of the Add menu
_SOCKET_TYPES = {"VALUE": "NodeSocketFloat", "INT": "NodeSocketInt", "VECTOR": "NodeSocketVector",
                 "RGBA": "NodeSocketColor"}


class _NodeBuilder:
    """Builds the fallback program's expressions as shader nodes (see shader_program.run), in part
    groups of at most ``part_nodes`` nodes inside ``tree``."""

    def __init__(self, tree, images: dict, part_nodes: int = PART_NODES):
        self.tree, self.images, self.part_nodes = tree, images, part_nodes
        self.depth: dict = {}
        self.column_rows: dict = {}
        self.separated: dict = {}
        self.steps: dict = {}
        self.parts: list = []           # (part tree, its group node in ``tree``)
        self.count = part_nodes         # nodes in the current part: the first node starts one
        self.passed: dict = {}          # (tree name, source socket pointer) -> the socket there

    # -- parts -------------------------------------------------------------------------------------
    def _new(self, kind: str):
        """A new node of ``kind`` in the current part (a new part when this one is full)."""
        if self.count >= self.part_nodes:
            part = bpy.data.node_groups.new(f"{PART_PREFIX} {len(self.parts) + 1:02d}", "ShaderNodeTree")
            part[GROUP_MARK] = "fallback part"
            for kind_, x in (("NodeGroupInput", -200.0), ("NodeGroupOutput", 3000.0)):
                part.nodes.new(kind_).location = (x, 0.0)
            holder = self.tree.nodes.new("ShaderNodeGroup")
            holder.node_tree = part
            holder.location = (180.0 * len(self.parts), 400.0)
            holder.hide = True
            self.parts.append((part, holder))
            self.count, self.column_rows = 0, {}
        self.count += 1
        return self.parts[-1][0].nodes.new(kind)

    def _in(self, tree, socket):
        """``socket`` (any tree's) as a socket of ``tree``: through the parts' interfaces, once each."""
        if socket.id_data == tree:
            return socket
        key = (tree.name, socket.as_pointer())
        if key not in self.passed:
            if tree == self.tree:   # out of its part: a new output of that part
                part, holder = next(p for p in self.parts if p[0] == socket.id_data)
                self.passed[key] = self._port(part, holder, "OUTPUT", socket)
            else:                   # into a part: a new input, fed in ``self.tree``
                part, holder = next(p for p in self.parts if p[0] == tree)
                self.passed[key] = self._port(part, holder, "INPUT", self._in(self.tree, socket))
        return self.passed[key]

    @staticmethod
    def _port(part, holder, in_out: str, socket):
        """A new interface socket of ``part`` carrying ``socket``; the socket where it comes out."""
        item = part.interface.new_socket(name=f"v{len(part.interface.items_tree)}", in_out=in_out,
                                         socket_type=_SOCKET_TYPES[socket.type])
        kind = "NodeGroupOutput" if in_out == "OUTPUT" else "NodeGroupInput"
        inner = next(n for n in part.nodes if n.bl_idname == kind)
        if in_out == "OUTPUT":
            part.links.new(socket, socket_by_identifier(inner.inputs, item.identifier))
            return socket_by_identifier(holder.outputs, item.identifier)
        holder.id_data.links.new(socket, socket_by_identifier(holder.inputs, item.identifier))
        return socket_by_identifier(inner.outputs, item.identifier)

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
            socket.id_data.links.new(self._in(socket.id_data, value), socket)

    def const(self, x):
        return float(x)

    def math(self, op, *args):
        if all(isinstance(a, float) for a in args) and op in _FOLD:  # constant subexpression
            return float(_FOLD[op](*args))
        node = self._new("ShaderNodeMath")
        node.operation = op   # use_clamp is off in a new node
        for i, a in enumerate(args):
            self._feed(node.inputs[i], a)
        self._place(node, args)
        return node.outputs[0]

    def vec(self, op, *args):
        node = self._new("ShaderNodeVectorMath")
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
        node = self._new("ShaderNodeCombineXYZ")
        for i, a in enumerate((x, y, z)):
            self._feed(node.inputs[i], a)
        self._place(node, (x, y, z))
        return node.outputs[0]

    def separate(self, v, i):
        key = v.as_pointer()
        node = self.separated.get(key)
        if node is None:
            node = self._new("ShaderNodeSeparateXYZ")
            self._feed(node.inputs[0], v)
            self._place(node, (v,))
            self.separated[key] = node
        return node.outputs[i]

    def hsv(self, colour, hue, saturation, value):
        node = self._new("ShaderNodeHueSaturation")
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
        node = self._new("ShaderNodeTexEnvironment")
        node.image = image
        node.interpolation = "Closest"
        node.projection = "EQUIRECTANGULAR"
        self._feed(node.inputs["Vector"], direction)
        self._place(node, (direction,))
        return node.outputs["Color"]


_FOLD = {
    "ADD": lambda a, b: a + b, "SUBTRACT": lambda a, b: a - b, "MULTIPLY": lambda a, b: a * b,
    "DIVIDE": lambda a, b: a / b if b else 0.0, "MINIMUM": min, "MAXIMUM": max,
    "SINE": math.sin, "COSINE": math.cos, "SQRT": lambda a: math.sqrt(max(a, 0.0)), "EXPONENT": math.exp,
    "ARCTANGENT": math.atan, "POWER": lambda a, b: a ** b if a > 0 else 0.0, "MULTIPLY_ADD": lambda a, b, c: a * b + c,
}


def build_fallback_group(part_nodes: int = PART_NODES):
    """Builds (or rebuilds in place) the fallback group, its program in part groups of at most
    ``part_nodes`` nodes; returns it."""
    tree = bpy.data.node_groups.get(FALLBACK_GROUP_NAME)
    if tree is None:
        tree = bpy.data.node_groups.new(FALLBACK_GROUP_NAME, "ShaderNodeTree")
    tree[GROUP_MARK] = "fallback"
    sync_interface(tree, FALLBACK_OUTPUTS, readable=False)
    tree.nodes.clear()
    for old in [group for group in bpy.data.node_groups if group.get(GROUP_MARK) == "fallback part"]:
        bpy.data.node_groups.remove(old)   # an earlier build's parts: only the fallback group used them
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

    builder = _NodeBuilder(tree, atlas_images(), part_nodes)
    env = {s.osl: group_in.outputs[s.name] for s in shader_params.socket_specs()}
    env.update(UV=uvmap.outputs["UV"], Tangent=tangent.outputs["Tangent"], Normal=geometry.outputs["Normal"],
               Incoming=geometry.outputs["Incoming"], Backfacing=geometry.outputs["Backfacing"])
    env = shader_fallback.run(builder, env)
    x0 = 180.0 * (len(builder.parts) + 2)   # right of the part groups, the fallback's own nodes
    row = iter(range(0, -10000, -120))

    def bsdf(kind, **inputs):
        node = nodes.new(kind)
        node.location = (x0, next(row))
        for name, value in inputs.items():
            builder._feed(node.inputs[name], env[value] if isinstance(value, str) else value)
        return node

    def glossy(lobe, k):
        node = bsdf("ShaderNodeBsdfAnisotropic", Color=f"gloss_{lobe}_color{k}", Roughness=f"gloss_{lobe}_rough{k}",
                    Anisotropy=f"gloss_{lobe}_aniso{k}", Normal=f"gloss_{lobe}_normal{k}",
                    Tangent=f"gloss_{lobe}_tangent{k}")
        node.distribution = "GGX"
        return node

    def hair(lobe, k):
        rough = f"hair_{'m' if lobe == 'f' else lobe}_rough{k}"  # the forward cone's is the multiple lobe's
        node = bsdf("ShaderNodeBsdfHair", Color=f"hair_{lobe}_color{k}", RoughnessU=rough,
                    RoughnessV=f"hair_f_rough{k}" if lobe == "f" else 1.0, Offset=0.0, Tangent=f"fiber{k}")
        node.component = "Transmission"
        return node

    diffuse = [bsdf("ShaderNodeBsdfDiffuse", Color="diffuse_flat"),
               bsdf("ShaderNodeBsdfDiffuse", Color="diffuse_yarn", Normal="n_main")]
    gloss = [glossy(lobe, k) for k in shader_fallback.LAYERS for lobe in ("s", "m")]
    cycles = diffuse + gloss + [bsdf("ShaderNodeBsdfTranslucent", Color="translucent")]
    cycles += [hair(lobe, k) for k in shader_fallback.LAYERS for lobe in ("s", "m", "f")]
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
