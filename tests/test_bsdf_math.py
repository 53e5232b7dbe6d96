"""The math of the lobes: normalisation, reciprocity, energy, and the fast forms vs the literal ones."""
import math

import pytest
import torch
from oracles import reference

from backend.model import asggx, sggx
from backend.model.spongecake import eval_layer, one_minus_exp_over, slab_g
from backend.model.yarn import scale_height

DT = torch.float64


def sphere(n: int) -> torch.Tensor:
    """Fibonacci lattice: n quasi-uniform unit vectors (3, n), each standing for 4 pi / n sr."""
    i = torch.arange(n, dtype=DT) + 0.5
    z = 1 - 2 * i / n
    r = torch.sqrt(1 - z * z)
    phi = math.pi * (1 + 5 ** 0.5) * i
    return torch.stack((r * torch.cos(phi), r * torch.sin(phi), z))


def random_unit(gen, n=1):
    v = torch.randn(3, n, generator=gen, dtype=DT)
    return v / v.norm(dim=0, keepdim=True)


WO = sphere(1_000_000)


@pytest.mark.parametrize("alpha", [0.1, 0.3, 0.7, 1.0])
@pytest.mark.parametrize("theta", [0.0, 0.6, 1.2, 1.5])
def test_sggx_phase_function_integrates_to_one(alpha, theta):
    # Fiber along z; wi at angle theta to the fiber.
    wi = torch.tensor([math.sin(theta), 0.0, math.cos(theta)], dtype=DT)[:, None]
    half = wi + WO
    half = half / half.norm(dim=0, keepdim=True)
    p = sggx.phase(wi[2].expand(WO.shape[1]), half[2] ** 2, torch.tensor(alpha, dtype=DT))
    assert p.mean().item() * 4 * math.pi == pytest.approx(1.0, abs=5e-3)


@pytest.mark.parametrize("theta", [0.0, 0.5, 1.2])
def test_asggx_lobe_normalisation(theta):
    """The ASGGX lobe integrates to 4 at alpha = 1 and tends to 2 pi sigma(wi) for small alpha:
    its implied phase D(h') / (2 sigma(wi)) is therefore not unit-integral (pi for sharp lobes)."""
    ci = torch.tensor(math.sin(theta), dtype=DT).expand(WO.shape[1])  # wi . o with the fiber along z
    rough = asggx.lobe(ci, WO[2], torch.tensor(1.0, dtype=DT)).mean().item() * 4 * math.pi
    assert rough == pytest.approx(4.0, rel=1e-6)
    sharp = asggx.lobe(ci, WO[2], torch.tensor(0.03, dtype=DT)).mean().item() * 4 * math.pi
    sigma_in = sggx.projected_area(ci[:1], torch.tensor(0.03, dtype=DT)).item()
    assert sharp == pytest.approx(2 * math.pi * sigma_in, rel=0.04)


def test_asggx_lobe_is_invariant_under_rotation_about_the_fiber():
    gen = torch.Generator().manual_seed(3)
    wi, wo = random_unit(gen, 500), random_unit(gen, 500)
    alpha = torch.tensor(0.4, dtype=DT)
    base = asggx.lobe(wi[2], wo[2], alpha)  # fiber along z
    for angle in (0.3, 1.7, 3.0):
        c, s = math.cos(angle), math.sin(angle)
        rotated = torch.stack((c * wo[0] - s * wo[1], s * wo[0] + c * wo[1], wo[2]))
        assert torch.allclose(asggx.lobe(wi[2], rotated[2], alpha), base)
    # ... and symmetric in wi, wo.
    assert torch.allclose(asggx.lobe(wo[2], wi[2], alpha), base)


