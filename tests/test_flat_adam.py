"""FlatAdam (``optim.adam = "warp"``): the Warp kernel against a float64 reference, the optimizer against torch's Adam,
its state under densification's surgery and checkpoints, and its errors."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
import warp as wp

from gof_warp.errors import GofError
from gof_warp.kernels.adam import adam_update
from gof_warp.model import Gaussians
from gof_warp.optim import FlatAdam, OptimConfig, check_optimizer_state, make_optimizer, replace_params

BETAS = (0.9, 0.999)


def _adam64(p, g_steps, lr, eps, betas=BETAS):
    """Adam in float64 numpy (Kingma & Ba, torch's placement of eps): the parameter after each gradient in turn."""
    p = p.astype(np.float64).copy()
    m = np.zeros_like(p)
    v = np.zeros_like(p)
    for t, g in enumerate(g_steps, start=1):
        g = g.astype(np.float64)
        m = betas[0] * m + (1 - betas[0]) * g
        v = betas[1] * v + (1 - betas[1]) * g * g
        p = p - lr / (1 - betas[0] ** t) * m / (np.sqrt(v) / np.sqrt(1 - betas[1] ** t) + eps)
    return p, m, v


def test_adam_kernel_matches_float64():
    """Five steps of ``adam_update`` (CPU) against float64 Adam: parameter and moments to float32 rounding."""
    wp.init()
    rng = np.random.default_rng(0)
    n, lr, eps = 1000, 0.05, 1e-8
    p0 = rng.normal(size=n).astype(np.float32)
    grads = [(rng.normal(size=n) * 10.0 ** rng.uniform(-6, 1, size=n)).astype(np.float32) for _ in range(5)]
    p, m, v = (wp.array(x, dtype=float, device="cpu") for x in (p0, np.zeros(n, np.float32), np.zeros(n, np.float32)))
    for t, g in enumerate(grads, start=1):
        wp.launch(adam_update, dim=n, device="cpu",
                  inputs=[wp.array(g, dtype=float, device="cpu"), BETAS[1], 1 - BETAS[0], 1 - BETAS[1], lr / (1 - BETAS[0] ** t),
                          float(np.sqrt(1 - BETAS[1] ** t)), eps], outputs=[p, m, v])  # fmt: skip
    p_ref, m_ref, v_ref = _adam64(p0, grads, lr, eps)
    assert np.allclose(m.numpy(), m_ref, rtol=1e-5, atol=0)
    assert np.allclose(v.numpy(), v_ref, rtol=1e-5, atol=0)
    step = p_ref - p0  # the update itself, to float32 rounding of the parameter
    assert np.max(np.abs(p.numpy() - p_ref)) <= 1e-6 * np.max(np.abs(p0)) + 1e-5 * np.max(np.abs(step))
    assert np.max(np.abs(step)) > 0.1  # the steps moved the parameter (a test that could not fail otherwise)


def _params(seed=0, n=50):
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(n, 3, generator=g), torch.randn(n, 15, 3, generator=g), torch.randn(n, 1, generator=g)]


def _run(opt_cls, params, steps, skip=(), **kw):
    """Apply ``steps`` pseudo-random gradients (the same for every optimizer); parameter ``i`` gets none at the
    steps in ``skip`` (as densification leaves a replaced parameter without a gradient)."""
    params = [p.clone().requires_grad_(True) for p in params]
    opt = opt_cls([{"params": [params[0]], "lr": 0.01}, {"params": params[1:], "lr": 0.003}], **kw)
    g = torch.Generator().manual_seed(7)
    for s in range(steps):
        for i, p in enumerate(params):
            p.grad = None if (s, i) in skip else torch.randn(p.shape, generator=g) * 0.1
        opt.step()
    return params, opt


def test_flat_adam_follows_torch_adam():
    """FlatAdam against ``torch.optim.Adam`` (its single-tensor loop, the same formula in float32) over 12 steps, two
    groups, with gradients missing at some steps: parameters and moments agree to float32 rounding."""
    skip = {(3, 1), (4, 1), (8, 0)}
    ours, opt_ours = _run(FlatAdam, _params(), 12, skip, betas=BETAS, eps=1e-15)
    ref, opt_ref = _run(torch.optim.Adam, _params(), 12, skip, betas=BETAS, eps=1e-15, foreach=False)
    for a, b, p0 in zip(ours, ref, _params()):
        assert torch.allclose(a.detach(), b.detach(), rtol=0, atol=1e-6)
        assert (a.detach() - p0).abs().max() > 1e-3
        sa, sb = opt_ours.state[a], opt_ref.state[b]
        assert float(sa["step"]) == float(sb["step"]) and sa["step"].device.type == "cpu"
        for key in ("exp_avg", "exp_avg_sq"):
            assert (sa[key] - sb[key]).abs().max() <= 1e-6 * sb[key].abs().max()  # float32 rounding of the sums
    assert float(opt_ours.state[ours[1]]["step"]) == 10  # two steps without a gradient were skipped


