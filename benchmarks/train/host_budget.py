"""Host time and GPU time of each part of a training step, measured apart (issue 14; for the GPU machine).

A profiler's tracer inflates the host side several-fold, and a step's wall clock is the larger of the two sides, so
neither says how much host time each part costs. Here each part runs K times while the GPU is held busy by a
``torch.cuda._sleep`` queued first: the host's issue time is the wall clock of the K calls (the GPU cannot make the
host wait), and the GPU time is the elapsed time between two events around the K calls (queued back to back behind
the sleep). Parts, on an 800×600 view (DTU's size):

- ``render``: ``gof_warp.render`` forward + backward of N random Gaussians (the Warp glue: arrays, launches);
  ``render_scratch``: the same through a ``RenderScratch``, as the trainer renders (a tree that has it);
- ``loss[+appearance]_<mode>``: the training loss forward + backward with the regularisers, without and with the
  decoupled appearance in its L1 term (eager, compiled, compiled with CUDA graphs: ``mode="reduce-overhead"``);
- ``appearance_<variant>``: the decoupled-appearance CNN alone, eager, forward + backward (default, channels-last);
- ``adam``: one fused Adam step over the six parameter groups of N Gaussians.

    python benchmarks/train/host_budget.py --out host_budget.json [--gaussians 800000] [--calls 4]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch


def issue_and_gpu_ms(fn, calls: int, sleep_cycles: int) -> tuple[float, float]:
    """(host ms per call, GPU ms per call) of ``fn`` issued ``calls`` times behind a GPU sleep."""
    fn()
    torch.cuda.synchronize()
    start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    torch.cuda._sleep(sleep_cycles)
    start.record()
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    host = time.perf_counter() - t0
    end.record()
    end.synchronize()
    busy_after_sleep = start.elapsed_time(end)
    return 1e3 * host / calls, busy_after_sleep / calls


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--gaussians", type=int, default=800_000)
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--height", type=int, default=600)
    ap.add_argument("--calls", type=int, default=4,
                    help="calls per measurement (the launch queue, ~1,000 kernels, must hold them)")
    ap.add_argument("--reps", type=int, default=5, help="measurements per part (the median is reported)")
    ap.add_argument("--sleep-cycles", type=int, default=1_000_000_000, help="~0.5 s of GPU sleep on an H100")
    ap.add_argument("--parts", default="render,loss,appearance,adam")
    ap.add_argument("--cprofile", type=int, default=0, help="print the N functions of most host time in each part")
    ap.add_argument("--kernels", type=int, default=0, help="print the N CUDA kernels of most GPU time in each part")
    ap.add_argument("--cudnn-benchmark", action="store_true",
                    help="cuDNN times its algorithms (torch.backends.cudnn.benchmark), as a training run sets it")
    ap.add_argument("--no-tf32", action="store_true",
                    help="cuDNN's convolutions in float32 proper (torch.backends.cudnn.allow_tf32 = False)")
    ap.add_argument("--loss-modes", default="off,on,graphs",
                    help="the loss parts' modes: eager (off), compiled (on), compiled as CUDA graphs (graphs)")
    ap.add_argument("--autotune", action="store_true",
                    help="also the loss with the appearance compiled with mode='max-autotune' (Triton convolution "
                         "templates benchmarked against cuDNN, and CUDA graphs)")
    args = ap.parse_args()

    import warp as wp

    from gof_warp.appearance import AppearanceModel
    from gof_warp.camera import look_at
    from gof_warp.kernels.binning import TileListSizer
    from gof_warp.losses import LossConfig, TrainingLoss
    from gof_warp.model import Gaussians
    from gof_warp.optim import OptimConfig, make_optimizer
    from gof_warp.render import render

    wp.config.quiet = True
    torch.backends.cudnn.benchmark = args.cudnn_benchmark
    torch.backends.cudnn.allow_tf32 = not args.no_tf32
    dev = torch.device("cuda")
    H, W = args.height, args.width
    cam = look_at((3.0, 0.0, 1.0), (0.0, 0.0, 0.0), fx=0.9 * W, width=W, height=H)
    rng = torch.Generator(device="cpu").manual_seed(0)
    parts: dict[str, callable] = {}
    wanted = set(args.parts.split(","))

    g = Gaussians.random_in_box(args.gaussians, sh_degree=3).to(dev)
    g.requires_grad_(True)
    if "render" in wanted:
        sizer = TileListSizer()

        def render_part(**kept):
            out = render(g, cam, tile_lists=sizer, **kept)
            (out["rgb"].sum() + out["alpha"].sum() + out["median_depth"].sum() + out["normal"].sum()
             + out["distortion"].sum()).backward()
        parts["render"] = render_part
        try:
            from gof_warp.render import RenderScratch
        except ImportError:  # a tree from before it
            pass
        else:
            scratch = RenderScratch()
            parts["render_scratch"] = lambda: render_part(scratch=scratch)

    if "loss" in wanted:
        maps = {"rgb": torch.rand(H, W, 3, generator=rng), "alpha": torch.rand(H, W, generator=rng),
                "median_depth": 2.0 + torch.rand(H, W, generator=rng),
                "normal": torch.rand(H, W, 3, generator=rng) - 0.5,
                "distortion": torch.rand(H, W, generator=rng)}
        maps = {k: v.to(dev).requires_grad_(True) for k, v in maps.items()}
        gt = torch.rand(H, W, 3, generator=rng).to(dev)
        cfg = LossConfig(regularization_from_iter=0)
        for appearance in (None, AppearanceModel(1).to(dev)):
            for mode in args.loss_modes.split(","):
                loss = TrainingLoss(cfg, [cam], dev, "on" if mode == "graphs" else mode, cuda_graphs=mode == "graphs",
                                    appearance=appearance)

                def loss_part(loss=loss):
                    value, _ = loss(dict(maps), gt, cam, 0, 1)
                    value.backward()
                for _ in range(3):  # compile / record before timing
                    loss_part()
                parts[f"loss{'' if appearance is None else '+appearance'}_{mode}"] = loss_part
        if args.autotune:
            from gof_warp.losses import appearance_loss_terms
            loss = TrainingLoss(cfg, [cam], dev, "on", cuda_graphs=True, appearance=AppearanceModel(1).to(dev))
            loss.compiled_appearance = torch.compile(appearance_loss_terms, dynamic=False, fullgraph=True,
                                                     mode="max-autotune")
            t0 = time.perf_counter()

            def autotuned(loss=loss):
                value, _ = loss(dict(maps), gt, cam, 0, 1)
                value.backward()
            for _ in range(3):
                autotuned()
            print(f"max-autotune compile and first calls: {time.perf_counter() - t0:.1f} s", flush=True)
            parts["loss+appearance_autotune"] = autotuned

    if "appearance" in wanted:  # the network alone, eager
        rgb = torch.rand(3, H, W, generator=rng).to(dev).requires_grad_(True)
        for variant in ("default", "channels_last"):
            model = AppearanceModel(64).to(dev)
            if variant == "channels_last":
                model = model.to(memory_format=torch.channels_last)

            def appearance_part(model=model):
                model.apply(rgb, 3).sum().backward()
            for _ in range(3):
                appearance_part()
            parts[f"appearance_{variant}"] = appearance_part

    if "adam" in wanted:
        opt = make_optimizer(g, OptimConfig(), 3.0)
        for p in g.params.values():
            p.grad = torch.rand_like(p) * 1e-3

        def adam_part():
            opt.step()
        parts["adam"] = adam_part

    torch.cuda.synchronize()
    start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    start.record()
    torch.cuda._sleep(args.sleep_cycles)
    end.record()
    end.synchronize()
    sleep_ms = start.elapsed_time(end)
    results = {"sleep_ms": round(sleep_ms, 1), "device": torch.cuda.get_device_name(), "torch": torch.__version__,
               "cudnn_benchmark": args.cudnn_benchmark, "cudnn_tf32": not args.no_tf32,
               "warp": wp.config.version,
               "gaussians": args.gaussians, "image": [W, H], "calls": args.calls, "reps": args.reps, "parts": {}}
    for name, fn in parts.items():
        samples = [issue_and_gpu_ms(fn, args.calls, args.sleep_cycles) for _ in range(args.reps)]
        host, gpu = (float(np.median([s[i] for s in samples])) for i in (0, 1))
        # a host time near the sleep's means the calls overfilled the launch queue (~1,000 kernels) and the host
        # waited for the sleep: not a measurement (fewer --calls)
        queue_full = host * args.calls > 0.5 * sleep_ms
        results["parts"][name] = {"host_ms": round(host, 3), "gpu_ms": round(gpu, 3),
                                  "host_ms_all": [round(s[0], 3) for s in samples], "queue_full": queue_full}
        print(f"{name:40s} host {host:7.3f} ms  gpu {gpu:7.3f} ms" + ("  (queue full: not a measurement)" if queue_full
                                                                        else ""), flush=True)
        if args.cprofile:
            import cProfile
            import pstats
            profiler = cProfile.Profile()
            profiler.enable()
            issue_and_gpu_ms(fn, args.calls, args.sleep_cycles)
            profiler.disable()
            pstats.Stats(profiler).sort_stats("tottime").print_stats(args.cprofile)
        if args.kernels:
            from torch.profiler import ProfilerActivity, profile
            with profile(activities=[ProfilerActivity.CUDA, ProfilerActivity.CPU]) as prof:
                for _ in range(args.calls):
                    fn()
                torch.cuda.synchronize()
            table = prof.key_averages().table(sort_by="cuda_time_total", row_limit=args.kernels, max_name_column_width=70)
            print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