@pytest.mark.parametrize("k", [0.0, 0.3, 0.7, 0.9])
def test_forward_scattering_moves_the_lobe_around_the_fiber_and_keeps_its_mean(k):
    """A_k over the azimuth of wo around the fiber (at a fixed angle to it) has mean 1, its peak
    (1 + k) / (1 - k) straight through (wo = -wi) and its least (1 - k) / (1 + k) opposite; k = 0 is 1."""
    fiber = torch.tensor([0.3, -0.5, 0.8], dtype=DT)
    fiber = fiber / fiber.norm()
    gen = torch.Generator().manual_seed(11)
    for _ in range(5):
        wi = random_unit(gen)[:, 0]
        ci = float(wi @ fiber)
        u = wi - ci * fiber
        u = u / u.norm()
        v = torch.linalg.cross(fiber, u)
        co = float(random_unit(gen)[2, 0])
        phi = (torch.arange(4096, dtype=DT) + 0.5) / 4096 * 2 * math.pi
        across = math.sqrt(1 - co * co)
        wo = co * fiber[:, None] - across * (torch.cos(phi) * u[:, None] + torch.sin(phi) * v[:, None])
        a = asggx.forward_peak(torch.full_like(phi, ci), wo.T @ fiber, torch.full_like(phi, 1 - ci * ci),
                               1 - (wo.T @ fiber) ** 2, wo.T @ wi, torch.tensor(k, dtype=DT))
        assert a.mean().item() == pytest.approx(1.0, abs=1e-9)
        straight = asggx.forward_peak(*(torch.tensor([x], dtype=DT)
                                        for x in (ci, -ci, 1 - ci * ci, 1 - ci * ci, -1.0, k)))
        assert straight.item() == pytest.approx((1 + k) / (1 - k), rel=1e-9)
        assert a.min().item() == pytest.approx((1 - k) / (1 + k), rel=1e-6)


def test_forward_scattering_acts_on_light_crossing_the_layer_only():
    """eval_layer: the forward scattering leaves the single lobe and every reflection as they are, and in
    transmission brightens the straight-through direction and dims the grazing azimuths."""
    gen = torch.Generator().manual_seed(12)
    wi = random_unit(gen, 4000)
    wi[2] = wi[2].abs() + 0.05
    wi = wi / wi.norm(dim=0, keepdim=True)
    wo = random_unit(gen, 4000)
    fiber = random_unit(gen, 4000)
    args = (torch.tensor(0.4, dtype=DT), torch.tensor(1.5, dtype=DT), torch.tensor(0.5, dtype=DT),
            torch.tensor(2.0, dtype=DT))
    plain = eval_layer(wi, wo, fiber, *args)
    forward = eval_layer(wi, wo, fiber, *args, forward_scattering=0.6)
    reflected = wo[2] > 0
    for a, b in zip(plain, forward):
        if a is not plain[1]:
            assert torch.equal(a, b)
    assert torch.equal(plain[1][reflected], forward[1][reflected])
    straight = eval_layer(wi, -wi, fiber, *args), eval_layer(wi, -wi, fiber, *args, forward_scattering=0.6)
    torch.testing.assert_close(straight[1][1], straight[0][1] * 4.0)  # (1 + 0.6) / (1 - 0.6)
    assert (forward[1][~reflected] < plain[1][~reflected]).any()


@pytest.mark.parametrize("opposite", [False, True], ids=["reflection", "transmission"])
def test_single_scattering_is_reciprocal(opposite):
    gen = torch.Generator().manual_seed(5)
    n = 2000
    wi, wo, fiber = random_unit(gen, n), random_unit(gen, n), random_unit(gen, n)
    wi[2] = wi[2].abs() + 1e-3
    wo[2] = -(wo[2].abs() + 1e-3) if opposite else wo[2].abs() + 1e-3
    wi, wo = wi / wi.norm(dim=0), wo / wo.norm(dim=0)
    alpha = 0.05 + torch.rand(n, generator=gen, dtype=DT)
    T = 0.01 + 5 * torch.rand(n, generator=gen, dtype=DT)
    f, _, _, _ = eval_layer(wi, wo, fiber, alpha.clamp(max=1), T, alpha, T)
    g, _, _, _ = eval_layer(wo, wi, fiber, alpha.clamp(max=1), T, alpha, T)
    # f includes the light-side cosine: the BSDF is f / |wo_z|.
    assert torch.allclose(f / wo[2].abs(), g / wi[2].abs(), rtol=1e-9, atol=1e-12)