def test_flat_adam_state_loads_both_ways():
    """A torch Adam's state dict continues in FlatAdam and the other way round, as a resumed run's does."""
    ref, opt_ref = _run(torch.optim.Adam, _params(1), 4, betas=BETAS, eps=1e-15, foreach=False)
    state = copy.deepcopy(opt_ref.state_dict())  # as read back from a checkpoint (a live state dict shares the moments)
    params = [p.detach().clone().requires_grad_(True) for p in ref]
    flat = FlatAdam([{"params": [params[0]], "lr": 0.01}, {"params": params[1:], "lr": 0.003}], betas=BETAS, eps=1e-15)
    flat.load_state_dict(state)
    again = [q.detach().clone().requires_grad_(True) for q in ref]
    back = torch.optim.Adam([{"params": [again[0]], "lr": 0.0}, {"params": again[1:], "lr": 0.0}], foreach=False)
    for p, q in zip(params, ref):
        g = torch.full_like(p, 0.05)
        p.grad, q.grad = g.clone(), g.clone()
    flat.step()
    opt_ref.step()
    for p, q in zip(params, ref):
        assert torch.allclose(p.detach(), q.detach(), rtol=0, atol=1e-6)
        assert float(flat.state[p]["step"]) == 5
    back.load_state_dict(copy.deepcopy(flat.state_dict()))
    assert all(float(s["step"]) == 5 for s in back.state.values())


def _gaussians(n=40):
    g = torch.Generator().manual_seed(3)
    return Gaussians(
        means=torch.randn(n, 3, generator=g), quats=torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=1),
        log_scales=torch.randn(n, 3, generator=g) - 3, opacity_logits=torch.randn(n, generator=g),
        sh_dc=torch.randn(n, 3, generator=g), sh_rest=torch.zeros(n, 15, 3))  # fmt: skip


def test_flat_adam_under_densification_surgery():
    """``make_optimizer`` with ``adam="warp"`` builds a FlatAdam; ``replace_params`` (prune, append, reset) moves its
    moments with the Gaussians as it does torch's, and the next step runs on the new tensors."""
    gs = _gaussians()
    opt = make_optimizer(gs, OptimConfig(adam="warp"), extent=1.0)
    assert isinstance(opt, FlatAdam)
    for p in gs.params.values():
        p.grad = torch.ones_like(p)
    opt.step()
    before = opt.state[gs.params["means"]]["exp_avg"].clone()
    keep = torch.arange(40) % 3 != 0
    append = {k: v.detach()[:5].clone() for k, v in gs.params.items()}
    replace_params(gs, opt, keep=keep, append=append, reset={"opacity_logits": (torch.arange(3), -4.0)})
    check_optimizer_state(gs, opt)
    moved = opt.state[gs.params["means"]]["exp_avg"]
    assert torch.equal(moved[: int(keep.sum())], before[keep]) and torch.all(moved[int(keep.sum()):] == 0)
    assert torch.all(opt.state[gs.params["opacity_logits"]]["exp_avg"][:3] == 0)
    for p in gs.params.values():
        p.grad = torch.ones_like(p)
    opt.step()
    assert float(opt.state[gs.params["means"]]["step"]) == 2


def test_flat_adam_choice_and_errors():
    assert OptimConfig().adam_kind("cpu") == "torch" and OptimConfig().adam_kind("cuda") == "warp"
    assert OptimConfig(adam="torch").adam_kind("cuda") == "torch" and OptimConfig(adam="warp").adam_kind("cpu") == "warp"
    with pytest.raises(GofError, match="optim.adam"):
        OptimConfig(adam="sgd")
    for kw in ({"lr": float("nan")}, {"eps": -1.0}, {"betas": (0.9, 1.0)}):
        with pytest.raises(GofError, match="FlatAdam"):
            FlatAdam([torch.zeros(3, requires_grad=True)], **kw)
    p = torch.zeros(4, dtype=torch.float64, requires_grad=True)
    p.grad = torch.ones_like(p)
    with pytest.raises(GofError, match="float32"):
        FlatAdam([p]).step()
    q = torch.zeros(4, 4).t().requires_grad_(True)  # not contiguous
    q.grad = torch.ones(4, 4)
    with pytest.raises(GofError, match="contiguous"):
        FlatAdam([q]).step()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_flat_adam_cuda_follows_torch_fused_adam():
    """On CUDA, FlatAdam against torch's fused Adam (the trainer's other choice) over 12 steps; and a state saved by
    the fused Adam (its ``step`` on the device) continues in FlatAdam."""
    dev = torch.device("cuda")
    params = [p.to(dev) for p in _params(2, n=20_000)]
    ours, _ = _run(FlatAdam, params, 12, betas=BETAS, eps=1e-15)
    ref, opt_ref = _run(torch.optim.Adam, params, 12, betas=BETAS, eps=1e-15, fused=True)
    for a, b in zip(ours, ref):
        assert torch.allclose(a.detach(), b.detach(), rtol=0, atol=2e-6)
    state = copy.deepcopy(opt_ref.state_dict())
    assert next(iter(state["state"].values()))["step"].device.type == "cuda"
    cont = [p.detach().clone().requires_grad_(True) for p in ref]
    flat = FlatAdam([{"params": [cont[0]], "lr": 0.01}, {"params": cont[1:], "lr": 0.003}], betas=BETAS, eps=1e-15)
    flat.load_state_dict(state)
    for p, q in zip(cont, ref):
        p.grad = torch.full_like(p, 0.05)
        q.grad = torch.full_like(q, 0.05)
    flat.step()
    opt_ref.step()
    torch.cuda.synchronize()
    for p, q in zip(cont, ref):
        assert torch.allclose(p.detach(), q.detach(), rtol=0, atol=2e-6)
        assert float(flat.state[p]["step"]) == 13 and flat.state[p]["step"].device.type == "cpu"
