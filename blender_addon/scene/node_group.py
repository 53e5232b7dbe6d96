"""The "Woven Fabric" shader node group and materials that use it (bpy layer).

The group's inputs are the fabric parameters (names from the spec, ranges from
``backend/core/params.py``; see ``core/shader_params.py`` for the socket list and the UV-scale rule) plus
colour maps multiplying the diffuse albedos. Inside:

- a Script node running ``shaders/woven_fabric.osl`` (stored as an internal text, compiled here
  so the .blend carries its bytecode), fed by the UV map and its tangent;
- the standard-node fallback (nested group "Woven Fabric fallback"): the same weave geometry and the
  OSL shader's per-layer closure weights from Math / Vector Math / Image Texture nodes
  (``core/shader_fallback.py``, float atlases packed into the .blend). Its ``BSDF`` output (Cycles
  without OSL) has the OSL shader's closures: Diffuse, Translucent, anisotropic Glossy and Hair
  (transmission) BSDFs per layer; its ``EEVEE`` output three closures (one Diffuse, Glossy and
  Translucent: EEVEE lights no hair closure and merges more than three); both mixed with a Transparent
  BSDF by the yarn coverage;
- a Mix Shader whose factor is the Script node's ``OSLActive`` output (1 when OSL runs). Where OSL
  is not available the Script node is dropped from the shader graph and the factor keeps its own
  value, 0: the fallback renders. So Cycles CPU with Open Shading Language enabled (and OptiX with
  OSL) renders the OSL shader, Cycles without OSL (CUDA, HIP, Metal, oneAPI, CPU with OSL off)
  renders the fallback, with no driver or script involved.

If the OSL cannot be compiled (a Blender without Cycles' OSL tools), the group is still built, the
error is printed and kept in the group's ``woven_fabric_osl_error`` property, and every engine
renders the fallback; :func:`ensure_node_group` retries the compilation next time.

Group outputs: ``BSDF`` (the switch above) and ``Fallback`` (the fallback's EEVEE output). A material
made by :func:`create_material` has two Material Output nodes: target Cycles <- BSDF, target EEVEE <-
Fallback (EEVEE never runs OSL).

API (used by materials.py and the tests): :data:`NODE_GROUP_NAME`, :func:`ensure_node_group`,
:func:`create_material`, :func:`apply_params`, :func:`read_params`.
"""
from __future__ import annotations

import hashlib
import math
import sys

import bpy
import numpy as np

from ..core import paths, shader_fallback, shader_params, shader_weave
from . import cycles_osl

NODE_GROUP_NAME = "Woven Fabric"
FALLBACK_GROUP_NAME = "Woven Fabric fallback"
TEXT_NAME = "woven_fabric.osl"
ATLAS_PREFIX = "Woven Fabric "
_MARK = "woven_fabric_group"
_HASH = "woven_fabric_hash"
_ERROR = "woven_fabric_osl_error"
# On a material: the photographed width and the cloth size its uv scale was set for.
WIDTH_KEY = "woven_fabric_width_cm"
CLOTH_SIZE_KEY = "woven_fabric_cloth_size_cm"
_BUILD = 3  # bump when the node layout changes

_SOCKET_TYPES = {"INT": "NodeSocketInt", "FLOAT": "NodeSocketFloat", "COLOR": "NodeSocketColor"}
# The fallback group's outputs: Cycles without OSL (hair transmission closures) and EEVEE (which
# lights no hair closure on a surface: translucent ones instead, see core/shader_fallback.py).
FALLBACK_OUTPUTS = ("BSDF", "EEVEE")


# -- small helpers ---------------------------------------------------------------------------
def _source_hash() -> str:
    md5 = hashlib.md5(usedforsecurity=False)
    md5.update(paths.shader_path().read_bytes())
    md5.update(repr(shader_params.socket_specs()).encode())
    md5.update(repr(shader_fallback.program()).encode())
    md5.update(str(_BUILD).encode())
    return md5.hexdigest()


def _socket_by_identifier(sockets, identifier):
    for sock in sockets:
        if sock.identifier == identifier:
            return sock
    raise KeyError(identifier)


def _rgba(value) -> tuple:
    v = tuple(float(c) for c in value)
    return v[:3] + (1.0,) if len(v) >= 3 else (v[0], v[0], v[0], 1.0)


