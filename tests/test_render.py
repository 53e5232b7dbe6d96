"""The renderer: agreement with the literal reference (values and gradients), gradient health,
gradcheck, chunking, compilation, determinism, glow and noise."""
import dataclasses
import math
import random
import zlib

import numpy as np
import pytest
import torch
from oracles import reference

from backend.app.environment import compiler_found
from backend.core import variation as yarn_variation
from backend.core.options import RenderOptions
from backend.core.params import PARAMETERS, FabricParams
from backend.core.rig import DEFAULT_RIG, CaptureRig
from backend.model import imaging
from backend.model import render as render_module
from backend.model.bsdf import eval_projected
from backend.model.bsdf_gradient import eval_with_hand_gradient
from backend.model.camera import CameraSamples
from backend.model.geometry import GeometryKey, sample_geometry
from backend.model.imaging import display_transform, gaussian_blur, subpixel_blur
from backend.model.layers import WeaveLookup
from backend.model.param_tensors import ParamTensors
from backend.model.projections import project
from backend.model.render import AUTO_SUBPIXEL_BELOW_PX, GradientShare, Renderer
from blender_addon.core.rig_display import gaussian_blur as numpy_blur

OPTIMISED = [s.name for s in PARAMETERS if s.optimised]
VARIANTS = {"full": {}, "one_layer": {"layers": 1}, "sggx": {"multiple_lobe": "sggx"},
            "no_diffuse": {"diffuse": False}, "no_tension": {"tension": False}}


def random_params(rng: random.Random, pattern: str, extreme: bool = False) -> FabricParams:
    """Parameters drawn over the whole declared box (or at its edges when extreme)."""
    values = {}
    for spec in PARAMETERS:
        if spec.name == "noise" or spec.name in yarn_variation.PARAMETER_NAMES:  # none (tests/test_variation.py)
            continue
        lo, hi = spec.lo, spec.hi
        if spec.name == "tiles":
            lo, hi = 40.0, 200.0  # denser than the film's resolution would alias, sparser is dull
        if spec.name == "twist_deg":
            lo, hi = -45.0, 45.0

        def draw():
            return rng.choice([lo, hi]) if extreme and rng.random() < 0.5 else rng.uniform(lo, hi)

        flat = [draw() for _ in range(spec.size)]
        values[spec.name] = flat[0] if spec.size == 1 else (
            (tuple(flat[:3]), tuple(flat[3:])) if spec.per_yarn and spec.rgb else tuple(flat))
    return FabricParams(pattern=pattern, **values)


def fast_points(params: FabricParams, xs, ys, options: RenderOptions, tensors: ParamTensors, rig=DEFAULT_RIG,
                evaluate=eval_with_hand_gradient):
    """The renderer's evaluation at world points: ``evaluate`` is the eager path's (the hand-written
    gradient where it applies) or ``eval_projected`` (autograd's, what the compiled graph fuses)."""
    camera = CameraSamples(rig, 512, 1, dtype=torch.float64)
    chunk = camera.at_points(torch.tensor(xs, dtype=torch.float64), torch.tensor(ys, dtype=torch.float64))
    key = GeometryKey(params.pattern, params.tiles, params.gap_scale, params.twist_deg, 0.0, options.tension,
                      options.layers)
    geometry = sample_geometry(chunk, WeaveLookup(params.resolved_weave, dtype=torch.float64), rig, key, torch.float64)
    r, t = evaluate(project(chunk, geometry), tensors, options)
    return r.radiance(), t.radiance(), geometry.no_yarn


@pytest.mark.parametrize("gradient", ["hand", "autograd"])
@pytest.mark.parametrize("variant", list(VARIANTS))
@pytest.mark.parametrize("pattern", ["plain", "twill0", "twill1", "satin0", "satin1"])
def test_fast_path_matches_the_literal_reference(pattern, variant, gradient):
    rng = random.Random(zlib.crc32(f"{pattern}/{variant}".encode()))  # the same draw in every process
    options = RenderOptions.from_flags(VARIANTS[variant])
    params = random_params(rng, pattern).replace(gap_scale=(rng.uniform(0.6, 1.0), rng.uniform(0.6, 1.0)))
    evaluate = eval_with_hand_gradient if gradient == "hand" else eval_projected
    assert_fast_path_matches_reference(params, options, rng, 150,
                                       points=lambda *args: fast_points(*args, evaluate=evaluate))


