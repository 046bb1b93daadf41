"""WarpAdam and its kernel: Adam as one Warp kernel a parameter, four floats a thread."""

from fractions import Fraction

import numpy as np
import pytest
import torch
import warp as wp

from _optim_cases import small_gaussians, steps_with_surgery, through_state_dict
from gof_warp.core.errors import GofError
from gof_warp.core.model import PARAM_NAMES
from gof_warp.training.optim import LeanAdam, OptimConfig, WarpAdam, make_optimizer


def _reference(g, m, v, p, beta1, beta2, lr, eps, t):
    """One Adam step in float64 (Kingma & Ba, torch's form)."""
    g, m, v, p = (np.asarray(x, np.float64) for x in (g, m, v, p))
    m = beta1 * m + (1 - beta1) * g
    v = beta2 * v + (1 - beta2) * g * g
    p = p - lr / (1 - beta1**t) * m / (np.sqrt(v) / np.sqrt(1 - beta2**t) + eps)
    return m, v, p


def _round32(x: Fraction) -> np.float32:
    """``x`` rounded once to the nearest float32 (ties to even), from its exact value."""
    f = np.float32(float(x))  # within one float32 ulp of x; pick the nearest of f and its neighbours exactly
    candidates = [np.nextafter(f, np.float32(-np.inf)), f, np.nextafter(f, np.float32(np.inf))]
    best = min(candidates, key=lambda c: (abs(Fraction(float(c)) - x), int(np.float32(c).view(np.uint32)) & 1))
    return np.float32(best)


def _fused_cuda_reference(g, m, v, p, beta1, beta2, lr, eps, t):
    """torch's fused CUDA Adam step (``fused_adam_utils.cuh``) float for float: every operation rounded once to
    float32 (a float32 +, −, ×, ÷ or √ done in double and rounded is rounded once: 53 ≥ 2·24 + 2), the two fused
    multiply-adds from their exact values. The bias corrections use the C library's ``powf`` through numpy, as the
    kernel on the CPU does."""
    f = np.float32
    b1, b2, lr32, eps32, t32 = f(beta1), f(beta2), f(lr), f(eps), f(t)
    step_size = f(float(lr32) / float(f(1.0) - f(b1**t32)))
    bc2_sqrt = f(np.sqrt(float(f(1.0) - f(b2**t32))))

    def fma(a, b, c):
        return _round32(Fraction(float(a)) * Fraction(float(b)) + Fraction(float(c)))

    out = []
    for gi, mi, vi, pi in zip(*(np.asarray(x, np.float32) for x in (g, m, v, p))):
        m1 = fma(b1, mi, fma(-b1, gi, gi))
        g2 = f(float(gi) * float(gi))
        v1 = fma(b2, vi, fma(-b2, g2, g2))
        denom = f(float(f(float(f(np.sqrt(float(v1)))) / float(bc2_sqrt))) + float(eps32))
        p1 = f(float(pi) - float(f(float(f(float(step_size) * float(m1))) / float(denom))))
        out.append((m1, v1, p1))
    return tuple(np.array(c, np.float32) for c in zip(*out))


def _launch_adam_step(arrs, n: int, vector: bool, device, beta1, beta2, lr, eps, t):
    """``adam_step`` over the float32 Warp arrays ``(g, p, m, v)`` in place (``vector=False``: all through the tail)."""
    from gof_warp.kernels.adam import adam_step

    n4 = n // 4 if vector else 0

    def vec4(a):
        return wp.array(ptr=a.ptr, dtype=wp.vec4, shape=(n4,), device=device) if n4 else wp.empty(0, dtype=wp.vec4,
                                                                                                      device=device)
    wp.launch(adam_step, dim=n4 + n - 4 * n4, device=device,
              inputs=[vec4(arrs[0]), arrs[0], n4, lr, beta1, beta2, eps, float(t)],
              outputs=[vec4(arrs[1]), vec4(arrs[2]), vec4(arrs[3]), arrs[1], arrs[2], arrs[3]])