def _sync_interface(tree, outputs: tuple[str, ...], readable: bool) -> None:
    """Makes the tree's interface exactly the socket list (keeps it when it already matches).

    ``readable``: the sockets carry their labels inside the panels of :data:`shader_params.PANELS`
    (the group the user sees); otherwise their identifiers, flat (the internal fallback group).
    """
    specs = shader_params.socket_specs()
    wanted = [("", name, "OUTPUT", "NodeSocketShader") for name in outputs]
    wanted += [(s.panel if readable else "", s.label if readable else s.name, "INPUT", _SOCKET_TYPES[s.kind])
               for s in specs]
    if _interface_layout(tree) != wanted:
        tree.interface.clear()
        panels = {}
        for panel, name, in_out, socket_type in wanted:
            if panel and panel not in panels:
                panels[panel] = tree.interface.new_panel(panel, default_closed=panel == "Advanced")
            tree.interface.new_socket(name=name, in_out=in_out, socket_type=socket_type,
                                      parent=panels.get(panel))
    items = _input_items(tree, readable)
    for s in specs:
        item = items[s.name]
        item.description = s.description
        if s.kind == "COLOR":
            item.default_value = _rgba(s.default)
        else:
            item.min_value = int(s.lo) if s.kind == "INT" else s.lo
            item.max_value = int(s.hi) if s.kind == "INT" else s.hi
            item.default_value = int(s.default) if s.kind == "INT" else float(s.default)


def _interface_layout(tree) -> list[tuple[str, str, str, str]]:
    """(panel, name, in/out, type) of every socket of the tree's interface, in order."""
    return [(item.parent.name if item.parent is not None and item.parent.index >= 0 else "", item.name,
             item.in_out, item.socket_type)
            for item in tree.interface.items_tree if item.item_type == "SOCKET"]


def _input_items(tree, readable: bool = True) -> dict:
    """Socket identifier (spec name) -> interface item of the group's inputs."""
    found = {}
    for item in tree.interface.items_tree:
        if item.item_type == "SOCKET" and item.in_out == "INPUT":
            panel = item.parent.name if item.parent is not None and item.parent.index >= 0 else ""
            found[(panel, item.name)] = item
    return {s.name: found[(s.panel, s.label) if readable else ("", s.name)] for s in shader_params.socket_specs()}


def input_sockets(node) -> dict:
    """Socket identifier (spec name, e.g. ``roughness warp``) -> the group node's input socket.

    The node shows readable labels in panels (two inputs may share a label, one per yarn), so the
    spec names are matched through the interface: label and panel give the item, its identifier
    the node's socket.
    """
    items = _input_items(node.node_tree)
    return {name: _socket_by_identifier(node.inputs, item.identifier) for name, item in items.items()}


def _atlas_pixels() -> dict[str, tuple[int, int, np.ndarray]]:
    """name -> (width, height, RGBA float32 pixels) of the fallback's atlases, as generated."""
    out = {}
    for name, (w, h, px) in shader_weave.fallback_atlases().items():
        rgb = np.asarray(px, dtype=np.float32).reshape(-1, 3)
        out[name] = (w, h, np.concatenate([rgb, np.ones((len(rgb), 1), np.float32)], 1).ravel())
    return out


def _write_atlas(image, pixels: np.ndarray) -> None:
    # Only an image with edited pixels gets packed, so the pixels are written last and packed at
    # once (as OpenEXR, float).
    image.pixels.foreach_set(pixels)
    image.pack()
    if image.packed_file is None:  # pragma: no cover - depends on Blender's packing rules
        raise RuntimeError(f"could not pack the fallback atlas {image.name!r}")


def _atlas_images() -> dict:
    """The fallback's float atlases as packed, non-colour images (created afresh each build).

    A generated image is regenerated (its pixels lost) when its colour space changes, so each is
    made non-colour at creation.
    """
    images = {}
    for name, (w, h, pixels) in _atlas_pixels().items():
        full = ATLAS_PREFIX + name
        old = bpy.data.images.get(full)
        if old is not None:
            bpy.data.images.remove(old)
        image = bpy.data.images.new(full, w, h, alpha=False, float_buffer=True, is_data=True)
        image.alpha_mode = "CHANNEL_PACKED"
        image.use_fake_user = True
        _write_atlas(image, pixels)
        images[name] = image
    return images