def assert_fast_path_matches_reference(params: FabricParams, options: RenderOptions, rng: random.Random, count: int,
                                       points=fast_points) -> tuple[list[float], list[float], torch.Tensor]:
    """The fast path (``points``) and the literal reference agree at ``count`` random world points, in
    values and in the gradients of every optimised parameter; returns the points and the reference's
    reflection there."""
    V = DEFAULT_RIG.view_size
    xs = [rng.uniform(0, V) for _ in range(count)]
    ys = [rng.uniform(-V, 0) for _ in range(count)]
    fast = ParamTensors.from_params(params, dtype=torch.float64, requires_grad=OPTIMISED)
    ref = {n: fast.values[n].detach().clone().requires_grad_(True) for n in OPTIMISED}
    r_fast, t_fast, no_yarn = points(params, xs, ys, options, fast)
    r_ref, t_ref, ref_no_yarn = reference.render_points(params, xs, ys, DEFAULT_RIG, options, tensors=ref)
    assert torch.equal(no_yarn > 0, ref_no_yarn)
    torch.testing.assert_close(r_fast, r_ref, rtol=1e-5, atol=1e-8)
    torch.testing.assert_close(t_fast, t_ref, rtol=1e-5, atol=1e-8)
    weights = torch.rand(r_ref.shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    ((r_fast + 0.5 * t_fast) * weights).sum().backward()
    ((r_ref + 0.5 * t_ref) * weights).sum().backward()
    for name in OPTIMISED:
        torch.testing.assert_close(fast.values[name].grad, ref[name].grad, rtol=1e-4, atol=1e-7, msg=name)
    return xs, ys, r_ref.detach()


@pytest.mark.parametrize("pattern,degrees", [("twill0", 4.0), ("satin1", -7.5), ("plain", 30.0)])
def test_a_turned_sample_matches_the_reference_evaluated_in_the_fabric_frame(pattern, degrees):
    # The fast path turns the lookup point back and the yarn frames forward; the reference turns the
    # directions into the fabric's frame instead: two formulations that must agree.
    rng = random.Random(zlib.crc32(f"turned/{pattern}".encode()))
    rig = CaptureRig(sample_rotation_deg=degrees)
    params = random_params(rng, pattern).replace(gap_scale=(0.8, 0.85))
    V = rig.view_size
    xs = [rng.uniform(0, V) for _ in range(120)]
    ys = [rng.uniform(-V, 0) for _ in range(120)]
    fast = ParamTensors.from_params(params, dtype=torch.float64)
    r_fast, t_fast, no_yarn = fast_points(params, xs, ys, RenderOptions(), fast, rig)
    r_ref, t_ref, ref_no_yarn = reference.render_points(params, xs, ys, rig, RenderOptions())
    assert torch.equal(no_yarn > 0, ref_no_yarn)
    torch.testing.assert_close(r_fast, r_ref, rtol=1e-5, atol=1e-8)
    torch.testing.assert_close(t_fast, t_ref, rtol=1e-5, atol=1e-8)
    unturned = fast_points(params, xs, ys, RenderOptions(), fast)[0]
    assert (unturned - r_fast).abs().max() > 1e-3  # the rotation is not a no-op


@pytest.mark.parametrize("pattern", ["plain", "twill1", "satin0"])
def test_gradients_are_finite_over_the_whole_parameter_box(pattern):
    rng = random.Random(99)
    # A wide-angle rig with low lights puts grazing directions in the image.
    grazing = CaptureRig(fov_deg=150.0, front_light=(0.0, 30.0, 0.5), back_light=(0.0, 1.0, -0.3))
    for rig in (DEFAULT_RIG, grazing):
        renderer = Renderer(rig, size=24, spp=2)
        for trial in range(6):
            params = random_params(rng, pattern, extreme=True)
            if trial == 0:  # nearly all gap, nearly no thickness
                params = params.replace(gap_scale=(0.01, 0.01), thickness=(0.01, 0.01), thickness_multiple=(0.01, 0.01))
            fabric = ParamTensors.from_params(params, requires_grad=OPTIMISED)
            pair = renderer.render(fabric)
            assert torch.isfinite(pair.reflection).all() and torch.isfinite(pair.transmission).all()
            (pair.reflection.mean() + pair.transmission.mean()).backward()
            for name in OPTIMISED:
                assert torch.isfinite(fabric.values[name].grad).all(), (name, params)


def test_float64_gradcheck_on_a_small_image():
    params = FabricParams.from_interchange(
        "twill0_R_0.7,0.5_S_1.2,1.5_T_1.6,2.3_N_0.0_UV_140.0,90.0_Kd_0.07,0.3,0.2,0.18,0.25,0.26_G_0.85,0.9"
        "_Rm_0.6,0.36_Tm_2.9,2.1_W_0.6,0.8_Ks_0.3,0.5,0.2,0.2,0.6,0.6_Psi_-30.0,-30.0")
    renderer = Renderer(size=6, spp=1, dtype=torch.float64)
    base = ParamTensors.from_params(params, dtype=torch.float64)
    names = OPTIMISED

    def radiance(*tensors):
        r, t = renderer.radiance(base.with_values(**dict(zip(names, tensors))))
        return r, t

    inputs = tuple(base.values[n].detach().clone().requires_grad_(True) for n in names)
    assert torch.autograd.gradcheck(radiance, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)
    # The display transform away from its clamp and its black-level guard.
    x = (0.05 + 0.9 * torch.rand(20, 3, dtype=torch.float64)).requires_grad_(True)
    vignette = torch.rand(20, dtype=torch.float64) + 0.5
    assert torch.autograd.gradcheck(lambda v: display_transform(v, 2.2, 1.0, vignette), (x,))


def test_chunking_does_not_change_the_image():
    params = FabricParams.from_interchange(
        "satin1_R_0.18,0.75_S_1.0,0.96_T_1.58,2.79_N_0.0_UV_151.9,84.7_Kd_0.077,0.282,0.077,0.147,0.245,0.205"
        "_G_0.88,0.85_Rm_0.15,0.61_Tm_1.39,2.45_W_0.03,0.94_Ks_0.12,0.53,0.28,0.1,0.52,0.26_Psi_0.0,0.0")
    whole = Renderer(size=64, spp=4).render(params)
    pieces = Renderer(size=64, spp=4, max_chunk_samples=64 * 4 * 5, cache_samples=0).render(params)
    assert torch.equal(whole.reflection, pieces.reflection)
    assert torch.equal(whole.transmission, pieces.transmission)


def test_checkpointed_chunks_give_the_same_gradients():
    params = FabricParams()
    grads = []
    for chunk in (1 << 20, 32 * 2 * 7):
        fabric = ParamTensors.from_params(params, requires_grad=OPTIMISED)
        pair = Renderer(size=32, spp=2, max_chunk_samples=chunk).render(fabric)
        (pair.reflection.sum() + pair.transmission.sum()).backward()
        grads.append(torch.cat([fabric.values[n].grad.flatten() for n in OPTIMISED]))
    torch.testing.assert_close(grads[0], grads[1], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("period", [2, 3])
def test_a_gradient_share_keeps_the_values_and_its_phases_average_to_the_whole_gradient(monkeypatch, period):
    # 64 px, 4 spp in blocks of 8 rows: 8 blocks, shared 4 / 4 (period 2) or 3 / 3 / 2 (period 3)
    monkeypatch.setattr(render_module, "EAGER_BLOCK_SAMPLES", 64 * 4 * 8)
    params = FabricParams(pattern="twill0", tiles=(70.0, 90.0))
    renderer = Renderer(size=64, spp=4)

    def rendered(share):
        fabric = ParamTensors.from_params(params, requires_grad=OPTIMISED)
        with renderer.gradient_share(share):
            pair = renderer.render(fabric)
        loss = (pair.reflection ** 2).mean() + (pair.transmission ** 2).mean()  # not linear in the samples
        loss.backward()
        return pair, torch.cat([fabric.values[n].grad.flatten() for n in OPTIMISED])

    whole, gradient = rendered(None)
    phases = [rendered(GradientShare(phase, period)) for phase in range(period)]
    for pair, _ in phases:
        assert torch.equal(pair.reflection, whole.reflection) and torch.equal(pair.transmission, whole.transmission)
    shares = torch.stack([g for _, g in phases])
    assert all((share - gradient).norm() > 1e-3 * gradient.norm() for share in shares)  # each is a share, not all
    torch.testing.assert_close(shares.mean(0), gradient, rtol=1e-4, atol=1e-7)
    torch.testing.assert_close(rendered(GradientShare(5, 1))[1], gradient)  # a period of 1 is every block


def test_a_render_without_gradients_ignores_the_gradient_share(monkeypatch):
    monkeypatch.setattr(render_module, "EAGER_BLOCK_SAMPLES", 32 * 4 * 8)  # 4 blocks of 8 rows
    params = FabricParams(pattern="plain", tiles=(60.0, 60.0))
    renderer = Renderer(size=32, spp=4)
    with torch.no_grad():
        whole = renderer.render(params)
        with renderer.gradient_share(GradientShare(1, 2)):
            shared = renderer.render(params)
    assert torch.equal(whole.reflection, shared.reflection)
    assert renderer._gradient_share is None  # the share holds for its block only


def test_the_eager_blocks_merge_only_where_no_gradient_is_taken():
    from backend.model.render import eager_blocks
    assert eager_blocks(16, 2, 8, None) == [(0, 8, False), (8, 16, False)]
    assert eager_blocks(16, 2, 8, lambda k: True) == [(r, r + 2, True) for r in range(0, 16, 2)]
    share = GradientShare(1, 4)  # blocks 1 and 5 carry, each the same 2 rows as unmerged
    assert eager_blocks(16, 2, 8, share.carries) == [(0, 2, False), (2, 4, True), (4, 10, False), (10, 12, True),
                                                     (12, 16, False)]
    assert eager_blocks(5, 2, 8, None) == [(0, 5, False)]  # a last short block joins too


def test_larger_forward_blocks_give_the_same_images_and_gradients(monkeypatch):
    params = FabricParams(pattern="satin1", tiles=(80.0, 60.0), forward_scattering=(0.3, 0.1))
    results = []
    for forward in (32 * 4 * 4, 32 * 4 * 16):  # the forward blocks as small as the others, or 4 of them
        monkeypatch.setattr(render_module, "EAGER_BLOCK_SAMPLES", 32 * 4 * 4)  # 8 blocks of 4 rows
        monkeypatch.setattr(render_module, "FORWARD_BLOCK_SAMPLES", forward)
        renderer = Renderer(size=32, spp=4)
        with torch.no_grad():
            plain = renderer.render(params)
        fabric = ParamTensors.from_params(params, requires_grad=OPTIMISED)
        with renderer.gradient_share(GradientShare(2, 4)):
            pair = renderer.render(fabric)
        (pair.reflection.square().mean() + pair.transmission.mean()).backward()
        results.append((plain.reflection, plain.transmission, pair.reflection.detach(),
                        torch.cat([fabric.values[n].grad.flatten() for n in OPTIMISED])))
    for small, large in zip(*results):
        assert torch.equal(small, large)


def test_fixed_seed_is_deterministic_and_seeds_differ():
    params = FabricParams(pattern="twill1", tiles=(90.0, 120.0))
    a = Renderer(size=32, spp=4, seed=3).render(params).reflection
    b = Renderer(size=32, spp=4, seed=3).render(params).reflection
    c = Renderer(size=32, spp=4, seed=4).render(params).reflection
    assert torch.equal(a, b)
    assert not torch.equal(a, c)


def test_jitter_is_stratified():
    jx, jy = CameraSamples(DEFAULT_RIG, 4, 4, seed=1).jitter(0, 4)
    cells = ((jx * 2).floor() + 2 * (jy * 2).floor()).long()  # the quarter each sample lands in
    assert (cells.sort(-1).values == torch.arange(4)).all()


@pytest.mark.slow
@pytest.mark.skipif(not compiler_found(), reason="torch.compile needs a C++ compiler, none found")
def test_compiled_renderer_matches_eager_and_is_kept_in_the_disk_cache():
    params = FabricParams.from_interchange(
        "plain_R_0.49,0.49_S_1.5,1.5_T_1.48,1.48_N_0.0_UV_150.6,150.6_Kd_0.077,0.282,0.077,0.147,0.245,0.205"
        "_G_0.88,0.88_Rm_0.37,0.37_Tm_0.8,0.8_W_0.54,0.9_Ks_0.1,0.52,0.26,0.1,0.52,0.26_Psi_0.0,0.0")
    from torch._dynamo.utils import counters
    counters.clear()
    results = []
    for compiled in (False, True):
        renderer = Renderer(size=48, spp=4, compile=compiled)  # a shape no other test compiles
        fabric = ParamTensors.from_params(params, requires_grad=OPTIMISED)
        pair = renderer.render(fabric)
        (pair.reflection.mean() + pair.transmission.mean()).backward()
        assert renderer.compiled == compiled
        results.append((pair.reflection.detach(), pair.transmission.detach(),
                        torch.cat([fabric.values[n].grad.flatten() for n in OPTIMISED])))
    # AOTAutograd keeps the compiled forward + backward on disk, unless the graph holds something it
    # will not save: the BSDF's torch.autograd.Function is one until the renderer allows it
    # (backend.model.compile_cache.allow_cached_custom_gradients). Bypassed, every process traced
    # the backward anew, 4-5 s at each fit's start.
    cache = counters["aot_autograd"]
    assert cache["autograd_cache_hit"] + cache["autograd_cache_miss"] >= 1, dict(cache)
    assert cache["autograd_cache_bypass"] == 0, dict(cache)
    # Inductor's vectorised exp/sqrt differ from ATen's by a few ulp; the transmission's attenuation
    # exp(-T S) of thick layers amplifies that to ~1.5e-4 relative on a few pixels (reflection: 2e-7).
    for eager, fused in zip(*results):
        torch.testing.assert_close(fused, eager, rtol=3e-4, atol=1e-6)
    # a render without gradients, after one with them, goes through the same graph: nothing compiles again
    graphs = counters["stats"]["unique_graphs"]
    with torch.no_grad():
        again = renderer.render(params)
    assert counters["stats"]["unique_graphs"] == graphs
    torch.testing.assert_close(again.reflection, results[0][0], rtol=3e-4, atol=1e-6)
    torch.testing.assert_close(again.transmission, results[0][1], rtol=3e-4, atol=1e-6)


def test_a_compiling_renderer_fuses_renders_without_gradients_once_it_knows_the_graphs_inputs(monkeypatch, tmp_path):
    """Renders without gradients stay eager until a render with gradients has gone through the
    compiled graph (one call per chunk of rows), or the renderer was told which inputs need them;
    after that they go through it too, with the same inputs needing gradients and grad mode on (no
    second graph to compile), and keep nothing. Here torch.compile hands back the function itself
    with a record of each call, so no C++ compiler is needed."""
    import backend.model.render as render_module
    calls = []

    def fake_compile(fn, **kwargs):
        def counted(samples, fabric):
            calls.append((torch.is_grad_enabled(), frozenset(n for n, v in fabric.values.items() if v.requires_grad)))
            return fn(samples, fabric)
        return counted

    monkeypatch.setattr(render_module.torch, "compile", fake_compile)
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", str(tmp_path))
    params = FabricParams(pattern="twill1")
    wanted = frozenset(OPTIMISED)
    renderer = Renderer(size=32, spp=4, compile=True, max_chunk_samples=32 * 4 * 8)  # 4 chunks of rows
    assert renderer.compiled and len(renderer.ranges) == 4
    with torch.no_grad():
        plain = renderer.render(params)
    assert calls == []
    fabric = ParamTensors.from_params(params, requires_grad=OPTIMISED)
    fused = renderer.render(fabric)
    (fused.reflection.mean() + fused.transmission.mean()).backward()
    # each chunk is recomputed in the backward pass (with gradients), after a forward without them
    assert calls.count((True, wanted)) == 4 and len(calls) == 8
    assert torch.equal(fused.reflection.detach(), plain.reflection)
    assert torch.equal(fused.transmission.detach(), plain.transmission)
    assert all(fabric.values[n].grad is not None for n in OPTIMISED)
    calls.clear()
    whole = Renderer(size=32, spp=4, compile=True)  # one chunk: the fit's usual case, no recomputation
    with torch.no_grad():
        first = whole.render(params)
    assert calls == []
    whole.render(ParamTensors.from_params(params, requires_grad=OPTIMISED))
    assert calls == [(True, wanted)]
    with torch.no_grad():
        later = whole.render(params.replace(roughness=(0.3, 0.5)))
        again = whole.render(params)
    assert calls == [(True, wanted)] * 3
    assert not later.reflection.requires_grad and not torch.equal(later.reflection, first.reflection)
    assert torch.equal(again.reflection, first.reflection) and torch.equal(again.transmission, first.transmission)
    calls.clear()
    declared = Renderer(size=32, spp=4, compile=True, gradient_inputs=OPTIMISED)  # as a fit's renderer is made
    with torch.no_grad():
        early = declared.render(params)
    assert calls == [(True, wanted)]
    assert torch.equal(early.reflection, first.reflection) and torch.equal(early.transmission, first.transmission)


def test_glow_shows_only_through_gaps_at_the_centre():
    params = FabricParams(pattern="plain", gap_scale=(0.6, 0.6))
    with_glow = Renderer(size=64, spp=4).render(params).transmission
    without = Renderer(size=64, spp=4, options=RenderOptions(glow=False)).render(params).transmission
    diff = (with_glow - without).mean(-1)
    assert diff[32, 32] > 0.05          # bright where the lamp shows through
    assert diff[2, 2].abs() < 1e-6      # exp(-d^2 / 20^2) is nothing at the corners
    closed = params.replace(gap_scale=(1.0, 1.0))
    assert torch.equal(Renderer(size=64, spp=4).render(closed).transmission,
                       Renderer(size=64, spp=4, options=RenderOptions(glow=False)).render(closed).transmission)


def test_vignetting_follows_the_film_not_the_resolution():
    small = CameraSamples(DEFAULT_RIG, 64, 1).pixel_falloff(450.0)
    large = CameraSamples(DEFAULT_RIG, 512, 1).pixel_falloff(450.0)
    assert small.max().item() == pytest.approx(1.0)
    assert small[0, 0].item() == pytest.approx(large[:8, :8].mean().item(), abs=2e-3)


@pytest.mark.parametrize("pattern", ["plain", "satin0"])
def test_noise_changes_the_fabric_deterministically(pattern):
    params = FabricParams(pattern=pattern, tiles=(60.0, 60.0))
    quiet = Renderer(size=32, spp=2).render(params).reflection
    noisy = Renderer(size=32, spp=2).render(params.replace(noise=1.0)).reflection
    again = Renderer(size=32, spp=2).render(params.replace(noise=1.0)).reflection
    assert torch.equal(noisy, again)
    assert (noisy - quiet).abs().mean() > 1e-3


def test_options_reject_unknown_flags():
    with pytest.raises(ValueError, match="unknown flag"):
        RenderOptions.from_flags({"layer": 1})
    with pytest.raises(ValueError, match="multiple_lobe"):
        RenderOptions.from_flags({"multiple_lobe": "ggx"})


def test_rig_settings_are_validated():
    with pytest.raises(ValueError, match="back_light"):
        CaptureRig(back_light=(0.0, 0.0, 2.0))
    with pytest.raises(ValueError, match="fov_deg"):
        CaptureRig(fov_deg=0.0)
    with pytest.raises(ValueError, match="unknown setting"):
        CaptureRig.from_dict({"camera_hieght": 8})
    with pytest.raises(ValueError, match="camera_blur_px"):
        CaptureRig(camera_blur_px=-0.5)
    # V = 2 * 8 * tan(26.5 deg) = 7.97731 (the spec prints 7.9787..., which its own formula does not give).
    assert CaptureRig().view_size == pytest.approx(7.97731, abs=1e-5)
    assert dataclasses.asdict(CaptureRig.from_dict(DEFAULT_RIG.to_dict())) == dataclasses.asdict(DEFAULT_RIG)


def test_camera_blur_keeps_the_mean_and_softens_the_yarn_lattice():
    params = FabricParams(pattern="twill0", tiles=(120.0, 120.0))
    sharp_renderer = Renderer(DEFAULT_RIG, 128, 4, subpixel_blur=True)
    sharp = sharp_renderer.render(params)
    soft = Renderer(CaptureRig(camera_blur_px=4.0), 128, 4, subpixel_blur=True).render(params)  # 1 px at 128 px
    assert torch.allclose(Renderer(CaptureRig(camera_blur_px=4.0), 128, 4).render(params).reflection_radiance,
                          gaussian_blur(sharp.reflection_radiance, 1.0))  # a fit's: on the pixel means
    with torch.no_grad():
        fine = sharp_renderer.radiance(ParamTensors.from_params(params), fine=True)
    # the sub-pixels are the quarters of each pixel's 2 x 2 strata: their mean is the pixel's (the
    # glow, added where a sample sees no yarn, is taken at each sub-pixel's centre: 5 px wide here)
    pooled = [imaging._pooled(sub) for sub in fine]
    assert fine[0].shape == fine[1].shape == (256, 256, 3)
    assert torch.allclose(pooled[0], sharp.reflection_radiance, atol=1e-6)
    assert pooled[1].mean().item() == pytest.approx(sharp.transmission_radiance.mean().item(), rel=0.002)
    for a, sub, b in ((sharp.reflection_radiance, fine[0], soft.reflection_radiance),
                      (sharp.transmission_radiance, fine[1], soft.transmission_radiance)):
        blurred = subpixel_blur(sub, 1.0)  # blurred on the sub-pixels, then each pixel their mean
        assert torch.allclose(b, blurred)
        # mirrored borders: the mean moves by edge effects only
        assert blurred.mean().item() == pytest.approx(a.mean().item(), rel=0.02)
        detail = lambda img: (img[1:] - img[:-1]).abs().mean().item()  # noqa: E731
        assert detail(blurred) < 0.7 * detail(a)
    assert torch.equal(gaussian_blur(sharp.reflection, 0.0), sharp.reflection)


@pytest.mark.parametrize("half", [1, 2, 3, 4])
def test_quarter_means_are_the_means_of_each_quarter_of_the_strata_and_carry_their_gradient(half):
    """render.quarter_means: each quarter's mean of a pixel's k x k strata (k = 2 half), as torch's
    mean over the quarter's rows and columns gives it, to the float's rounding, and the same gradient
    (1 / half^2 to each of its samples)."""
    gen = torch.Generator().manual_seed(11 + half)
    strata = (torch.rand(3, 5, 7, 2, half, 2, half, generator=gen) * 10.0 ** (4 * torch.rand(3, 1, 1, 1, 1, 1, 1,
                                                                                          generator=gen) - 2))
    strata.requires_grad_(True)
    got = render_module.quarter_means(strata)
    assert got.shape == (3, 5, 7, 2, 2)
    literal = torch.stack([torch.stack([strata[..., qy, :, qx, :].reshape(3, 5, 7, -1).double().mean(-1)
                                        for qx in range(2)], -1) for qy in range(2)], -2)
    assert torch.allclose(got.double(), literal, rtol=1e-6, atol=0)
    assert torch.allclose(got, strata.mean((-3, -1)), rtol=1e-6, atol=0)
    weights = torch.rand(got.shape, generator=gen)
    (grad,) = torch.autograd.grad((got * weights).sum(), strata)
    (expected,) = torch.autograd.grad((strata.mean((-3, -1)) * weights).sum(), strata)
    assert torch.allclose(grad, expected, rtol=1e-6, atol=0)


def test_auto_subpixel_blur_takes_the_subpixels_only_under_the_alias_free_width():
    """subpixel_blur=None: a blur narrower than AUTO_SUBPIXEL_BELOW_PX render pixels acts on the
    sub-pixels (as subpixel_blur=True), a wider one on the pixel means (as False)."""
    params = FabricParams(pattern="plain", tiles=(200.0, 200.0))  # 0.2 px per yarn at 64 px: the two ways differ
    renderers = {mode: Renderer(DEFAULT_RIG, 64, 4, subpixel_blur=mode) for mode in (None, True, False)}
    film_px = DEFAULT_RIG.film_size / 64  # film pixels per render pixel
    with torch.no_grad():
        for render_px, same_as in ((0.6, True), (AUTO_SUBPIXEL_BELOW_PX - 0.05, True),
                                   (AUTO_SUBPIXEL_BELOW_PX, False), (2.0, False)):
            blurred = {mode: renderer.blurred(params, camera_blur_px=render_px * film_px)[0]
                       for mode, renderer in renderers.items()}
            assert torch.equal(blurred[None], blurred[same_as])
            assert not torch.allclose(blurred[True], blurred[False], atol=1e-4)  # the two ways differ here


@pytest.mark.parametrize("subpixels, images", [(False, 1), (True, 2)])
def test_a_blur_scan_renders_the_radiance_once(monkeypatch, subpixels, images):
    """Without gradients the last radiance is reused for the same parameter values (a camera-blur scan
    blurs one render), with the numbers of a fresh render; other values, or gradients, render anew.
    Blurring on sub-pixels, a scan that includes no blur renders the pixels and the sub-pixels once each."""
    params = FabricParams(pattern="twill0", tiles=(120.0, 120.0))
    blurs = (0.0, 1.0, 2.0)
    with torch.no_grad():
        fresh = [Renderer(DEFAULT_RIG, 64, 4, subpixel_blur=subpixels).blurred(params, camera_blur_px=blur)
                 for blur in blurs]
    renderer = Renderer(DEFAULT_RIG, 64, 4, subpixel_blur=subpixels)
    calls = []
    radiance = Renderer.radiance
    monkeypatch.setattr(Renderer, "radiance", lambda self, *args, **kwargs: calls.append(1)
                        or radiance(self, *args, **kwargs))
    with torch.no_grad():
        scan = [renderer.blurred(params, camera_blur_px=blur) for blur in blurs]
        assert len(calls) == images
        for (reflection, transmission), (expected_r, expected_t) in zip(scan, fresh):
            assert torch.equal(reflection, expected_r) and torch.equal(transmission, expected_t)
        renderer.blurred(params.replace(roughness=(0.3, 0.3)), camera_blur_px=1.0)
        assert len(calls) == images + 1
    fabric = ParamTensors.from_params(params.replace(roughness=(0.3, 0.3)), requires_grad=["roughness"])
    reflection, _ = renderer.blurred(fabric, camera_blur_px=1.0)
    assert len(calls) == images + 2 and reflection.requires_grad


@pytest.mark.parametrize("size, sigma", [(64, 0.0), (64, 0.3), (96, 0.9), (32, 4.0)])
def test_the_sub_pixel_blur_is_its_step_by_step_reference_with_its_gradients(size, sigma):
    """The blur and the 2 x 2 means in one strided kernel equal the whole sub-pixel image blurred and
    then averaged, values and gradients (the kernel reaches across the mirrored borders alike)."""
    torch.manual_seed(3)
    image = torch.rand(size, size, 3, dtype=torch.float64, requires_grad=True)
    weights = torch.rand(size // 2, size // 2, 3, dtype=torch.float64)
    fast, slow = imaging.subpixel_blur(image, sigma), imaging.subpixel_blur_reference(image, sigma)
    assert fast.shape == (size // 2, size // 2, 3)
    assert torch.allclose(fast, slow, atol=1e-12)
    (fast_grad,) = torch.autograd.grad((fast * weights).sum(), image)
    (slow_grad,) = torch.autograd.grad((slow * weights).sum(), image)
    assert torch.allclose(fast_grad, slow_grad, atol=1e-12)


@pytest.mark.parametrize("blur", [imaging.gaussian_blur, imaging.subpixel_blur])
@pytest.mark.parametrize("sigma", [0.4, 1.3, 2.7])
def test_a_tensor_sigma_blurs_as_its_number_and_has_the_derivative_of_the_blur(blur, sigma):
    """The fit estimates the camera blur by gradient: a 0-d tensor sigma gives the float's image
    (the same taps, made in torch), and d(image)/d(sigma) is the finite difference of the float blurs
    (central, 1e-5 px; float64) and passes gradcheck."""
    torch.manual_seed(5)
    image = torch.rand(48, 48, 3, dtype=torch.float64)
    weights = torch.rand_like(blur(image, sigma))
    at = torch.tensor(sigma, dtype=torch.float64, requires_grad=True)
    assert torch.allclose(blur(image, at), blur(image, sigma), atol=1e-12)
    (derivative,) = torch.autograd.grad((blur(image, at) * weights).sum(), at)
    h = 1e-5
    difference = ((blur(image, sigma + h) - blur(image, sigma - h)) * weights).sum() / (2 * h)
    assert float(derivative) == pytest.approx(float(difference), rel=1e-6)
    assert float(derivative) != 0.0
    assert torch.autograd.gradcheck(lambda s: blur(image, s), (at,))


@pytest.mark.parametrize("frequency, sigma", [(0.3, 1.2), (0.45, 0.6), (0.6, 0.8), (0.7, 0.9), (0.85, 1.0)])
def test_the_camera_blur_on_sub_pixels_passes_what_the_optics_pass(frequency, sigma):
    """A cosine of ``frequency`` cycles per pixel, blurred by a Gaussian of ``sigma`` pixels and then
    integrated over each pixel (a camera): exp(-2 pi^2 sigma^2 f^2) sinc(f) cos(2 pi f (x + 1/2)),
    where sinc(f) = sin(pi f) / (pi f) is what the pixel alone passes. Blurred on sub-pixels and then
    averaged 2 x 2 (the renderer's formation), the result is within 0.2 % of sinc(f) everywhere.
    Blurred after the pixel means, a cosine above the pixels' Nyquist frequency leaves its alias at
    1 - f, which the blur there barely touches (13-63 % of sinc(f) stay, where the optics leave
    0.5 % at most), and one just below it passes too strongly (the sampled kernel folds the
    Gaussian's response about the pixel grid); a well-sampled one comes out the same either way."""
    n = 64
    x = torch.arange(2 * n, dtype=torch.float64)

    def box_means(width):  # the exact means of the cosine over cells of ``width`` pixels
        centres = (x[: int(n / width)] + 0.5) * width
        return torch.cos(2 * math.pi * frequency * centres) * math.sin(math.pi * frequency * width) / (
            math.pi * frequency * width)

    def image(row):  # constant down the columns: the blur acts along the rows alone
        return row[None, :, None].expand(32, -1, 1).contiguous()

    pixel_only = abs(math.sin(math.pi * frequency) / (math.pi * frequency))
    centres = x[:n] + 0.5
    truth = (math.exp(-2 * math.pi ** 2 * sigma ** 2 * frequency ** 2) * math.sin(math.pi * frequency)
             / (math.pi * frequency) * torch.cos(2 * math.pi * frequency * centres))
    inside = slice(12, n - 12)  # away from the mirrored borders
    on_subpixels = subpixel_blur(image(box_means(0.5)), sigma)[8, :, 0][inside]
    on_pixels = gaussian_blur(image(box_means(1.0)), sigma)[8, :, 0][inside]
    sub_error = float((on_subpixels - truth[inside]).abs().max()) / pixel_only
    pixel_error = float((on_pixels - truth[inside]).abs().max()) / pixel_only
    assert sub_error < 0.002
    if frequency < 0.4:
        assert pixel_error < 0.002
    else:
        assert pixel_error > 0.1


@pytest.mark.parametrize("pattern, noise, placement", [("plain", 3.0, (0.0, 0.0)), ("twill1", 0.0, (2.5, 0.0)),
                                                      ("satin0", 5.0, (-1.5, 2.0))])
def test_gap_and_twist_steps_reuse_the_lattice_bands_with_the_numbers_of_a_fresh_render(pattern, noise, placement,
                                                                                     monkeypatch):
    """A discrete search renders one lattice at several gap scales and twists: the renderer computes
    the lattice's bands once (``tile_bands``), a twist step computes only the fiber directions again
    (a kept state at another twist: ``retwisted``), and each image is the one a fresh renderer makes."""
    from backend.model import render as render_module

    rig = dataclasses.replace(DEFAULT_RIG, sample_rotation_deg=placement[0], sample_skew_deg=placement[1])
    base = FabricParams(pattern=pattern, tiles=(70.0, 90.0), noise=noise)
    steps = [base, base.replace(gap_scale=(0.7, 0.95)), base.replace(twist_deg=(-20.0, 10.0)),
             base.replace(gap_scale=(0.8, 0.6), twist_deg=(5.0, -30.0)),
             base.replace(gap_scale=(0.8, 0.6), twist_deg=(5.0, 25.0))]
    calls, made, retwisted = [], [], []
    for name, log in (("tile_bands", calls), ("sample_geometry", made), ("retwisted", retwisted)):
        counted = getattr(render_module, name)
        monkeypatch.setattr(render_module, name, lambda *args, log=log, f=counted: log.append(1) or f(*args))
    renderer = Renderer(rig, 48, 4)
    with torch.no_grad():
        for params in steps:
            kept = renderer.radiance(ParamTensors.from_params(params))
            fresh = Renderer(rig, 48, 4).radiance(ParamTensors.from_params(params))
            assert torch.equal(kept[0], fresh[0]) and torch.equal(kept[1], fresh[1])
        assert len(calls) == 1 + len(steps)  # once for the kept renderer, once per fresh one
        assert len(retwisted) == 2 and len(made) == len(steps) + 3  # the twist steps; the others, and the fresh ones
        renderer.radiance(ParamTensors.from_params(base.replace(tiles=(71.0, 90.0))))
        assert len(calls) == 2 + len(steps)  # another lattice: new bands


@pytest.mark.parametrize("pattern, placement", [("twill1", (2.3, 1.4)), ("satin0", (0.0, 0.0))])
def test_the_projections_are_the_float64_products_rounded_once(pattern, placement):
    """Each cosine part a float32 render keeps (:mod:`backend.model.projections`) is the float64 value
    rounded once to float32: the in-plane sums formed in float64, the z products in float32 (exact,
    since the product of two floats is exact in float64)."""
    rig = dataclasses.replace(DEFAULT_RIG, sample_rotation_deg=placement[0], sample_skew_deg=placement[1])
    params = FabricParams(pattern=pattern, tiles=(70.0, 90.0), gap_scale=(0.8, 0.9), twist_deg=(-20.0, 10.0))
    chunk = CameraSamples(rig, 64, 4, seed=3).chunk(0, 64)
    key = GeometryKey(pattern, params.tiles, params.gap_scale, params.twist_deg, 0.0, True, 2)
    geometry = sample_geometry(chunk, WeaveLookup(params.resolved_weave), rig, key)
    projected = project(chunk, geometry)

    def rounded(d, v):  # (plane, z) of d . v in float64, rounded once
        d, v = d.double(), v.double()
        return (d[0] * v[0] + d[1] * v[1]).float(), (d[2] * v[2]).float()

    for layer, projections in zip(geometry.layers, projected.layers):
        splits = [(chunk.wi, layer.fiber, projections.wi)]
        for light, samples in ((projections.front, chunk.front), (projections.back, chunk.back)):
            splits += [(samples.wo, layer.fiber, light.out), (samples.half, layer.fiber, light.half),
                       (samples.wo, layer.normal, light.normal)]
        for d, v, split in splits:
            plane, z = rounded(d, v)
            assert split.plane.dtype == split.z.dtype == torch.float32
            assert torch.equal(split.plane, plane) and torch.equal(split.z, z)
        for v, plane2, z2 in ((layer.fiber, projections.fiber_plane2, projections.fiber_z2),
                              (layer.normal, projections.normal_plane2, projections.normal_z2)):
            plane, z = rounded(v, v)
            assert torch.equal(plane2, plane) and torch.equal(z2, z)


def test_camera_blur_has_a_gradient_and_matches_the_addon_preview():
    image = torch.rand(24, 24, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: gaussian_blur(x, 1.3), (image,))
    assert np.allclose(gaussian_blur(image, 1.3).detach().numpy(), numpy_blur(image.detach().numpy(), 1.3))
    # the matrix product is the mirrored-border convolution at any radius, on any shape
    wide = torch.rand(20, 36, 2, dtype=torch.float64)
    for sigma in (0.4, 2.5, 9.0):  # 9 px: the radius is clipped to the image (19 px)
        assert np.allclose(gaussian_blur(wide, sigma).numpy(), numpy_blur(wide.numpy(), sigma))


def test_the_convolution_path_of_the_blur_is_the_matrix_products():
    """Colour images with a short kernel take the depthwise convolution (imaging.CONV_TAPS_PER_PIXEL):
    the same mirrored-border sums and gradient as the matrix products and the add-on's preview."""
    generator = torch.Generator().manual_seed(3)
    image = torch.rand(60, 64, 3, dtype=torch.float64, generator=generator)
    for sigma in (0.3, 0.6):  # 3 and 5 taps: within 10 % of the 60-px side
        assert 2 * imaging.blur_radius(sigma, 59) + 1 <= imaging.CONV_TAPS_PER_PIXEL * 60
        radius = imaging.blur_radius(sigma, 59)
        convolved = imaging._convolved(image, imaging.gaussian_kernel(sigma, radius), radius)
        assert torch.allclose(gaussian_blur(image, sigma), convolved, rtol=0, atol=0)  # this path was taken
        assert np.allclose(convolved.numpy(), numpy_blur(image.numpy(), sigma))
        planes = image.permute(2, 0, 1)
        rows = imaging.blur_matrix(60, sigma, 59, torch.float64)
        cols = imaging.blur_matrix(64, sigma, 59, torch.float64)
        assert torch.allclose(convolved, (rows @ planes @ cols.T).permute(1, 2, 0))
    small = torch.rand(30, 30, 2, dtype=torch.float64, generator=generator, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: gaussian_blur(x, 0.3), (small,))


@pytest.mark.parametrize("sigma", [0.3, 0.9, 2.8])
def test_the_blur_s_shifted_sums_are_the_depthwise_convolution_with_its_gradients(sigma):
    """imaging._shifted_sums (the camera blur at stride 1) against PyTorch's depthwise convolution
    (imaging._depthwise_conv, its plain twin): the same values, and the same gradients with respect to
    the image and to a tensor sigma's taps, to float rounding."""
    generator = torch.Generator().manual_seed(11)
    image = torch.rand(40, 52, 3, dtype=torch.float64, generator=generator, requires_grad=True)
    weights = torch.rand(40, 52, 3, dtype=torch.float64, generator=generator)
    radius = imaging.blur_radius(sigma, 39)
    outputs = []
    for blur in (imaging._shifted_sums, lambda planes, taps: imaging._depthwise_conv(planes[None], taps)[0]):
        image.grad = None
        sigma_t = torch.tensor(sigma, dtype=torch.float64, requires_grad=True)
        taps = imaging.gaussian_taps(sigma_t, radius, torch.float64)
        planes = torch.nn.functional.pad(image.permute(2, 0, 1)[None], (radius,) * 4, mode="reflect")[0]
        out = blur(planes, taps)
        (out.permute(1, 2, 0) * weights).sum().backward()
        outputs.append((out.detach(), image.grad.clone(), sigma_t.grad.clone()))
    (shifted, image_grad, sigma_grad), (conv, conv_image_grad, conv_sigma_grad) = outputs
    assert shifted.shape == conv.shape == (3, 40, 52)
    assert torch.allclose(shifted, conv, rtol=1e-12, atol=1e-14)
    assert torch.allclose(image_grad, conv_image_grad, rtol=1e-12, atol=1e-14)
    assert torch.allclose(sigma_grad, conv_sigma_grad, rtol=1e-10)
    numpy_taps = imaging.gaussian_kernel(sigma, radius)  # a fixed blur's taps: plain numbers
    assert torch.allclose(imaging._shifted_sums(planes.detach(), numpy_taps),
                          imaging._depthwise_conv(planes.detach()[None], numpy_taps)[0], rtol=1e-12, atol=1e-14)