def _step_inputs(n: int, seed: int):
    rng = np.random.default_rng(seed)
    g, p = rng.normal(size=n), rng.normal(size=n)
    m, v = rng.normal(size=n) * 0.1, rng.random(n) * 0.01
    g[::5] *= 1e-12  # tiny gradients (the denominator's ε matters there) and an exact zero
    g[0] = 0.0
    return [x.astype(np.float32) for x in (g, p, m, v)]


@pytest.mark.parametrize("n, vector", [(1, True), (3, True), (4, True), (5, True), (30, True), (30, False)])
def test_adam_step_against_float64(n, vector, device):
    """Every float of the vec4 body and of the tail gets the float64 step (within float32 rounding) for the float32
    values of the betas, which is what the kernel (as torch's fused kernel) works with: 1 − fl(0.999) is 1.3e-5 under
    0.001; ``vector=False`` runs the whole array through the one-float path."""
    g, p, m, v = _step_inputs(n, n)
    beta1, beta2, lr, eps, t = 0.9, 0.999, 3e-3, 1e-15, 7
    arrs = [wp.array(x, dtype=float, device=device) for x in (g, p, m, v)]
    _launch_adam_step(arrs, n, vector, device, beta1, beta2, lr, eps, t)
    m_ref, v_ref, p_ref = _reference(g, m, v, p, float(np.float32(beta1)), float(np.float32(beta2)), lr, eps, t)
    np.testing.assert_allclose(arrs[2].numpy(), m_ref, rtol=2e-6, atol=1e-8)
    np.testing.assert_allclose(arrs[3].numpy(), v_ref, rtol=2e-6, atol=1e-10)
    np.testing.assert_allclose(arrs[1].numpy(), p_ref, rtol=2e-6, atol=1e-7)
    assert np.abs(arrs[1].numpy() - p).max() > 1e-4  # the step moved the parameter


@pytest.mark.parametrize("vector", [True, False])
@pytest.mark.parametrize("t", [1, 2, 7, 3000])
def test_adam_step_is_torch_fused_gpu_arithmetic_bit_for_bit(vector, t):
    """On the CPU, the kernel's results are the bits of torch's fused CUDA formula worked out exactly
    (:func:`_fused_cuda_reference`): the moments through fused multiply-adds (a plain ``β·m + (1 − β)·g`` differs in
    the last bit for a good share of these floats), every other operation rounded once."""
    n = 2003
    g, p, m, v = _step_inputs(n, t)
    beta1, beta2, lr, eps = 0.9, 0.999, 1.6e-4 * 0.37, 1e-15
    arrs = [wp.array(x, dtype=float, device="cpu") for x in (g, p, m, v)]
    _launch_adam_step(arrs, n, vector, "cpu", beta1, beta2, lr, eps, t)
    m_ref, v_ref, p_ref = _fused_cuda_reference(g, m, v, p, beta1, beta2, lr, eps, t)
    for got, ref in ((arrs[2], m_ref), (arrs[3], v_ref), (arrs[1], p_ref)):
        np.testing.assert_array_equal(got.numpy().view(np.uint32), ref.view(np.uint32))
    plain = (np.float32(beta1) * m + np.float32(1 - beta1) * g).astype(np.float32)
    assert (plain != m_ref).sum() > 0  # the test tells the fused form from the plain one


def _groups(seed: int, device):
    g = torch.Generator().manual_seed(seed)
    shapes = [(7, 3), (9, 4), (5,), (13, 15, 3)]
    params = [torch.randn(s, generator=g).to(device).requires_grad_(True) for s in shapes]
    return [{"params": [params[0]], "lr": 1e-2}, {"params": [params[1], params[2]], "lr": 3e-3},
            {"params": [params[3]], "lr": 5e-4}], params, g