def repair_atlases() -> list[str]:
    """Restores any fallback atlas whose pixels were changed (painted over, edited by a script);
    returns the names of those it restored.

    The atlases are lookup tables of the weave, not textures: texture painting lists them among a
    material's paint slots (Blender lists every Image Texture node, in nested groups too), so they
    are checked here, whenever a fabric material is made or updated, before a file is saved and
    on a timer while the add-on runs (ui/material_operators.py).
    """
    restored = []
    for name, (w, h, pixels) in _atlas_pixels().items():
        image = bpy.data.images.get(ATLAS_PREFIX + name)
        if image is None or tuple(image.size) != (w, h):
            continue  # missing or replaced: ensure_node_group rebuilds the group
        current = np.empty(len(pixels), dtype=np.float32)
        image.pixels.foreach_get(current)
        if not np.array_equal(current, pixels):
            _write_atlas(image, pixels)
            restored.append(image.name)
    return restored


def _atlases_present() -> bool:
    return all(tuple(getattr(bpy.data.images.get(ATLAS_PREFIX + name), "size", ())) == (w, h)
               for name, (w, h, _) in _atlas_pixels().items())


class _NodeBuilder:
    """Builds the fallback program's expressions as shader nodes (see shader_fallback.run)."""

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
        coord = self.combine(u, v, 0.0)
        node = self.tree.nodes.new("ShaderNodeTexImage")
        node.image = self.images[name]
        node.interpolation = "Closest"
        node.extension = "EXTEND"
        self.tree.links.new(coord, node.inputs["Vector"])
        self._place(node, (coord,))
        return node.outputs["Color"]


_FOLD = {
    "ADD": lambda a, b: a + b, "SUBTRACT": lambda a, b: a - b, "MULTIPLY": lambda a, b: a * b,
    "DIVIDE": lambda a, b: a / b if b else 0.0, "MINIMUM": min, "MAXIMUM": max,
    "SINE": math.sin, "COSINE": math.cos, "SQRT": lambda a: math.sqrt(max(a, 0.0)), "EXPONENT": math.exp,
    "ARCTANGENT": math.atan, "POWER": lambda a, b: a ** b if a > 0 else 0.0,
}


def _build_fallback_group():
    tree = bpy.data.node_groups.get(FALLBACK_GROUP_NAME)
    if tree is None:
        tree = bpy.data.node_groups.new(FALLBACK_GROUP_NAME, "ShaderNodeTree")
    tree[_MARK] = "fallback"
    _sync_interface(tree, FALLBACK_OUTPUTS, readable=False)
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

    builder = _NodeBuilder(tree, _atlas_images())
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
             bsdf("ShaderNodeBsdfTranslucent", Color="eevee_translucent")]
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


