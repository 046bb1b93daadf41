"""Shared cases of the optimizer tests: a small model and Adam steps through a densification's state surgery."""

from __future__ import annotations

import torch

from gof_warp.core.model import PARAM_NAMES, Gaussians
from gof_warp.training.optim import replace_params


def small_gaussians(n: int = 11, seed: int = 3) -> Gaussians:
    """``n`` Gaussians at SH degree 3 with seeded random raw parameters (CPU)."""
    g = torch.Generator().manual_seed(seed)
    return Gaussians(means=torch.randn(n, 3, generator=g), quats=torch.randn(n, 4, generator=g),
                     log_scales=torch.randn(n, 3, generator=g), opacity_logits=torch.randn(n, generator=g),
                     sh_dc=torch.randn(n, 3, generator=g), sh_rest=torch.randn(n, 15, 3, generator=g))


def steps_with_surgery(g: Gaussians, opt, steps: int, appended: int, swap=None):
    """``steps`` steps of ``opt`` on seeded gradients; after step 2 rows 1 and 4 are removed and ``appended`` rows added
    (:func:`replace_params`); after step ``i``, ``swap(i, opt)`` may hand back another optimizer (None: keep). Returns
    the last optimizer."""
    gen = torch.Generator().manual_seed(5)
    for i in range(steps):
        for k in PARAM_NAMES:
            g.params[k].grad = torch.randn(g.params[k].shape, generator=gen)
        opt.step()
        if i == 2:
            keep = torch.ones(len(g), dtype=torch.bool)
            keep[[1, 4]] = False
            append = {k: torch.randn((appended, *g.params[k].shape[1:]), generator=gen) for k in PARAM_NAMES}
            replace_params(g, opt, keep=keep, append=append)
        if swap is not None:
            opt = swap(i, opt) or opt
    return opt


def through_state_dict(opt, cls, **kwargs):
    """A new ``cls(opt.param_groups, **kwargs)`` holding ``opt``'s state, passed through ``state_dict`` /
    ``load_state_dict`` as a checkpoint would pass it."""
    state = opt.state_dict()
    new = cls(opt.param_groups, **kwargs)
    new.load_state_dict(state)
    return new
