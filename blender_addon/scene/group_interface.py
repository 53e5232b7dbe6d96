"""The Woven Fabric node groups' sockets (bpy layer): the interface made from the socket list
(core/shader_params.py) and the sockets found by their spec names.

The group the user sees has readable labels inside panels (two inputs may share a label, one per
yarn); the internal fallback group has the spec names, flat. Either way a socket is found by its
spec name through the interface (label and panel give the item, its identifier the socket).
"""
from __future__ import annotations

from ..core import shader_params

SOCKET_TYPES = {"INT": "NodeSocketInt", "FLOAT": "NodeSocketFloat", "COLOR": "NodeSocketColor"}


def socket_by_identifier(sockets, identifier):
    for sock in sockets:
        if sock.identifier == identifier:
            return sock
    raise KeyError(identifier)


def rgba(value) -> tuple:
    v = tuple(float(c) for c in value)
    return v[:3] + (1.0,) if len(v) >= 3 else (v[0], v[0], v[0], 1.0)


def sync_interface(tree, outputs: tuple[str, ...], readable: bool) -> None:
    """Makes the tree's interface exactly the socket list (keeps it when it already matches).

    ``readable``: the sockets carry their labels inside the panels of :data:`shader_params.PANELS`
    (the group the user sees); otherwise their identifiers, flat (the internal fallback group).
    """
    specs = shader_params.socket_specs()
    wanted = [("", name, "OUTPUT", "NodeSocketShader") for name in outputs]
    wanted += [(s.panel if readable else "", s.label if readable else s.name, "INPUT", SOCKET_TYPES[s.kind])
               for s in specs]
    if _interface_layout(tree) != wanted:
        tree.interface.clear()
        panels = {}
        for panel, name, in_out, socket_type in wanted:
            if panel and panel not in panels:
                panels[panel] = tree.interface.new_panel(panel, default_closed=panel in shader_params.CLOSED_PANELS)
            tree.interface.new_socket(name=name, in_out=in_out, socket_type=socket_type,
                                      parent=panels.get(panel))
    items = input_items(tree, readable)
    for s in specs:
        item = items[s.name]
        item.description = s.description
        if s.kind == "COLOR":
            item.default_value = rgba(s.default)
        else:
            item.min_value = int(s.lo) if s.kind == "INT" else s.lo
            item.max_value = int(s.hi) if s.kind == "INT" else s.hi
            item.default_value = int(s.default) if s.kind == "INT" else float(s.default)


def _interface_layout(tree) -> list[tuple[str, str, str, str]]:
    """(panel, name, in/out, type) of every socket of the tree's interface, in order."""
    return [(item.parent.name if item.parent is not None and item.parent.index >= 0 else "", item.name,
             item.in_out, item.socket_type)
            for item in tree.interface.items_tree if item.item_type == "SOCKET"]


def input_items(tree, readable: bool = True) -> dict:
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
    items = input_items(node.node_tree)
    return {name: socket_by_identifier(node.inputs, item.identifier) for name, item in items.items()}