def test_warp_adam_is_torch_adam(device):
    """12 steps with some gradients missing (those parameters skip the step, as in torch) and the first group's rate
    changing every step. On CUDA: torch's fused Adam's parameters, moments and step counts bit for bit. On the CPU,
    against torch's loop Adam (which rounds ``1 − β`` on its own): within float32 rounding, the second moments within
    the 1.3e-5 by which 1 − fl(0.999) differs from fl(1 − 0.999)."""
    runs = []
    torch_kw = {"fused": True} if device == "cuda" else {"foreach": False}
    for cls, kw in ((torch.optim.Adam, torch_kw), (WarpAdam, {})):
        groups, params, g = _groups(0, device)
        opt = cls(groups, eps=1e-15, **kw)
        for i in range(12):
            for j, p in enumerate(params):
                p.grad = None if (i, j) in ((2, 1), (5, 3), (6, 3)) else torch.randn(p.shape, generator=g).to(device)
            opt.param_groups[0]["lr"] = 1e-2 * 0.9**i
            opt.step()
        runs.append((params, opt))
    (ref, ref_opt), (got, opt) = runs
    exact = device == "cuda"
    for a, b in zip(ref, got):
        pairs = [(b, a)] + [(opt.state[b][k], ref_opt.state[a][k]) for k in ("exp_avg", "exp_avg_sq")]
        for (x, y), rtol, atol in zip(pairs, (1e-5, 1e-5, 2e-5), (1e-6, 1e-7, 1e-9)):
            if exact:
                assert torch.equal(x.detach(), y.detach())
            else:
                torch.testing.assert_close(x, y, rtol=rtol, atol=atol)
        assert float(opt.state[b]["step"]) == float(ref_opt.state[a]["step"])


def test_densification_surgery_and_state_dicts_between_warp_and_torch_adam():
    """Through replace_params (rows removed and appended: new tensors, new launches) and state dicts passed from
    WarpAdam to torch's Adam and back, the Gaussians follow torch's Adam within float32 rounding."""
    runs = []
    for kind in ("torch", "warp"):
        g = small_gaussians()
        opt = make_optimizer(g, OptimConfig(adam=kind), extent=2.0)
        assert isinstance(opt, WarpAdam) == (kind == "warp")

        def swap(i, opt, warp=kind == "warp"):
            if warp and i in (3, 5):  # to torch's Adam and back to WarpAdam through state dicts
                return through_state_dict(opt, torch.optim.Adam if i == 3 else WarpAdam, lr=0.0, eps=1e-15)
            return None

        steps_with_surgery(g, opt, 7, appended=3, swap=swap)
        runs.append(g)
    for k in PARAM_NAMES:
        torch.testing.assert_close(runs[1].params[k], runs[0].params[k], rtol=1e-5, atol=1e-6)


def test_bad_parameters_are_named():
    with pytest.raises(GofError, match="float32"):
        p = torch.zeros(4, dtype=torch.float64, requires_grad=True)
        p.grad = torch.ones_like(p)
        WarpAdam([p]).step()
    with pytest.raises(GofError, match="betas"):
        WarpAdam([torch.zeros(3, requires_grad=True)], betas=(0.9, 1.0))
    with pytest.raises(GofError, match="optim.adam"):
        OptimConfig(adam="sgd")


def test_auto_adam_is_warp_on_cuda_and_torch_on_the_cpu():
    """``optim.adam=auto`` (the default) picks WarpAdam for CUDA parameters and torch's Adam for CPU ones (whose loop
    arithmetic WarpAdam does not copy); an explicit kind is kept on either device."""
    assert OptimConfig().adam == "auto"
    for device, auto in (("cpu", "torch"), ("cuda", "warp"), ("cuda:1", "warp"), (torch.device("cpu"), "torch")):
        assert OptimConfig().adam_for(device) == auto
        for kind in ("torch", "warp"):
            assert OptimConfig(adam=kind).adam_for(device) == kind


def test_make_optimizer_by_default(device):
    """The default config gives LeanAdam on the CPU and WarpAdam on CUDA."""
    opt = make_optimizer(small_gaussians().to(device), OptimConfig(), extent=2.0)
    assert isinstance(opt, WarpAdam) == (device == "cuda")
    assert isinstance(opt, LeanAdam) == (device == "cpu")
