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
:func:`create_material`, :func:`apply_params`, :func:`read_params`. The group's sockets are
group_interface.py's, the fallback group fallback_group.py's, its atlases fallback_atlases.py's.
"""
from __future__ import annotations

import hashlib
import sys

import bpy

from ..core import paths, shader_fallback, shader_params
from . import cycles_osl
from .fallback_atlases import atlases_present, repair_atlases
from .fallback_group import FALLBACK_GROUP_NAME, GROUP_MARK, build_fallback_group
from .group_interface import SOCKET_TYPES, input_items, input_sockets, rgba, socket_by_identifier, sync_interface

NODE_GROUP_NAME = "Woven Fabric"
TEXT_NAME = "woven_fabric.osl"
_HASH = "woven_fabric_hash"
_ERROR = "woven_fabric_osl_error"
# On a material: the photographed width and the cloth size its uv scale was set for.
WIDTH_KEY = "woven_fabric_width_cm"
CLOTH_SIZE_KEY = "woven_fabric_cloth_size_cm"
_BUILD = 4  # bump when the node layout changes (4: the fallback in part groups)


def _source_hash() -> str:
    md5 = hashlib.md5(usedforsecurity=False)
    md5.update(paths.shader_path().read_bytes())
    md5.update(repr(shader_params.socket_specs()).encode())
    md5.update(repr(shader_fallback.program()).encode())
    md5.update(str(_BUILD).encode())
    return md5.hexdigest()


def _build_main_group(tree, fallback):
    sync_interface(tree, ("BSDF", "Fallback"), readable=True)
    tree.nodes.clear()
    nodes, links = tree.nodes, tree.links
    group_in = nodes.new("NodeGroupInput")
    group_in.location = (-600, 0)
    group_out = nodes.new("NodeGroupOutput")
    group_out.location = (600, 0)
    script = _osl_script(tree)

    uvmap = nodes.new("ShaderNodeUVMap")
    uvmap.location = (-300, 500)
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    tangent.location = (-300, 600)
    links.new(uvmap.outputs["UV"], socket_by_identifier(script.inputs, "UV"))
    links.new(tangent.outputs["Tangent"], socket_by_identifier(script.inputs, "Tangent"))

    fb = nodes.new("ShaderNodeGroup")
    fb.node_tree = fallback
    fb.name = fb.label = "Fallback (EEVEE, GPU Cycles)"
    fb.location = (0, -300)
    items = input_items(tree)
    for s in shader_params.socket_specs():
        source = socket_by_identifier(group_in.outputs, items[s.name].identifier)
        if s.name == shader_params.UV_SCALE:
            source = _object_uv_scale(tree, source)
        links.new(source, socket_by_identifier(script.inputs, s.osl))
        links.new(source, fb.inputs[s.name])

    mix = nodes.new("ShaderNodeMixShader")
    mix.name = mix.label = "OSL or fallback"
    mix.location = (300, 0)
    mix.inputs[0].default_value = 0.0  # what the factor reads where the Script node does not run
    links.new(socket_by_identifier(script.outputs, "OSLActive"), mix.inputs[0])
    links.new(fb.outputs["BSDF"], mix.inputs[1])
    links.new(socket_by_identifier(script.outputs, "BSDF"), mix.inputs[2])
    links.new(mix.outputs[0], group_out.inputs["BSDF"])
    links.new(fb.outputs["EEVEE"], group_out.inputs["Fallback"])


def _osl_script(tree):
    """The Script node running the shader (an internal text, compiled here); when it cannot be
    compiled, the error is kept on the group and the node gets the sockets the links need."""
    text = bpy.data.texts.get(TEXT_NAME) or bpy.data.texts.new(TEXT_NAME)
    text.clear()
    text.write(paths.shader_path().read_text())
    script = tree.nodes.new("ShaderNodeScript")
    script.name = script.label = "Woven Fabric OSL"
    script.mode = "INTERNAL"
    script.script = text
    script.location = (0, 300)
    error = cycles_osl.compile_script(script)
    tree[_ERROR] = error
    if error:
        # The material still renders through the fallback (the OSLActive switch reads 0).
        print(f"Woven Fabric: {error}; the node group falls back to standard nodes", file=sys.stderr)
        wanted = [("OUTPUT", "NodeSocketShader", "BSDF", "BSDF"),
                  ("OUTPUT", "NodeSocketFloat", "OSLActive", "OSLActive")]
        wanted += [("INPUT", SOCKET_TYPES[s.kind], s.name, s.osl) for s in shader_params.socket_specs()]
        wanted += [("INPUT", "NodeSocketVector", name, name) for name in ("UV", "Tangent")]
        for side, kind, name, identifier in wanted:
            sockets = script.outputs if side == "OUTPUT" else script.inputs
            if not any(sock.identifier == identifier for sock in sockets):
                sockets.new(kind, name, identifier=identifier)
    return script


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
            and atlases_present():
        repair_atlases()
        return tree
    if tree is None or tree.bl_idname != "ShaderNodeTree":
        tree = bpy.data.node_groups.new(NODE_GROUP_NAME, "ShaderNodeTree")
    tree[GROUP_MARK] = "main"
    fallback = build_fallback_group()
    _build_main_group(tree, fallback)
    tree[_HASH] = digest
    return tree


def group_node(material):
    tree = getattr(material, "node_tree", None)
    if tree is None:
        raise ValueError(f"material {material.name!r} has no node tree")
    for node in tree.nodes:
        if node.type == "GROUP" and node.node_tree is not None and node.node_tree.get(GROUP_MARK) == "main":
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
    # Translucent closures of a plane from the front and mostly shadows the back light; "Slab"
    # transmits the back light (half of it, which the fallback's EEVEE output makes up for) and none
    # from the front.
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
        inputs[name].default_value = rgba(value) if isinstance(value, tuple) else value
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