def _build_main_group(tree, fallback):
    _sync_interface(tree, ("BSDF", "Fallback"), readable=True)
    tree.nodes.clear()
    nodes, links = tree.nodes, tree.links
    group_in = nodes.new("NodeGroupInput")
    group_in.location = (-600, 0)
    group_out = nodes.new("NodeGroupOutput")
    group_out.location = (600, 0)

    text = bpy.data.texts.get(TEXT_NAME) or bpy.data.texts.new(TEXT_NAME)
    text.clear()
    text.write(paths.shader_path().read_text())
    script = nodes.new("ShaderNodeScript")
    script.name = script.label = "Woven Fabric OSL"
    script.mode = "INTERNAL"
    script.script = text
    script.location = (0, 300)
    error = cycles_osl.compile_script(script)
    tree[_ERROR] = error
    if error:
        # The material still renders through the fallback (the OSLActive switch reads 0).
        print(f"Woven Fabric: {error}; the node group falls back to standard nodes", file=sys.stderr)
        for name, kind in (("BSDF", "NodeSocketShader"), ("OSLActive", "NodeSocketFloat")):
            if not any(s.identifier == name for s in script.outputs):
                script.outputs.new(kind, name, identifier=name)
        for s in shader_params.socket_specs():
            if not any(sock.identifier == s.osl for sock in script.inputs):
                script.inputs.new(_SOCKET_TYPES[s.kind], s.name, identifier=s.osl)
        for name in ("UV", "Tangent"):
            if not any(sock.identifier == name for sock in script.inputs):
                script.inputs.new("NodeSocketVector", name, identifier=name)

    uvmap = nodes.new("ShaderNodeUVMap")
    uvmap.location = (-300, 500)
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    tangent.location = (-300, 600)
    links.new(uvmap.outputs["UV"], _socket_by_identifier(script.inputs, "UV"))
    links.new(tangent.outputs["Tangent"], _socket_by_identifier(script.inputs, "Tangent"))

    fb = nodes.new("ShaderNodeGroup")
    fb.node_tree = fallback
    fb.name = fb.label = "Fallback (EEVEE, GPU Cycles)"
    fb.location = (0, -300)
    items = _input_items(tree)
    for s in shader_params.socket_specs():
        source = _socket_by_identifier(group_in.outputs, items[s.name].identifier)
        if s.name == shader_params.UV_SCALE:
            source = _object_uv_scale(tree, source)
        links.new(source, _socket_by_identifier(script.inputs, s.osl))
        links.new(source, fb.inputs[s.name])

    mix = nodes.new("ShaderNodeMixShader")
    mix.name = mix.label = "OSL or fallback"
    mix.location = (300, 0)
    mix.inputs[0].default_value = 0.0  # what the factor reads where the Script node does not run
    links.new(_socket_by_identifier(script.outputs, "OSLActive"), mix.inputs[0])
    links.new(fb.outputs["BSDF"], mix.inputs[1])
    links.new(_socket_by_identifier(script.outputs, "BSDF"), mix.inputs[2])
    links.new(mix.outputs[0], group_out.inputs["BSDF"])
    links.new(fb.outputs["EEVEE"], group_out.inputs["Fallback"])


def _object_uv_scale(tree, uv_scale):
    """The object's own uv scale (its OBJECT_UV_SCALE property, set by Set Real-World Scale) where it
    has one, else the material's: an Attribute node reads 0 on an object without the property."""
    nodes, links = tree.nodes, tree.links
    attribute = nodes.new("ShaderNodeAttribute")
    attribute.name = attribute.label = "Object's real-world scale"
    attribute.attribute_type = "OBJECT"
    attribute.attribute_name = shader_params.OBJECT_UV_SCALE
    attribute.location = (-400, -700)
    has_own = nodes.new("ShaderNodeMath")
    has_own.operation = "GREATER_THAN"
    has_own.inputs[1].default_value = 0.0
    has_own.location = (-200, -700)
    links.new(attribute.outputs["Fac"], has_own.inputs[0])
    choose = nodes.new("ShaderNodeMix")
    choose.name = choose.label = "UV scale (object or material)"
    choose.data_type = "FLOAT"
    choose.clamp_factor = True
    choose.location = (-100, -600)
    links.new(has_own.outputs[0], choose.inputs["Factor"])
    links.new(uv_scale, choose.inputs["A"])
    links.new(attribute.outputs["Fac"], choose.inputs["B"])
    return choose.outputs["Result"]


def ensure_node_group() -> "bpy.types.ShaderNodeTree":
    """The "Woven Fabric" node group, created (or rebuilt when the shader or sockets changed)."""
    tree = bpy.data.node_groups.get(NODE_GROUP_NAME)
    digest = _source_hash()
    if tree is not None and tree.bl_idname == "ShaderNodeTree" and tree.get(_HASH) == digest \
            and not tree.get(_ERROR) and bpy.data.node_groups.get(FALLBACK_GROUP_NAME) is not None \
            and _atlases_present():
        repair_atlases()
        return tree
    if tree is None or tree.bl_idname != "ShaderNodeTree":
        tree = bpy.data.node_groups.new(NODE_GROUP_NAME, "ShaderNodeTree")
    tree[_MARK] = "main"
    fallback = _build_fallback_group()
    _build_main_group(tree, fallback)
    tree[_HASH] = digest
    return tree


