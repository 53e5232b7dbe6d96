"""Yarn variation (backend/core/variation.py, backend/model/variation.py): the hash (same bits in
torch as in plain Python, exact in float32, its distribution), the smooth values, and the renders
(none by default, the reference with variation on, gradients)."""
from __future__ import annotations

import math
import random
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
from oracles import reference
from test_render import assert_fast_path_matches_reference, random_params

from backend.core import variation as core
from backend.core.options import RenderOptions
from backend.core.params import SPECS, FabricParams
from backend.core.rig import DEFAULT_RIG
from backend.model import variation
from backend.model.bsdf_gradient import eval_with_hand_gradient
from backend.model.camera import CameraSamples
from backend.model.geometry import GeometryKey, sample_geometry
from backend.model.layers import WeaveLookup
from backend.model.param_tensors import ParamTensors
from backend.model.projections import project
from backend.model.render import Renderer, render_pair


def _plain_permute(x: int) -> int:
    """R written out independently of the module: ((x + 1013) mod 4091)^3 mod 4091."""
    return pow((x + 1013) % 4091, 3, 4091)


def test_the_permutation_permutes_and_stays_exact_in_float32():
    assert sorted(_plain_permute(x) for x in range(4091)) == list(range(4091))
    inputs = range(3 * 4091)  # h + lo + the offset stay below this
    assert [core.permute(x) for x in inputs] == [_plain_permute(x) for x in inputs]
    # the products of two residues are below 2^24: float32 gives the same numbers
    assert (core.HASH_MODULUS - 1) ** 2 < 2 ** 24
    y = np.arange(4091, dtype=np.float32)
    square = np.mod(y * y, np.float32(4091))
    assert np.array_equal(np.mod(square * y, np.float32(4091)).astype(np.int64), [pow(v, 3, 4091) for v in range(4091)])


def _float32_hash(stream: int, component: int, *keys: int) -> int:
    """The hash as float32 arithmetic does it (OSL, Blender's Math nodes: floored modulo)."""
    f = np.float32
    p = f(4091)

    def perm(x):
        y = np.mod(x + f(1013), p)
        return np.mod(np.mod(y * y, p) * y, p)

    h = perm(perm(f(stream)) + f(component))
    for n in keys:
        n = f(n)
        lo = np.mod(n, p)
        hi = np.mod((n - lo) / p, p)
        h = perm(perm(h + lo) + hi)
    return int(h)


def test_torch_float32_and_plain_python_give_the_same_bits():
    rng = random.Random(5)
    keys = [rng.randrange(-(1 << 23), 1 << 23) for _ in range(300)] + list(range(-300, 300))
    knots = [rng.randrange(-5000, 5000) for _ in keys]
    for stream in (0, 3, 9):
        for component in (0, 1):
            got = variation.hash_keys(stream, component, torch.tensor(keys), torch.tensor(knots)).tolist()
            assert got == [core.hash_keys(stream, component, k, j) for k, j in zip(keys, knots)]
            assert got[:40] == [_float32_hash(stream, component, k, j) for k, j in zip(keys[:40], knots[:40])]
    xs = torch.tensor([rng.uniform(-50, 50) for _ in range(200)], dtype=torch.float64)
    ks = torch.tensor([rng.randrange(-100, 100) for _ in range(200)])
    got = variation.smooth(4, xs, 2.5, ks)
    expected = [core.smooth(4, float(x), 2.5, int(k)) for x, k in zip(xs, ks)]
    torch.testing.assert_close(got, torch.tensor(expected, dtype=torch.float64), rtol=1e-12, atol=1e-12)


def test_knot_values_gathered_from_the_keys_range_are_the_hash_of_every_sample():
    gen = torch.Generator().manual_seed(3)
    yarns = torch.randint(-10, 20, (8000,), generator=gen)
    knots = torch.randint(-30, 90, (8000,), generator=gen)
    cases = [((knots,), ()),                                   # per-yarn values: the knot alone
             ((knots,), (yarns,)),                             # slubs: the yarn and its knot
             ((knots[:, None],), (yarns[None, :50],)),         # keys broadcast together
             ((torch.randint(-(1 << 20), 1 << 20, (300,), generator=gen),), ()),  # sparser than the samples
             ((torch.zeros(0, dtype=torch.int64),), ())]       # nothing to hash
    for (j,), keys in cases:
        gathered = variation.knot_gauss(5, j, *keys)
        direct = variation.knot_gauss_direct(5, j, *keys)
        for got, expected in zip(gathered, direct):
            assert got.shape == expected.shape
            assert torch.equal(got, expected)


