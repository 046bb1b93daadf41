"""WarpAdam against torch's fused Adam at the DTU model's size on a GPU: the same parameters and
gradients, 30 steps with the means' rate changing, a densification (rows kept and appended) at step 10 and GOF's
opacity reset at step 20; prints the largest relative difference of each parameter and moment and how many floats
of them differ at all (on a GPU, where WarpAdam does torch's fused CUDA arithmetic: none).

    python benchmarks/train/warp_adam_check.py [--gaussians 848237]
"""

from __future__ import annotations

import argparse
import json

import torch

from gof_warp.training.densify import reset_opacity
from gof_warp.core.model import PARAM_NAMES, Gaussians
from gof_warp.training.optim import OptimConfig, make_optimizer, replace_params


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--gaussians", type=int, default=848_237)
    ap.add_argument("--device", default="cuda")
    a = ap.parse_args()
    dev = torch.device(a.device)
    n = a.gaussians
    gen = torch.Generator(device=dev).manual_seed(0)
    init = dict(means=torch.randn(n, 3, device=dev, generator=gen), quats=torch.randn(n, 4, device=dev, generator=gen),
                log_scales=torch.randn(n, 3, device=dev, generator=gen) - 4,
                opacity_logits=torch.randn(n, device=dev, generator=gen), sh_dc=torch.randn(n, 3, device=dev, generator=gen),
                sh_rest=torch.randn(n, 15, 3, device=dev, generator=gen) * 0.1)
    models = {}
    for kind in ("torch", "warp"):
        g = Gaussians(**{k: v.clone() for k, v in init.items()})
        opt = make_optimizer(g, OptimConfig(adam=kind, fused=True), extent=1.0)
        gg = torch.Generator(device=dev).manual_seed(1)
        for step in range(30):
            for i, k in enumerate(PARAM_NAMES):
                p = g.params[k]
                if step % 7 == 3 and i == 2:  # a parameter without a gradient now and then
                    p.grad = None
                    continue
                big = torch.randn(p.numel() + 3, device=dev, generator=gg) * 1e-3  # a view at an offset, as fused
                p.grad = big[: p.numel()].view(p.shape) if step % 2 else big[: p.numel()].view(p.shape).clone()
            opt.param_groups[0]["lr"] = 1.6e-4 * 0.99**step
            opt.step()
            opt.zero_grad(set_to_none=True)
            if step == 10:
                m = len(g)
                keep = torch.rand(m, device=dev, generator=gg) > 0.05
                add = min(20_000, n // 10)
                append = {k: torch.randn((add, *g.params[k].shape[1:]), device=dev, generator=gg) for k in PARAM_NAMES}
                replace_params(g, opt, keep=keep, append=append)
            if step == 20:
                reset_opacity(g, opt)
        models[kind] = (g, opt)
    (gt, ot), (gw, ow) = models["torch"], models["warp"]
    out, differing = {}, 0
    for k in PARAM_NAMES:
        a_, b_ = gt.params[k].detach(), gw.params[k].detach()
        out[k] = float((a_ - b_).abs().max() / a_.abs().max())
        differing += int((a_ != b_).sum())
        for mk in ("exp_avg", "exp_avg_sq"):
            sa, sb = ot.state[gt.params[k]][mk], ow.state[gw.params[k]][mk]
            out[f"{k}.{mk}"] = float((sa - sb).abs().max() / sa.abs().max().clamp_min(1e-30))
            differing += int((sa != sb).sum())
    out["worst"] = max(out.values())
    # WarpAdam does torch's fused CUDA arithmetic: on a GPU every float should be the same
    out["differing_floats"] = differing
    out["device"] = torch.cuda.get_device_name(dev) if dev.type == "cuda" else "cpu"
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
