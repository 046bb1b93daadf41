"""How far torch's Adam over the Gaussians' parameters is from its memory roofline (issue 14; run on a GPU).

The trainer's optimiser is ``torch.optim.Adam(fused=True)`` with one group per parameter (``gof_warp.training.optim``). Its
traffic per float is at least 28 bytes (read parameter, gradient, both moments; write parameter and both moments).
This times, for DTU scan 24's final model size by default (776,149 Gaussians, SH degree 3: 59 floats each):

* ``fused``: torch's fused Adam (six groups, the means' rate changed every step as the schedule does);
* ``lean``: ``gof_warp.training.optim.LeanAdam``, the same kernel with less host work (``optim.adam=torch``);
* ``warp``: ``gof_warp.training.optim.WarpAdam`` (``optim.adam=warp``, the default on CUDA), one Warp
  kernel a parameter, four floats a thread;
* ``foreach``: torch's multi-tensor Adam, for comparison;
* ``copy``: 12 B a float copied and 4 B more read (28 B of traffic a float, as Adam's), the practical roofline;
* ``zero_grad``: clearing the gradients (``set_to_none=False``, what a step after it reads).

Each optimiser's GPU time per step (CUDA events) and its host time per step (wall time of the calls while the GPU is
kept busy, the host's own cost). Usage: ``python benchmarks/train/adam_roofline.py [--gaussians N] [--iters K]
[--out FILE.json]``.
"""

from __future__ import annotations

import argparse
import json
import time

import torch

from gof_warp.training.optim import LeanAdam, WarpAdam

SHAPES = {"means": (3,), "sh_dc": (1, 3), "sh_rest": (15, 3), "opacity_logits": (1,), "log_scales": (3,),
          "quats": (4,)}
LR = {"means": 1.6e-4, "sh_dc": 2.5e-3, "sh_rest": 1.25e-4, "opacity_logits": 0.05, "log_scales": 5e-3, "quats": 1e-3}


def timed(fn, iters: int) -> float:
    """Mean milliseconds of ``fn`` over ``iters`` calls after 10 warm-up calls (CUDA events)."""
    for _ in range(10):
        fn()
    start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    torch.cuda.synchronize()
    start.record()
    for _ in range(iters):
        fn()
    end.record()
    torch.cuda.synchronize()
    return start.elapsed_time(end) / iters


def host_ms(fn, iters: int) -> float:
    """Mean milliseconds of the host's own time in ``fn``: the calls are timed on the wall clock while a long kernel
    queued first keeps the GPU busy (so that no call waits for the device)."""
    big = torch.empty(1 << 28, device="cuda")
    torch.cuda.synchronize()
    for _ in range(300):
        big.mul_(1.0)  # ~0.2 s of queued work ahead of the calls on an H100 (300 of the ~1,000 launches CUDA queues)
    t = time.perf_counter()
    for _ in range(iters):
        fn()
    host = (time.perf_counter() - t) / iters * 1e3
    torch.cuda.synchronize()
    return host


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--gaussians", type=int, default=776_149)
    ap.add_argument("--iters", type=int, default=200)
    ap.add_argument("--out")
    a = ap.parse_args()
    dev = torch.device("cuda")
    gen = torch.Generator(device=dev).manual_seed(0)
    result = {"gaussians": a.gaussians, "device": torch.cuda.get_device_name(dev), "torch": torch.__version__}
    floats = a.gaussians * sum(torch.Size(s).numel() for s in SHAPES.values())
    result["floats"] = floats
    for mode in ("fused", "lean", "warp", "foreach"):
        params = [torch.nn.Parameter(torch.randn((a.gaussians, *s), device=dev, generator=gen))
                  for s in SHAPES.values()]
        for p in params:
            p.grad = torch.randn(p.shape, device=dev, generator=gen) * 1e-3
        groups = [{"params": [p], "lr": LR[n], "name": n} for p, n in zip(params, SHAPES)]
        if mode == "warp":
            opt = WarpAdam(groups, eps=1e-15, betas=(0.9, 0.999))
        else:
            cls = LeanAdam if mode == "lean" else torch.optim.Adam
            opt = cls(groups, eps=1e-15, betas=(0.9, 0.999), **{"fused" if mode == "lean" else mode: True})
        step = [0]

        def adam_step():
            step[0] += 1
            opt.param_groups[0]["lr"] = LR["means"] * 0.999 ** (step[0] % 100)  # the schedule: a new rate each step
            opt.step()

        result[f"{mode}_ms"] = timed(adam_step, a.iters)
        result[f"{mode}_host_ms"] = host_ms(adam_step, 50)  # 50 steps: their launches fit CUDA's queue
        if mode == "fused":
            result["zero_grad_ms"] = timed(lambda: opt.zero_grad(set_to_none=False), a.iters)
    src = torch.empty(floats * 4, device=dev, dtype=torch.float32)  # 16 B a float read
    dst = torch.empty(floats * 3, device=dev, dtype=torch.float32)  # 12 B a float written

    def copy():
        dst.copy_(src[: floats * 3])
        src[floats * 3:].sum()

    result["copy_ms"] = timed(copy, a.iters)
    result["bytes_per_step"] = floats * 28
    for mode in ("fused", "lean", "warp"):
        result[f"{mode}_GBps"] = result["bytes_per_step"] / result[f"{mode}_ms"] / 1e6
    result["copy_GBps"] = result["bytes_per_step"] / result["copy_ms"] / 1e6
    print(json.dumps(result, indent=1))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
