"""blender_addon/scene/node_group.py in Blender (bpy, in a subprocess): the group's sockets, the
create_material / apply_params / read_params round trip, the real-world UV scale, and that a
saved .blend keeps everything (OSL bytecode, packed fallback atlases)."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from addon_support import run_blender  # noqa: E402

from backend.core.params import FabricParams  # noqa: E402
from blender_addon.core import shader_params, shader_weave  # noqa: E402


@pytest.mark.blender
def test_node_group_sockets_and_material_round_trip(tmp_path):
    blend = tmp_path / "fabric.blend"
    result = run_blender(f"""
        from backend.core.params import FabricParams
        from blender_addon.scene import fallback_atlases
        group = node_group.ensure_node_group()
        again = node_group.ensure_node_group()
        inputs = [(i.parent.name, i.name, i.socket_type, getattr(i, "min_value", None), getattr(i, "max_value", None),
                   i.description)
                  for i in group.interface.items_tree if i.item_type == "SOCKET" and i.in_out == "INPUT"]
        outputs = [i.name for i in group.interface.items_tree if i.item_type == "SOCKET" and i.in_out == "OUTPUT"]
        p = FabricParams(pattern="satin1", tiles=(151.9, 84.7), roughness=(0.18, 0.75), thickness=(1.58, 2.79),
                         twist_deg=(-12.0, 30.0), specular_albedo=((0.12, 0.53, 0.28), (0.1, 0.52, 0.26)),
                         diffuse_reflection=(0.077, 0.282, 0.077), multiple_weight=0.94, noise=1.0)
        data = dict(p.to_dict(), rig={{"width_cm": 5.0}}, interchange=p.to_interchange())
        mat = node_group.create_material("Fitted", data)
        mesh = bpy.data.meshes.new("cloth")
        obj = bpy.data.objects.new("cloth", mesh)
        bpy.context.scene.collection.objects.link(obj)
        mesh.materials.append(mat)
        first = node_group.read_params(mat)
        node = [n for n in mat.node_tree.nodes if n.type == "GROUP"][0]
        uv_default = node_group.input_sockets(node)["uv scale"].default_value
        node_group.apply_params(mat, dict(p.to_dict(), pattern="plain", roughness=[0.5, 0.25]),
                                width_cm=5.0, cloth_size_cm=120.0)
        second = node_group.read_params(mat)
        uv_scale = node_group.input_sockets(node)["uv scale"].default_value
        targets = sorted(n.target for n in mat.node_tree.nodes if n.type == "OUTPUT_MATERIAL")
        script = group.nodes["Woven Fabric OSL"]
        has_bytecode = bool(script.bytecode)
        bpy.ops.wm.save_as_mainfile(filepath={str(blend)!r})
        bpy.ops.wm.open_mainfile(filepath={str(blend)!r})
        mat = bpy.data.materials["Fitted"]
        reloaded = node_group.read_params(mat)
        atlases = {{im.name: (im.packed_file is not None, list(im.size)) for im in bpy.data.images
                   if im.name.startswith(fallback_atlases.ATLAS_PREFIX)}}
        warp = bpy.data.images[fallback_atlases.ATLAS_PREFIX + "warp"]
        px = list(warp.pixels[:8])
        emit({{"same_group": group == again, "inputs": inputs, "outputs": outputs, "first": first,
              "second": second, "reloaded": reloaded, "uv_default": uv_default, "uv_scale": uv_scale,
              "targets": targets, "bytecode": has_bytecode, "atlases": atlases, "warp_px": px,
              "groups": sorted(g.name for g in bpy.data.node_groups)}})
    """, tmp_path)
    specs = shader_params.socket_specs()
    # Readable labels and tooltips in panels (the spec names stay the identifiers: input_sockets).
    assert [(i[0], i[1]) for i in result["inputs"]] == [(s.panel, s.label) for s in specs]
    for (panel, name, socket_type, lo, hi, tooltip), s in zip(result["inputs"], specs):
        assert socket_type == {"INT": "NodeSocketInt", "FLOAT": "NodeSocketFloat", "COLOR": "NodeSocketColor"}[s.kind]
        assert tooltip == s.description
        if s.kind != "COLOR":
            assert lo == pytest.approx(s.lo, rel=1e-6) and hi == pytest.approx(s.hi, rel=1e-6), name
    assert result["outputs"] == ["BSDF", "Fallback"]
    assert result["same_group"] and result["bytecode"]
    assert result["targets"] == ["CYCLES", "EEVEE"]

    expected = FabricParams(pattern="satin1", tiles=(151.9, 84.7), roughness=(0.18, 0.75), thickness=(1.58, 2.79),
                            twist_deg=(-12.0, 30.0), specular_albedo=((0.12, 0.53, 0.28), (0.1, 0.52, 0.26)),
                            diffuse_reflection=(0.077, 0.282, 0.077), multiple_weight=0.94, noise=1.0).to_dict()

    def close(a, b):
        assert a.keys() == b.keys()
        for key in a:
            if key == "pattern":
                assert a[key] == b[key]
            else:
                flat_a = [x for v in a[key] for x in v] if key == "specular_albedo" else a[key]
                flat_b = [x for v in b[key] for x in v] if key == "specular_albedo" else b[key]
                assert flat_a == pytest.approx(flat_b, rel=1e-5, abs=1e-6), key

    close(result["first"], expected)
    close(result["second"], dict(expected, pattern="plain", roughness=[0.5, 0.25]))
    close(result["reloaded"], result["second"])
    assert result["uv_default"] == 1.0
    V = 2 * 8 * math.tan(math.radians(26.5))
    assert result["uv_scale"] == pytest.approx(120.0 * V / (10 * 5.0), rel=1e-5)
    assert set(result["atlases"]) == {f"Woven Fabric {n}" for n in shader_weave.fallback_atlases()}
    assert all(packed for packed, _ in result["atlases"].values())
    w, h, px = shader_weave.fallback_atlases()["warp"]
    assert result["warp_px"][:3] == pytest.approx(px[:3]) and result["warp_px"][4:7] == pytest.approx(px[3:6])
    assert {"Woven Fabric", "Woven Fabric fallback"} <= set(result["groups"])


@pytest.mark.blender
def test_the_fallback_is_built_in_small_parts_that_shade_as_one_tree(tmp_path):
    """The fallback's program goes into part groups of at most PART_NODES nodes (Blender's build time
    grows with the square of a tree's nodes); a value one part computes reaches another through their
    interfaces, so the fallback renders (Cycles without OSL, and EEVEE) exactly as the program built
    in one tree; a rebuild leaves no part of the earlier build behind."""
    result = run_blender("""
        import numpy as np
        from blender_addon.scene import fallback_group
        from backend.core.params import FabricParams
        p = FabricParams(pattern="twill1", tiles=(60.0, 40.0), roughness=(0.3, 0.6), thickness=(1.5, 2.5),
                         twist_deg=(-20.0, 10.0), diffuse_reflection=(0.2, 0.1, 0.05))
        mat = node_group.create_material("m", p.to_dict())
        scene = rig_scene.build_scene(mat, size=16, samples=2, osl=False, threads=1, scene=bpy.context.scene)

        def parts():
            fallback = bpy.data.node_groups[fallback_group.FALLBACK_GROUP_NAME]
            used = [n.node_tree.name for n in fallback.nodes if n.type == "GROUP"]
            marked = [g.name for g in bpy.data.node_groups if g.get(fallback_group.GROUP_MARK) == "fallback part"]
            return {"fallback_nodes": len(fallback.nodes), "used": sorted(used), "marked": sorted(marked),
                    "largest": max(len(bpy.data.node_groups[name].nodes) for name in used)}

        def renders():
            out = []
            for engine in ("fallback", "eevee"):
                rig_scene.set_engine(scene, engine, 2)
                out.append(np.concatenate(rig_scene.render_pair(scene), 1))
            return out

        in_parts, split = renders(), parts()
        fallback_group.build_fallback_group(part_nodes=10 ** 6)   # the whole program in one part
        in_one, whole = renders(), parts()
        emit({"split": split, "whole": whole,
              "differences": [float(np.abs(a - b).max()) for a, b in zip(in_parts, in_one)],
              "mean": float(in_one[0].mean())})
    """, tmp_path)
    split, whole = result["split"], result["whole"]
    from blender_addon.scene.fallback_group import PART_NODES
    assert len(split["used"]) > 5 and split["used"] == split["marked"]
    assert split["largest"] <= PART_NODES + 2   # and the part's Group Input and Output nodes
    assert split["fallback_nodes"] < 60         # the parts, the closures and the geometry nodes
    assert len(whole["used"]) == 1 and whole["used"] == whole["marked"]   # the earlier parts are gone
    assert whole["largest"] > 1000
    assert result["mean"] > 0.05                # a lit cloth, not a black frame
    assert result["differences"] == [0.0, 0.0]
