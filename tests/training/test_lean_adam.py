"""LeanAdam: torch's fused Adam with less host work per step, the same results bit for bit."""

import pytest
import torch

from _optim_cases import small_gaussians, steps_with_surgery, through_state_dict
from gof_warp.core.model import PARAM_NAMES
from gof_warp.training.optim import LeanAdam, OptimConfig, make_optimizer


def _groups(seed: int, device="cpu"):
    g = torch.Generator().manual_seed(seed)
    shapes = [(7, 3), (7, 4), (5,), (3, 15, 3)]
    params = [torch.randn(s, generator=g).to(device).requires_grad_(True) for s in shapes]
    return [{"params": [params[0]], "lr": 1e-2}, {"params": [params[1], params[2]], "lr": 3e-3},
            {"params": [params[3]], "lr": 5e-4}], g


def _run(opt_cls, steps: int, missing: dict[int, int], device="cpu", **kwargs):
    """``steps`` steps of ``opt_cls`` on fixed pseudo-random gradients; at step i the parameter ``missing[i]`` has no
    gradient; the first group's rate changes every step (as the means' schedule does)."""
    groups, g = _groups(0, device)
    params = [p for grp in groups for p in grp["params"]]
    opt = opt_cls(groups, eps=1e-15, **kwargs)
    for i in range(steps):
        for j, p in enumerate(params):
            p.grad = None if missing.get(i) == j else torch.randn(p.shape, generator=g).to(device)
        opt.param_groups[0]["lr"] = 1e-2 * 0.9**i
        opt.step()
    return params, opt


@pytest.mark.parametrize("missing", [{}, {0: 1, 3: 3, 4: 0}])
def test_lean_step_is_torch_fused_adam_bit_for_bit(missing, device):
    ref, ref_opt = _run(torch.optim.Adam, 9, missing, device, fused=True)
    got, opt = _run(LeanAdam, 9, missing, device, fused=True)
    for a, b in zip(ref, got):
        assert torch.equal(a, b)
    for a, b in zip(ref, got):
        sa, sb = ref_opt.state[a], opt.state[b]
        assert set(sa) == set(sb)
        for k in sa:
            assert torch.equal(sa[k], sb[k]), k


def test_lean_step_takes_its_own_path_after_the_first():
    """After the first step (torch's, which creates the state) the lean path runs: torch's step is not called."""
    groups, _ = _groups(1)
    opt = LeanAdam(groups, fused=True)
    calls = []
    original = torch.optim.Adam.step

    def counting(self, *a, **k):
        calls.append(1)
        return original(self, *a, **k)

    for p in opt.param_groups[0]["params"] + opt.param_groups[1]["params"] + opt.param_groups[2]["params"]:
        p.grad = torch.ones_like(p)
    torch.optim.Adam.step = counting
    try:
        opt.step()
        assert len(calls) == 1  # the state is created by torch's step
        opt.step()
        opt.step()
        assert len(calls) == 1
    finally:
        torch.optim.Adam.step = original
    assert all(float(opt.state[p]["step"]) == 3.0 for grp in opt.param_groups for p in grp["params"])


def test_unfused_and_unusual_options_are_torch_adam():
    for kwargs in ({"fused": False}, {"fused": True, "amsgrad": True}, {"fused": True, "weight_decay": 0.1}):
        ref, _ = _run(torch.optim.Adam, 4, {1: 2}, **kwargs)
        got, _ = _run(LeanAdam, 4, {1: 2}, **kwargs)
        for a, b in zip(ref, got):
            assert torch.equal(a, b), kwargs


def test_densification_surgery_and_state_dict_round_trip():
    """Through replace_params (rows removed and appended) and a state-dict round trip the lean optimizer stays
    torch's fused Adam bit for bit."""
    cfg = OptimConfig(fused=True)
    runs = []
    for lean in (False, True):
        g = small_gaussians()
        opt = make_optimizer(g, cfg, extent=2.0)
        if not lean:  # the same groups in torch's own Adam
            opt = torch.optim.Adam(opt.param_groups, lr=0.0, **cfg.adam_kwargs("cpu"))
        assert isinstance(opt, LeanAdam) == lean

        def swap(i, opt, cls=LeanAdam if lean else torch.optim.Adam):
            return through_state_dict(opt, cls, lr=0.0, **cfg.adam_kwargs("cpu")) if i == 4 else None

        steps_with_surgery(g, opt, 6, appended=2, swap=swap)
        runs.append(g)
    for k in PARAM_NAMES:
        assert torch.equal(runs[0].params[k], runs[1].params[k]), k