def test_the_hash_is_deterministic_and_spread_evenly():
    k = torch.arange(-20000, 20000)
    first, again = variation.hash_keys(2, 0, k), variation.hash_keys(2, 0, k)
    assert torch.equal(first, again)
    counts = torch.bincount(first % 64, minlength=64).double()
    expected = len(k) / 64
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert chi2 < CHI2_64_BOUND
    # streams and components are different sequences, neighbouring keys are not alike
    other = variation.hash_keys(3, 0, k)
    assert (first == other).double().mean() < 0.002
    g = variation.gauss(2, k)
    assert abs(float(g.mean())) < 0.03 and abs(float(g.var()) - 1.0) < 0.05
    for lag in (1, 2, 4091):
        assert abs(float(torch.corrcoef(torch.stack((g[:-lag], g[lag:])))[0, 1])) < 0.03, lag
    two_keys = variation.gauss(2, k, torch.tensor(7))
    assert abs(float(torch.corrcoef(torch.stack((two_keys[:-1], two_keys[1:])))[0, 1])) < 0.03
    assert float(g.abs().max()) < core.GAUSS_SCALE


# chi-square with 63 degrees of freedom is below this with probability about 0.999 (a fixed hash either
# passes or fails: this one passes with room)
CHI2_64_BOUND = 104.0


def test_smooth_values_have_unit_variance_and_the_correlation_length():
    x = torch.arange(0, 40000, dtype=torch.float64) * 0.37
    for length in (1.0, 6.0):
        g = variation.smooth(1, x, length)
        assert abs(float(g.var()) - 1.0) < 0.08, length
    # on yarn indices with length 1, independent yarns: G itself
    k = torch.arange(-50, 50)
    assert torch.equal(variation.smooth(0, k.double(), 1.0), variation.gauss(0, k))
    # a long correlation: neighbours alike; continuous across the knots
    near = variation.smooth(1, torch.tensor([2.999999, 3.0], dtype=torch.float64) * 8.0, 8.0)
    assert abs(float(near[0] - near[1])) < 1e-4
    g = variation.smooth(1, torch.arange(0, 20000, dtype=torch.float64), 8.0)
    assert float(torch.corrcoef(torch.stack((g[:-1], g[1:])))[0, 1]) > 0.9


def test_variation_parameters_are_declared_with_ranges_priors_and_no_variation_by_default():
    default = FabricParams()
    assert core.PARAMETER_NAMES == tuple(name for name in SPECS if "variation" in name)
    for name in core.PARAMETER_NAMES:
        spec = SPECS[name]
        assert spec.per_yarn and not spec.optimised and not spec.searched, name
        assert spec.prior is not None and spec.lo <= spec.prior[0] < spec.prior[1] <= spec.hi, name
        assert spec.lo <= getattr(default, name)[0] <= spec.hi
    for kind in core.KINDS:
        assert getattr(default, core.amplitude_name(kind)) == (0.0, 0.0)
    assert not variation.VariationSettings.of(lambda n: getattr(default, n)).active
    # the JSON form carries them; the paper's interchange string does not (reading one gives none)
    varied = default.replace(width_variation=(0.1, 0.2), slub_variation_length=(3.0, 5.0))
    assert FabricParams.from_dict(varied.to_dict()) == varied
    assert FabricParams.from_interchange(varied.to_interchange()).width_variation == (0.0, 0.0)


def test_sqrt6_is_the_unit_variance_scale():
    assert core.GAUSS_SCALE == pytest.approx(math.sqrt(1.0 / (2.0 / 12.0)))


# -- renders -------------------------------------------------------------------------------------
VARIED = dict(width_variation=(0.25, 0.2), width_variation_length=(1.0, 3.0), thickness_variation=(0.3, 0.2),
              thickness_variation_length=(2.0, 1.0), spacing_variation=(0.15, 0.2), brightness_variation=(0.3, 0.25),
              brightness_variation_length=(1.0, 4.0), slub_variation=(0.2, 0.3), slub_variation_length=(2.0, 1.5))


