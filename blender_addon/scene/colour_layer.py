"""A Woven Fabric material's colour (bpy): Add Colour Layer, a paintable image wired into its colour
map; the yarn-dyed sett written into its stripe sockets (:func:`apply_sett`); its base colour.

The rules (modes, size, the neutral start) are core/colour_layer.py's. In the material's node
tree, beside the group node: a UV Map node (the UV map the weave uses unless one is named) feeds an
Image Texture node whose colour goes to the group's ``colour map`` and, to replace, whose alpha
goes to ``colour map replace`` (the dye of core/dye.py: the yarns, diffuse and specular together).
A second layer stacks on the first: multiplied by it, or mixed over it by its alpha. The image is
new (``Fabric Colour``, ``.001`` ...), so nothing the user has is touched; it becomes the material's
active paint slot and, for texture painting, the canvas.

The sett (core/sett.py) goes into the group node's stripe inputs; its ``F`` stripes get the base
colour of the material's current albedos (core/dye.base_colour, :func:`base_colour`).
"""
from __future__ import annotations

import bpy

from ..core import colour_layer, dye, sett, shader_params
from . import group_interface, node_group


def add_colour_layer(material, mode: str = "MULTIPLY", size: int | None = None, uv_map: str = ""):
    """Adds a layer to ``material`` (a Woven Fabric material); returns the new image."""
    pixel = colour_layer.initial_pixel(mode)
    group = node_group.group_node(material)
    inputs = group_interface.input_sockets(group)
    params = node_group.read_params(material)
    if size is None:
        size = colour_layer.layer_size(params["tiles"], inputs[shader_params.UV_SCALE].default_value)
    image = bpy.data.images.new(colour_layer.IMAGE_PREFIX, size, size, alpha=True)
    image.generated_color = pixel
    image.alpha_mode = "STRAIGHT"
    image[colour_layer.KEY] = mode

    tree = material.node_tree
    x, y = group.location.x - 700, group.location.y - 150 * _layer_count(tree)
    uv = tree.nodes.new("ShaderNodeUVMap")
    uv.uv_map = uv_map
    uv.location = (x - 250, y)
    texture = tree.nodes.new("ShaderNodeTexImage")
    texture.name = texture.label = image.name
    texture.image = image
    texture.location = (x, y)
    texture[colour_layer.KEY] = mode
    tree.links.new(uv.outputs["UV"], texture.inputs["Vector"])

    colour, alpha = texture.outputs["Color"], texture.outputs["Alpha"]
    target = inputs[shader_params.COLOUR_MAP]
    previous = target.links[0].from_socket if target.is_linked else None
    tree.links.new(_stacked(tree, previous, colour, alpha, mode, (x + 300, y)), target)
    if mode == "REPLACE":
        target = inputs[shader_params.MAP_REPLACE]
        previous = target.links[0].from_socket if target.is_linked else None
        tree.links.new(_combined_alpha(tree, previous, alpha, (x + 300, y - 80)), target)
    make_active_slot(material, image)
    return image


def _layer_count(tree) -> int:
    return sum(1 for node in tree.nodes if node.get(colour_layer.KEY))


def _stacked(tree, previous, colour, alpha, mode, location):
    """The colour map with the new layer over what was there before (``previous``, or white: the
    map's neutral). A Replace layer mixes in by its alpha: Blender's image colour is black where a
    pixel is transparent, which as the map alone would multiply the fabric to black."""
    if previous is None and mode == "MULTIPLY":
        return colour
    mix = tree.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.location = location
    if mode == "MULTIPLY":
        mix.blend_type = "MULTIPLY"
        mix.inputs["Factor"].default_value = 1.0
    else:
        mix.blend_type = "MIX"
        tree.links.new(alpha, mix.inputs["Factor"])
    if previous is None:
        mix.inputs["A"].default_value = (1.0, 1.0, 1.0, 1.0)
    else:
        tree.links.new(previous, mix.inputs["A"])
    tree.links.new(colour, mix.inputs["B"])
    return mix.outputs["Result"]


def _combined_alpha(tree, previous, alpha, location):
    if previous is None:
        return alpha
    maximum = tree.nodes.new("ShaderNodeMath")
    maximum.operation = "MAXIMUM"
    maximum.location = location
    tree.links.new(previous, maximum.inputs[0])
    tree.links.new(alpha, maximum.inputs[1])
    return maximum.outputs[0]


def make_active_slot(material, image) -> None:
    """The layer's node becomes the active one (the node the material's paint slots follow) and the
    image the active paint slot and the paint canvas. Blender lists a material's slots once the
    material is on an object (texture paint mode refreshes the list)."""
    texture = next((n for n in material.node_tree.nodes if n.type == "TEX_IMAGE" and n.image == image), None)
    if texture is not None:
        for node in material.node_tree.nodes:
            node.select = node == texture
        material.node_tree.nodes.active = texture
    images = list(material.texture_paint_images)
    if image in images:
        material.paint_active_slot = images.index(image)
    settings = bpy.context.scene.tool_settings.image_paint if bpy.context.scene else None
    if settings is not None:
        settings.mode = "MATERIAL"
        settings.canvas = image


def base_colour(material) -> tuple[float, float, float]:
    """The material's base colour C0 (core/dye.py): what painting back changes nothing with."""
    return dye.base_colour(node_group.read_params(material))


def apply_sett(material, warp_text: str, weft_text: str = "") -> tuple:
    """Writes the warp and weft setts (an empty weft: the warp's) into the material's stripe inputs;
    returns (warp stripes, weft stripes). Raises sett.SettError (nothing written) on a bad text."""
    warp, weft = sett.parse_pair(warp_text, weft_text)
    inputs = group_interface.input_sockets(node_group.group_node(material))
    for name, value in sett.socket_values(warp, weft, base_colour(material)).items():
        inputs[name].default_value = group_interface.rgba(value) if isinstance(value, tuple) else value
    return warp, weft
