"""The BSDF's hand-written gradient (backend.model.bsdf_gradient) against autograd's of the same
evaluation: the same values bit for bit, and the gradients of every optimised parameter, on the
plain, the varied and the forward-scattering model; the ablations keep autograd's."""
import pytest
import torch

from backend.core.options import RenderOptions
from backend.core.params import PARAMETERS, FabricParams
from backend.model.bsdf import eval_projected
from backend.model.bsdf_gradient import eval_with_hand_gradient, supported
from backend.model.param_tensors import ParamTensors
from backend.model.render import Renderer

OPTIMISED = [s.name for s in PARAMETERS if s.optimised]
SATIN = FabricParams.from_interchange(
    "satin1_R_0.18,0.75_S_1.0,0.96_T_1.58,2.79_N_0.0_UV_151.9,84.7_Kd_0.077,0.282,0.077,0.147,0.245,0.205"
    "_G_0.88,0.85_Rm_0.15,0.61_Tm_1.39,2.45_W_0.03,0.94_Ks_0.12,0.53,0.28,0.1,0.52,0.26_Psi_8.0,-3.0")
CASES = {
    "plain model": SATIN,
    "forward scattering": SATIN.replace(forward_scattering=(0.3, 0.7)),
    "varied, noisy": SATIN.replace(pattern="twill0", tiles=(40.0, 30.0), width_variation=(0.2, 0.1),
                                   thickness_variation=(0.3, 0.2), spacing_variation=(0.1, 0.2),
                                   brightness_variation=(0.2, 0.3), slub_variation=(0.2, 0.1), noise=0.6,
                                   forward_scattering=(0.5, 0.0)),
    "thin, rough, flat": SATIN.replace(pattern="plain", roughness=(1.0, 0.05), thickness=(0.01, 5.0),
                                       height_scale=(0.01, 2.0), gap_scale=(0.5, 0.6)),
}


def _samples(params: FabricParams, options: RenderOptions = RenderOptions()):
    """The projections of a 24-pixel render's samples (float64), as the renderer caches them."""
    renderer = Renderer(size=24, spp=4, dtype=torch.float64, options=options)
    fabric = ParamTensors.from_params(params, dtype=torch.float64)
    rows = renderer.ranges[0]
    return renderer._geometry_for(renderer.geometry_key(fabric), renderer._lookup(fabric), rows, renderer._chunk(rows))


def _values_and_gradients(evaluate, samples, params, options, names):
    fabric = ParamTensors.from_params(params, dtype=torch.float64, requires_grad=names)
    terms = evaluate(samples, fabric, options)
    generator = torch.Generator().manual_seed(7)
    loss = sum((t.weights * torch.randn(t.weights.shape, dtype=torch.float64, generator=generator)).sum()
               + (t.radiance() * torch.rand(t.radiance().shape, dtype=torch.float64, generator=generator)).sum()
               for t in terms)
    loss.backward()
    return [t.weights.detach() for t in terms], {n: fabric.values[n].grad for n in names}


@pytest.mark.parametrize("case", list(CASES))
def test_the_hand_written_gradient_is_autograd_s(case):
    params = CASES[case]
    names = OPTIMISED if params.forward_scattering != (0.0, 0.0) else [n for n in OPTIMISED
                                                                       if n != "forward_scattering"]
    samples = _samples(params)
    values, hand = _values_and_gradients(eval_with_hand_gradient, samples, params, RenderOptions(), names)
    reference, auto = _values_and_gradients(eval_projected, samples, params, RenderOptions(), names)
    for ours, theirs in zip(values, reference):
        assert torch.equal(ours, theirs)  # the same forward code
    for name in names:
        assert auto[name] is not None and auto[name].abs().max() > 0, name
        torch.testing.assert_close(hand[name], auto[name], rtol=1e-9, atol=1e-12, msg=name)


def test_a_gradient_the_hand_written_pass_gets_wrong_fails_the_comparison(monkeypatch):
    """The comparison above can fail: a wrong derivative (of the slab's G in T) shows."""
    from backend.model import bsdf_gradient
    params, names = CASES["plain model"], OPTIMISED[:]
    samples = _samples(params)
    right = _values_and_gradients(eval_with_hand_gradient, samples, params, RenderOptions(), names)[1]
    monkeypatch.setattr(bsdf_gradient, "one_minus_exp_over_slope", lambda y, phi: 0.0 * phi)
    wrong = _values_and_gradients(eval_with_hand_gradient, samples, params, RenderOptions(), names)[1]
    assert not torch.allclose(wrong["thickness"], right["thickness"], rtol=1e-3)


@pytest.mark.parametrize("flags", [{"multiple_lobe": "sggx"}, {"layers": 1}, {"diffuse": False}])
def test_the_ablations_keep_autograd_s_gradient(flags):
    options = RenderOptions(**flags)
    assert not supported(options) and supported(RenderOptions())
    params = CASES["plain model"]
    samples = _samples(params, options)
    ours = _values_and_gradients(eval_with_hand_gradient, samples, params, options, OPTIMISED)
    theirs = _values_and_gradients(eval_projected, samples, params, options, OPTIMISED)
    for name in OPTIMISED:  # the ablation's lobe has no forward scattering: neither has its gradient
        assert (ours[1][name] is None and theirs[1][name] is None) or torch.equal(ours[1][name], theirs[1][name]), name


def test_the_eager_renderer_s_gradient_is_autograd_s():
    """A whole render's gradient (pixel means, glow, blur) through the eager path, against the same
    render with autograd's evaluation of the BSDF (float32, as fits run)."""
    params = CASES["forward scattering"]
    grads = []
    for hand in (True, False):
        renderer = Renderer(size=32, spp=4, hand_gradient=hand)
        fabric = ParamTensors.from_params(params, requires_grad=OPTIMISED)
        reflection, transmission = renderer.blurred(fabric, camera_blur_px=1.5)
        (reflection.square().mean() + transmission.mean()).backward()
        grads.append({n: fabric.values[n].grad for n in OPTIMISED})
    for name in OPTIMISED:
        torch.testing.assert_close(grads[0][name], grads[1][name], rtol=2e-4, atol=1e-7, msg=name)