def _points(params: FabricParams, xs, ys, options, tensors):
    """The fast path's radiance at world points, its geometry state with the params' variation (the eager
    renderer's evaluation: its gradient by hand where it applies)."""
    camera = CameraSamples(DEFAULT_RIG, 512, 1, dtype=torch.float64)
    chunk = camera.at_points(torch.tensor(xs, dtype=torch.float64), torch.tensor(ys, dtype=torch.float64))
    settings = variation.VariationSettings.of(lambda n: getattr(params, n))
    key = GeometryKey(params.pattern, params.tiles, params.gap_scale, params.twist_deg, 0.0, options.tension,
                      options.layers, settings)
    geometry = sample_geometry(chunk, WeaveLookup(params.resolved_weave, dtype=torch.float64), DEFAULT_RIG, key,
                               torch.float64)
    r, t = eval_with_hand_gradient(project(chunk, geometry), tensors, options)
    return r.radiance(), t.radiance(), geometry.no_yarn


@pytest.mark.parametrize("pattern,layers", [("plain", 2), ("twill0", 2), ("satin0", 2), ("satin1", 1)])
def test_varied_fast_path_matches_the_literal_reference_values_and_gradients(pattern, layers):
    rng = random.Random(f"variation/{pattern}")
    options = RenderOptions(layers=layers)
    params = random_params(rng, pattern).replace(gap_scale=(rng.uniform(0.6, 0.95), rng.uniform(0.6, 0.95)),
                                                 tiles=(rng.uniform(15, 40), rng.uniform(15, 40)), **VARIED)
    xs, ys, r_ref = assert_fast_path_matches_reference(params, options, rng, 300, points=_points)
    # the variation shows: the same points without it differ
    plain = params.replace(**{n: getattr(FabricParams(), n) for n in VARIED})
    assert (reference.render_points(plain, xs, ys, DEFAULT_RIG, options)[0] - r_ref).abs().max() > 1e-3


def test_no_variation_renders_exactly_as_without_the_variation_parameters():
    """Every amplitude 0 (the default): the geometry state has no variation and the render is bit-identical
    whatever the correlation lengths, so every render of an unvaried fabric is the same as before them."""
    params = FabricParams(pattern="twill1", tiles=(60.0, 90.0))
    lengths = params.replace(width_variation_length=(5.0, 7.0), slub_variation_length=(9.0, 2.0))
    renderer = Renderer(size=32, spp=4)
    assert renderer.geometry_key(ParamTensors.from_params(lengths)).variation is None
    a, b = render_pair(params, size=32, spp=4), render_pair(lengths, size=32, spp=4)
    assert torch.equal(a.reflection, b.reflection) and torch.equal(a.transmission, b.transmission)
    varied = render_pair(params.replace(**VARIED), size=32, spp=4)
    assert (varied.reflection - a.reflection).abs().max() > 0.01