def test_single_scattering_of_one_layer_never_exceeds_the_light_it_intercepts():
    """Albedo 1: reflection + transmission <= 1 - att(wi) (what is not attenuated never scattered)."""
    gen = torch.Generator().manual_seed(7)
    worst = 0.0
    for _ in range(24):
        theta = 1.5 * torch.rand(1, generator=gen).item()
        wi = torch.tensor([math.sin(theta), 0.0, math.cos(theta)], dtype=DT)[:, None].expand(3, WO.shape[1])
        fiber = random_unit(gen)
        alpha = torch.tensor(0.1 + 0.9 * torch.rand(1, generator=gen).item(), dtype=DT)
        T = torch.tensor(0.01 + 4.99 * torch.rand(1, generator=gen).item(), dtype=DT)
        single, _, att_in, _ = eval_layer(wi, WO, fiber, alpha, T, alpha, T)
        energy = single.mean().item() * 4 * math.pi
        assert 0.0 < energy <= 1.0 - att_in[0].item() + 1e-3
        worst = max(worst, energy + att_in[0].item())
    assert worst <= 1.0 + 1e-3


def test_stable_g_equals_the_literal_formula():
    gen = torch.Generator().manual_seed(11)
    n = 5000
    T = 0.01 + 5 * torch.rand(n, generator=gen, dtype=DT)
    a_in = 0.05 + 20 * torch.rand(n, generator=gen, dtype=DT)
    a_out = (torch.rand(n, generator=gen, dtype=DT) - 0.5) * 40
    a_out = torch.where(a_out.abs() < 0.05, torch.full_like(a_out, 0.05), a_out)
    literal = reference._g_literal(T, a_in, a_out)
    assert torch.allclose(slab_g(T, a_in, a_out), literal, rtol=1e-8, atol=1e-12)
    # Where A_i + A_o = 0 the stable form gives the continuous limit T exp(-T A_i), with a finite gradient.
    a = torch.tensor([1.3], dtype=DT, requires_grad=True)
    g = slab_g(torch.tensor([2.0], dtype=DT), a, -a)
    assert g.item() == pytest.approx(2.0 * math.exp(-2.0 * 1.3))
    g.backward()
    assert torch.isfinite(a.grad).all()


def test_phi_has_the_derivative_of_its_formula_down_to_zero():
    """phi(y) = (1 - exp(-y)) / y carries a hand-written derivative; it must be the formula's,
    phi'(y) = (exp(-y) - phi(y)) / y, which tends to -1/2 + y/3 at 0 (where 0/0 would be NaN)."""
    y = torch.tensor([0.0, 1e-12, 1e-6, 9.9e-5, 1.01e-4, 1e-3, 0.1, 1.0, 7.5, 40.0], dtype=DT, requires_grad=True)
    phi = one_minus_exp_over(y)
    phi.sum().backward()
    exact = torch.tensor([1.0 if v == 0 else -math.expm1(-v) / v for v in y.tolist()], dtype=DT)
    assert torch.allclose(phi.detach(), exact, rtol=1e-15)
    slope = [-0.5 + v / 3 - v * v / 8 if v < 1e-3 else (math.exp(-v) - -math.expm1(-v) / v) / v for v in y.tolist()]
    assert torch.allclose(y.grad, torch.tensor(slope, dtype=DT), rtol=1e-6, atol=1e-12)
    # Through slab_g the gradients are the literal formula's (away from A_i + A_o = 0, where it is 0/0).
    T = torch.tensor([0.3, 2.0, 4.5], dtype=DT, requires_grad=True)
    a_in = torch.tensor([0.7, 3.0, 12.0], dtype=DT, requires_grad=True)
    a_out = torch.tensor([-2.5, 1.1, -0.4], dtype=DT, requires_grad=True)
    stable = torch.autograd.grad(slab_g(T, a_in, a_out).sum(), (T, a_in, a_out))
    literal = torch.autograd.grad(reference._g_literal(T, a_in, a_out).sum(), (T, a_in, a_out))
    for got, want in zip(stable, literal):
        assert torch.allclose(got, want, rtol=1e-9)