def group_node(material):
    tree = getattr(material, "node_tree", None)
    if tree is None:
        raise ValueError(f"material {material.name!r} has no node tree")
    for node in tree.nodes:
        if node.type == "GROUP" and node.node_tree is not None and node.node_tree.get(_MARK) == "main":
            return node
    raise ValueError(f"material {material.name!r} has no {NODE_GROUP_NAME!r} group node")


def create_material(name: str, params: dict, width_cm: float | None = None,
                    cloth_size_cm: float | None = None) -> "bpy.types.Material":
    """A new material whose node tree is the Woven Fabric group with `params` applied.

    Two Material Output nodes: Cycles <- group BSDF (OSL or fallback, see the module docstring),
    EEVEE <- group Fallback. For ``width_cm`` / ``cloth_size_cm`` see :func:`apply_params`.
    """
    group = ensure_node_group()
    material = bpy.data.materials.new(name)
    if material.node_tree is None:  # before Blender 5.0 materials start without nodes
        material.use_nodes = True
    tree = material.node_tree
    tree.nodes.clear()
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    node.name = node.label = NODE_GROUP_NAME
    node.width = 260
    out_cycles = tree.nodes.new("ShaderNodeOutputMaterial")
    out_cycles.name = out_cycles.label = "Output (Cycles)"
    out_cycles.target = "CYCLES"
    out_cycles.location = (400, 100)
    out_eevee = tree.nodes.new("ShaderNodeOutputMaterial")
    out_eevee.name = out_eevee.label = "Output (EEVEE)"
    out_eevee.target = "EEVEE"
    out_eevee.location = (400, -150)
    tree.links.new(node.outputs["BSDF"], out_cycles.inputs["Surface"])
    tree.links.new(node.outputs["Fallback"], out_eevee.inputs["Surface"])
    out_cycles.is_active_output = True
    out_eevee.is_active_output = True
    # EEVEE: a cloth is a thin sheet. With the default "Sphere" thickness mode EEVEE lights the
    # Translucent closures of a plane from the front and mostly shadows the back light (measured:
    # 17 % of k |cos| / pi from behind); "Slab" transmits the back light (half of it, which the
    # fallback's EEVEE output makes up for) and none from the front.
    for attr, value in (("surface_render_method", "DITHERED"), ("use_transparent_shadow", True),
                        ("thickness_mode", "SLAB")):
        if hasattr(material, attr):
            try:
                setattr(material, attr, value)
            except (TypeError, AttributeError):
                pass
    apply_params(material, params, width_cm, cloth_size_cm)
    return material


def apply_params(material, params: dict, width_cm: float | None = None,
                 cloth_size_cm: float | None = None) -> None:
    """Writes a params.json dict onto the material's group node (values clamped into range).

    ``uv scale`` is set to ``cloth_size_cm * V / (plane_size * width_cm)`` when both sizes are
    known (``width_cm`` defaults to ``params["rig"]["width_cm"]``), so the weave has its real size
    on a cloth whose UV unit square is ``cloth_size_cm`` wide; otherwise it is left as it is
    (1 on a new material: tiles per UV unit as in the rig).
    """
    inputs = input_sockets(group_node(material))
    repair_atlases()
    for name, value in shader_params.socket_values(params).items():
        inputs[name].default_value = _rgba(value) if isinstance(value, tuple) else value
    rig = params.get("rig") if isinstance(params.get("rig"), dict) else None
    if width_cm is None and rig is not None:
        width_cm = rig.get("width_cm")
    if width_cm is not None and cloth_size_cm is not None:
        inputs[shader_params.UV_SCALE].default_value = shader_params.uv_scale(width_cm, cloth_size_cm, rig)
        material[WIDTH_KEY] = float(width_cm)
        material[CLOTH_SIZE_KEY] = float(cloth_size_cm)


def read_params(material) -> dict:
    """The parameters currently on the material's group node, as a params.json dict
    (``FabricParams.to_dict()`` names; tiles as on the sockets, i.e. per UV unit of the rig plane,
    without the ``uv scale`` factor)."""
    inputs = input_sockets(group_node(material))
    values = {}
    for s in shader_params.socket_specs():
        v = inputs[s.name].default_value
        values[s.name] = tuple(v)[:3] if s.kind == "COLOR" else (int(v) if s.kind == "INT" else float(v))
    return shader_params.params_from_sockets(values)