def test_varied_render_gradcheck_in_float64():
    """The optimised parameters' gradients with a yarn variation on (its amplitudes are geometry, not optimised)."""
    params = FabricParams(pattern="satin0", tiles=(30.0, 45.0), gap_scale=(0.85, 0.8), **VARIED)
    renderer = Renderer(size=5, spp=1, dtype=torch.float64)
    base = ParamTensors.from_params(params, dtype=torch.float64)
    names = ("roughness", "thickness", "specular_albedo", "diffuse_reflection", "height_scale")

    def radiance(*tensors):
        return renderer.radiance(base.with_values(**dict(zip(names, tensors))))

    inputs = tuple(base.values[n].detach().clone().requires_grad_(True) for n in names)
    assert torch.autograd.gradcheck(radiance, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


# -- the OSL shader and the fallback -------------------------------------------------------------
OSL_SOURCE = Path(__file__).resolve().parent.parent / "shaders" / "woven_fabric.osl"
OSL_BEGIN, OSL_END = "/* Yarn variation (backend/core/variation.py", "/* Segment coordinates of one yarn"


def test_osl_variation_constants_are_the_backends():
    source = OSL_SOURCE.read_text()
    assert f"#define WF_HASH_MODULUS {core.HASH_MODULUS:.1f}" in source
    assert f"#define WF_HASH_OFFSET {core.HASH_OFFSET:.1f}" in source
    assert f"#define WF_GAUSS_SCALE {core.GAUSS_SCALE!r}" in source
    assert f"#define WF_XI_MIN {core.XI_MIN!r}" in source
    for kind in core.KINDS:  # the streams wf_variation passes: 2 kind + family
        assert f"wf_smooth({core.stream(kind, 0)} + family" in source, kind


@pytest.mark.blender
def test_osl_variation_values_are_the_backends_bits(tmp_path):
    """The OSL shader's hash and smooth values (its own functions, compiled by Cycles into a probe shader that
    emits them) are the backend's: the hash bit for bit, the smooth values to float32 rounding."""
    from addon_support import run_blender

    source = OSL_SOURCE.read_text()
    helpers = source[source.index(OSL_BEGIN):source.index(OSL_END)]
    probe = helpers + textwrap.dedent("""
        shader wf_probe(point UV = point(0, 0, 0), output closure color Emit = 0)
        {
            float k = floor(UV[0] * 16.0) * 1237.0 - 9000.0;
            float j = floor(UV[1] * 16.0) * 523.0 - 4000.0;
            float h = wf_hash_key(wf_hash_key(wf_permute(wf_permute(9.0) + 1.0), k), j);
            Emit = emission() * color(k, j, h) + emission() * color(0, 0, 0);
            if (UV[0] > 0.0 && fmod(floor(UV[1] * 16.0), 2.0) > 0.5)
                Emit = emission() * color(k, j + 0.25, wf_smooth(3.0, k * 0.37 + j * 0.001, 2.5, 0.0, 0));
        }
    """)
    (tmp_path / "probe.osl").write_text(probe)
    result = run_blender(f"""
        import numpy as np
        from blender_addon.scene import cycles_osl
        mat = bpy.data.materials.new("probe")
        tree = mat.node_tree
        text = bpy.data.texts.new("probe.osl")
        text.from_string(open({str(tmp_path / 'probe.osl')!r}).read())
        script = tree.nodes.new("ShaderNodeScript")
        script.mode = "INTERNAL"
        script.script = text
        error = cycles_osl.compile_script(script)
        uv = tree.nodes.new("ShaderNodeUVMap")
        tree.links.new(uv.outputs["UV"], script.inputs["UV"])
        out = tree.nodes.get("Material Output") or tree.nodes.new("ShaderNodeOutputMaterial")
        tree.links.new(script.outputs["Emit"], out.inputs["Surface"])
        scene = rig_scene.build_scene(mat, size=48, samples=1, osl=True, scene=bpy.context.scene, threads=1)
        scene.cycles.filter_width = 0.01
        scene.render.image_settings.file_format = "OPEN_EXR"
        scene.render.image_settings.color_depth = "32"
        img = rig_scene.render_linear(scene, "front")[..., :3]
        emit({{"error": error, "pixels": img.reshape(-1, 3).tolist()}})
    """, tmp_path)
    assert not result["error"]
    pixels = np.array(result["pixels"], dtype=np.float64)
    keys = pixels[:, :2]
    hashed = pixels[np.all(keys == np.round(keys), axis=1)]
    smoothed = pixels[keys[:, 1] - np.floor(keys[:, 1]) == 0.25]
    assert len(hashed) > 100 and len(smoothed) > 100
    k, j = torch.tensor(hashed[:, 0]).long(), torch.tensor(hashed[:, 1]).long()
    assert torch.equal(variation.hash_keys(9, 1, k, j), torch.tensor(hashed[:, 2]).long())
    k, j = torch.tensor(smoothed[:, 0]), torch.tensor(np.floor(smoothed[:, 1]))
    expected = variation.smooth(3, k * 0.37 + j * 0.001, 2.5)
    # x near 4000 in float32 is within 2.4e-4 (its ulp) of float64's: g moves by at most a few times that
    torch.testing.assert_close(torch.tensor(smoothed[:, 2]), expected, rtol=0, atol=1e-3)


@pytest.mark.parametrize("pattern", ["plain", "twill1", "satin0"])
def test_fallback_variation_matches_the_backend(pattern):
    """The standard-node fallback's variation lines (evaluated with numpy; not in the built group:
    shader_fallback.FALLBACK_VARIATION) give the backend's varied layers, thicknesses and brightness."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tools"))
    from fallback_numpy import NumpyBuilder, fallback_env, rig_points

    from blender_addon.core import shader_fallback

    rng = np.random.default_rng(3)
    params = FabricParams(pattern=pattern, tiles=(23.0, 31.0), gap_scale=(0.85, 0.8), thickness=(1.2, 2.5),
                          **VARIED)
    x, y, wi = rig_points(rng, 3000)
    out = shader_fallback.run(NumpyBuilder(), fallback_env(params.to_dict(), x, y, wi), variation=True)
    camera = CameraSamples(DEFAULT_RIG, 512, 1, dtype=torch.float64)
    chunk = camera.at_points(torch.tensor(x), torch.tensor(y))
    key = GeometryKey(pattern, params.tiles, params.gap_scale, params.twist_deg, 0.0, True, 2,
                      variation.VariationSettings.of(lambda n: getattr(params, n)))
    geometry = sample_geometry(chunk, WeaveLookup(params.resolved_weave, dtype=torch.float64), DEFAULT_RIG, key,
                               torch.float64)
    for k, layer in enumerate(geometry.layers):
        yarn = np.where(layer.warp.numpy() > 0, 0, np.where(layer.weft.numpy() > 0, 1, 2))
        mine = np.where(out[f"y{k}w"] > 0.5, 0, np.where(out[f"y{k}f"] > 0.5, 1, 2))
        assert (yarn == mine).mean() > 0.998, k
        same = (yarn == mine) & (yarn != 2)
        thickness = np.where(yarn == 0, 1.2, 2.5) * layer.thickness_scale.numpy()
        assert np.abs(out[f"T{k}"] - thickness)[same].max() < 1e-4, k
        bright = np.where(yarn == 0, out["w_bright"], out["f_bright"])
        assert np.abs(bright - layer.albedo_scale.numpy())[same].max() < 1e-6, k
    seen = 1 - geometry.no_yarn.numpy() > 0
    assert np.abs(out["seen_bright"] - geometry.diffuse_scale.numpy())[seen].max() < 1e-6
    assert np.ptp(out["w_bright"]) > 0.3 and np.ptp(out["f_xi"]) > 0.1  # it varies


@pytest.mark.blender
def test_osl_shader_shows_the_backends_varied_gaps(tmp_path):
    """The whole OSL shader with a yarn variation (its lobes off: black where a yarn is, transparent where
    both layers are gaps) covers the pixels the backend's varied geometry covers: the yarn indices, positions
    and the varied widths and slides reach its layer lookup as they reach the renderer's."""
    from addon_support import run_blender

    size = 64
    params = FabricParams(pattern="plain", tiles=(3.0, 4.0), gap_scale=(0.75, 0.7), width_variation=(0.3, 0.3),
                          spacing_variation=(0.2, 0.2), slub_variation=(0.25, 0.25), slub_variation_length=(1.5, 1.5),
                          diffuse_normal_weight=0.0)
    bright = params.replace(brightness_variation=(0.3, 0.4), brightness_variation_length=(1.0, 2.0))
    result = run_blender(f"""
        import numpy as np
        from blender_addon.core import shader_params
        from blender_addon.scene import cycles_osl
        from blender_addon.scene.group_interface import socket_by_identifier
        mat = bpy.data.materials.new("varied")  # the shader alone: no node group (its fallback takes a while)
        tree = mat.node_tree
        text = bpy.data.texts.new("woven_fabric.osl")
        text.from_string(open({str(OSL_SOURCE)!r}).read())
        script = tree.nodes.new("ShaderNodeScript")
        script.mode = "INTERNAL"
        script.script = text
        error = cycles_osl.compile_script(script)
        def set_inputs(params, lobes):
            for name, value in shader_params.socket_values(params).items():
                if not isinstance(value, tuple):
                    socket_by_identifier(script.inputs, shader_params.osl_name(name)).default_value = value
            socket_by_identifier(script.inputs, "lobes").default_value = lobes
        set_inputs({params.to_dict()!r}, 0)
        uv, tangent = tree.nodes.new("ShaderNodeUVMap"), tree.nodes.new("ShaderNodeTangent")
        tangent.direction_type = "UV_MAP"
        tree.links.new(uv.outputs["UV"], socket_by_identifier(script.inputs, "UV"))
        tree.links.new(tangent.outputs["Tangent"], socket_by_identifier(script.inputs, "Tangent"))
        out = tree.nodes.get("Material Output") or tree.nodes.new("ShaderNodeOutputMaterial")
        tree.links.new(socket_by_identifier(script.outputs, "BSDF"), out.inputs["Surface"])
        scene = rig_scene.build_scene(mat, size={size}, samples=1, osl=True, scene=bpy.context.scene, threads=1)
        scene.cycles.filter_width = 0.01
        alpha = rig_scene.render_linear(scene, "front")[..., 3]
        set_inputs({params.to_dict()!r}, 16)  # the diffuse reflection alone
        plain = rig_scene.render_linear(scene, "front")[..., 1]
        set_inputs({bright.to_dict()!r}, 16)
        varied = rig_scene.render_linear(scene, "front")[..., 1]
        emit({{"error": error, "alpha": alpha.tolist(), "ratio": (varied / np.maximum(plain, 1e-12)).tolist()}})
    """, tmp_path)
    assert not result["error"]
    covered = np.array(result["alpha"]) > 0.5
    V = DEFAULT_RIG.view_size
    centres = (torch.arange(size, dtype=torch.float64) + 0.5) * V / size
    x, y = centres[None, :].expand(size, size).reshape(-1), -centres[:, None].expand(size, size).reshape(-1)
    chunk = CameraSamples(DEFAULT_RIG, 512, 1, dtype=torch.float64).at_points(x, y)

    def yarn_at_centres(fabric):
        key = GeometryKey("plain", fabric.tiles, fabric.gap_scale, fabric.twist_deg, 0.0, True, 2,
                          variation.VariationSettings.of(lambda n: getattr(fabric, n)))
        lookup = WeaveLookup(fabric.resolved_weave, dtype=torch.float64)
        no_yarn = sample_geometry(chunk, lookup, DEFAULT_RIG, key, torch.float64).no_yarn
        return (no_yarn == 0).numpy().reshape(size, size)

    varied, unvaried = yarn_at_centres(params), yarn_at_centres(params.replace(**{n: getattr(FabricParams(), n)
                                                                                  for n in VARIED}))
    # a pixel's one sample lies anywhere in it: pixels at an edge may go either way (measured: none did)
    assert (covered == varied).mean() > 0.98
    assert (covered == varied).mean() > (covered == unvaried).mean() + 0.05
    # the brightness of the yarn seen scales its diffuse reflection by the backend's factor
    key = GeometryKey("plain", bright.tiles, bright.gap_scale, bright.twist_deg, 0.0, True, 2,
                      variation.VariationSettings.of(lambda n: getattr(bright, n)))
    geometry = sample_geometry(chunk, WeaveLookup(bright.resolved_weave, dtype=torch.float64), DEFAULT_RIG, key,
                               torch.float64)
    factor = geometry.diffuse_scale.numpy().reshape(size, size)
    ratio = np.array(result["ratio"])
    seen = covered & varied
    assert np.ptp(factor[seen]) > 0.3
    assert np.mean(np.abs(ratio - factor)[seen] < 1e-3) > 0.98


def test_the_renderers_kept_geometry_follows_the_variation_and_its_twist_steps():
    """The renderer keeps geometry per state: a variation is part of the state, and a twist step on a varied
    state (only the fiber directions computed again) gives a fresh render's numbers."""
    params = FabricParams(pattern="twill0", tiles=(40.0, 55.0), twist_deg=(-20.0, -20.0))
    varied = params.replace(**VARIED)
    renderer = Renderer(size=24, spp=1)
    with torch.no_grad():
        first = renderer.render(params).reflection
        with_variation = renderer.render(varied).reflection
        assert (with_variation - first).abs().max() > 0.01
        assert torch.equal(renderer.render(params).reflection, first)
        turned = varied.replace(twist_deg=(-25.0, -15.0))
        stepped = renderer.render(turned)
        fresh = Renderer(size=24, spp=1).render(turned)
    torch.testing.assert_close(stepped.reflection, fresh.reflection, rtol=0, atol=1e-6)
    torch.testing.assert_close(stepped.transmission, fresh.transmission, rtol=0, atol=1e-6)