def test_phi_in_float32_is_the_formula_rounded_beyond_its_fast_range():
    """phi's float32 argument is kept within [PHI_FLOOR_FLOAT32, EXPM1_SATURATION] for the CPU's fast
    expm1: below and above, phi must take the float32 values of the formula with expm1 on the whole
    argument, to the last bit, within an ulp of the exact ones, and its slope the formula's."""
    y64 = torch.tensor([0.0, 1e-38, 1e-30, 1e-20, 1e-16, 1e-13, 1e-12, 1e-9, 6e-8, 0.05, 0.5, 17.0, 39.0, 40.0,
                        41.0, 56.0, 90.0, 1e3, 1e6, 3e38], dtype=DT)
    y = y64.float().requires_grad_(True)
    phi = one_minus_exp_over(y)
    phi.sum().backward()
    whole = y.detach().clamp_min(1e-38)
    assert torch.equal(phi.detach(), torch.expm1(-whole) / -whole)
    exact = torch.tensor([1.0 if v == 0 else -math.expm1(-v) / v for v in y64.tolist()], dtype=DT)
    assert torch.allclose(phi.detach().double(), exact, rtol=1.2e-7, atol=0)
    slope = torch.tensor([-0.5 + v / 3 if v < 1e-4 else (math.exp(-v) - -math.expm1(-v) / v) / v
                          for v in y64.tolist()], dtype=DT)
    assert torch.allclose(y.grad.double(), slope, rtol=1e-5, atol=1e-12)


def test_projected_forms_equal_the_fiber_frame_forms():
    gen = torch.Generator().manual_seed(13)
    n = 3000
    w, fiber, normal = random_unit(gen, n), random_unit(gen, n), random_unit(gen, n)
    normal = normal - (normal * fiber).sum(0) * fiber
    normal = normal / normal.norm(dim=0)
    b = torch.linalg.cross(fiber, normal, dim=0)
    w1, w2, w3 = (w * normal).sum(0), (w * b).sum(0), (w * fiber).sum(0)
    alpha = 0.01 + 0.99 * torch.rand(n, generator=gen, dtype=DT)
    assert torch.allclose(sggx.projected_area(w3, alpha), reference._sigma(w1, w2, w3, alpha))
    assert torch.allclose(sggx.ndf(w3 * w3, alpha), reference._ndf(w1, w2, w3, alpha), rtol=1e-9)
    # ASGGX: the trig-free sin^2 of the half angle equals the atan2 construction.
    v = random_unit(gen, n)
    th = (torch.asin(w3) + torch.asin((v * fiber).sum(0))) / 2
    assert torch.allclose(asggx.half_sin2(w3, (v * fiber).sum(0)), torch.sin(th) ** 2, atol=1e-12)


def test_height_scaling_matches_the_literal_k_rule():
    gen = torch.Generator().manual_seed(17)
    n = 4000
    u = (torch.rand(n, generator=gen, dtype=DT) - 0.5) * 1.2
    v = (torch.rand(n, generator=gen, dtype=DT) - 0.5) * 3.0
    psi = (torch.rand(n, generator=gen, dtype=DT) - 0.5) * 1.5
    normal = torch.stack((torch.sin(v), torch.sin(u) * torch.cos(v), torch.cos(u) * torch.cos(v)))
    fiber = torch.stack((-torch.cos(v) * torch.sin(psi),
                         torch.cos(u) * torch.cos(psi) + torch.sin(u) * torch.sin(v) * torch.sin(psi),
                         -torch.sin(u) * torch.cos(psi) + torch.cos(u) * torch.sin(v) * torch.sin(psi)))
    beta = 0.01 + 1.99 * torch.rand(n, generator=gen, dtype=DT)
    n_fast, o_fast = scale_height(normal, fiber, beta)
    n_ref, o_ref = reference.height_scaled(normal, fiber, beta)
    assert torch.allclose(n_fast, n_ref, atol=1e-12)
    assert torch.allclose(o_fast, o_ref, atol=1e-7)
    assert (n_fast * o_fast).sum(0).abs().max() < 1e-12
