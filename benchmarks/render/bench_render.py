"""GPU benchmark of the differentiable renderer (``gof_warp.rendering.render.rasterize``), plus a CUDA correctness check.

    python benchmarks/render/bench_render.py --check            # CUDA (tiled and plain) vs float64 reference
    python benchmarks/render/bench_render.py --sweep --out DIR  # 100k..3M Gaussians x 800x600, 1920x1080
    python benchmarks/render/bench_render.py --sweep --no-tile-cull --out DIR2  # bounding-box binning, to compare

Each sweep point runs in its own process (clean peak-memory counters). The scene is a "realistic"
synthetic distribution: flat Gaussians on the surfaces of a ground plane, a sphere and a box (tangent
sizes ~ the point spacing, thickness 5 %), 5 % larger background Gaussians on a far sphere, opacities
from a mixture of mostly-opaque and faint, SH degree 3; the camera looks at the objects from 3.5 units.
Results: JSON lines with the machine named (GPU, driver, torch, warp versions).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))

import warp as wp  # noqa: E402

try:  # installed package (pip install -e .) maps kernels/ to gof_warp.kernels; a bare checkout does not
    import gof_warp.kernels  # noqa: F401
except ImportError:
    import importlib.util

    _spec = importlib.util.spec_from_file_location("gof_warp.kernels", REPO / "kernels" / "__init__.py",
                                                   submodule_search_locations=[str(REPO / "kernels")])  # fmt: skip
    sys.modules["gof_warp.kernels"] = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(sys.modules["gof_warp.kernels"])

from gof_warp.benchmarking.render_scene import make_camera, make_scene  # noqa: E402,F401
from gof_warp.rendering.render import DensifyStats, RenderConfig, rasterize  # noqa: E402
from gof_warp.kernels.render_types import camera_params_from, make_raster_settings  # noqa: E402
from gof_warp.kernels.binning import TileListSizer  # noqa: E402
from gof_warp.kernels.renderer import RenderOutputs, render_backward, render_forward  # noqa: E402

OUTPUT_KEYS = ("rgb", "alpha", "depth", "median_depth", "normal", "distortion")
SIZES = {"800x600": (800, 600), "1920x1080": (1920, 1080)}
COUNTS = (100_000, 500_000, 1_000_000, 3_000_000)


def machine_info():
    props = torch.cuda.get_device_properties(0)
    return dict(gpu=props.name, sm_count=props.multi_processor_count, memory_gb=round(props.total_memory / 2**30, 1),
                torch=torch.__version__, cuda=torch.version.cuda, warp=wp.__version__)  # fmt: skip


def _loss_weights(out, seed=1):
    g = torch.Generator(device=out["rgb"].device).manual_seed(seed)
    return {k: torch.randn(out[k].shape, generator=g, device=out[k].device) for k in OUTPUT_KEYS}


def _time(fn, iters, warmup=2):
    for _ in range(warmup):
        fn()
    torch.cuda.synchronize()
    start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    times = []
    for _ in range(iters):
        start.record()
        fn()
        end.record()
        torch.cuda.synchronize()
        times.append(start.elapsed_time(end))
    return float(np.median(times)), float(np.min(times))


def _stage_times(params, cam, tiled, iters=5, reduce_min_lanes=16, tile_cull=True):
    """Median per-stage milliseconds from ``profile`` events of the Warp entry points, and the number of
    (Gaussian, tile) entries."""
    settings = make_raster_settings(cam.width, cam.height, reduce_min_lanes=reduce_min_lanes, tile_cull=tile_cull)
    camp = camera_params_from(cam)
    types = (wp.vec3, wp.vec4, wp.vec3, None, wp.vec3)
    wpar = [wp.from_torch(p, dtype=t) for p, t in zip(params, types)]
    grads = [wp.from_torch(torch.zeros_like(p), dtype=t) for p, t in zip(params, types)]
    stages = {}
    for it in range(iters + 1):
        prof_f, prof_b = [], []
        out, state = render_forward(*wpar, 3, camp, settings, profile=prof_f, tiled=tiled)
        gout = RenderOutputs(*[wp.full_like(a, wp.vec3(1.0) if a.dtype == wp.vec3 else 1.0) for a in out.arrays()])
        render_backward(state, gout, tuple(grads), profile=prof_b)
        wp.synchronize()
        if it == 0:
            continue  # warm-up
        for prof in (prof_f, prof_b):
            for (_, e0), (name, e1) in zip(prof[:-1], prof[1:]):
                stages.setdefault(name, []).append(wp.get_event_elapsed_time(e0, e1))
        entries = state.num_entries
    return {k: float(np.median(v)) for k, v in stages.items()}, entries


def bench_one(n, size, iters, tile_cull=True):
    W, H = SIZES[size]
    cam = make_camera(W, H)
    params = make_scene(n)
    config = RenderConfig(tile_cull=tile_cull)
    res = dict(n=n, size=size, tile_cull=tile_cull, machine=machine_info())
    torch.cuda.synchronize()
    torch.cuda.reset_peak_memory_stats()
    leaves = [p.clone().requires_grad_(True) for p in params]
    stats = DensifyStats(n, device="cuda")

    def fwd():
        with torch.no_grad():
            rasterize(*params, cam, stats=stats, config=config)

    def fwd_bwd():
        out = rasterize(*leaves, cam, stats=stats, config=config)
        w = weights
        sum((out[k] * w[k]).sum() for k in OUTPUT_KEYS).backward()

    sizer = TileListSizer()  # as in training: the tile lists sized without a host-device sync per render

    def fwd_bwd_sized():
        out = rasterize(*leaves, cam, stats=stats, config=config, tile_lists=sizer)
        sum((out[k] * weights[k]).sum() for k in OUTPUT_KEYS).backward()

    train_sizer = TileListSizer()

    def fwd_bwd_train():  # the trainer's path: render() skips the positivity read-back; zero_grad(set_to_none)
        for p in leaves:
            p.grad = None
        out = rasterize(*leaves, cam, stats=stats, config=config, check_values=False, tile_lists=train_sizer)
        sum((out[k] * weights[k]).sum() for k in OUTPUT_KEYS).backward()

    weights = _loss_weights(rasterize(*params, cam, config=config))
    res["fwd_ms"], res["fwd_ms_min"] = _time(fwd, iters)
    res["fwd_bwd_ms"], res["fwd_bwd_ms_min"] = _time(fwd_bwd, iters)
    res["fwd_bwd_sized_ms"], res["fwd_bwd_sized_ms_min"] = _time(fwd_bwd_sized, iters)
    res["fwd_bwd_train_ms"], res["fwd_bwd_train_ms_min"] = _time(fwd_bwd_train, iters)
    res["sizer"] = sizer.stats()
    torch.cuda.synchronize()
    res["peak_torch_mb"] = torch.cuda.max_memory_allocated() / 2**20
    res["peak_warp_mb"] = wp.get_mempool_used_mem_high("cuda:0") / 2**20  # fresh process: Warp's temporaries only
    res["params_mb"] = sum(p.numel() * 4 for p in params) / 2**20
    res["stages_tiled_ms"], res["tile_entries"] = _stage_times(params, cam, tiled=True, tile_cull=tile_cull)
    res["stages_plain_ms"], _ = _stage_times(params, cam, tiled=False, tile_cull=tile_cull)
    res["raster_backward_ms_by_reduce_min_lanes"] = {m: _stage_times(params, cam, tiled=True, reduce_min_lanes=m, tile_cull=tile_cull)[0]["raster_backward"]
                                                     for m in (1, 2, 4, 8, 16, 33)}  # fmt: skip
    out = rasterize(*params, cam, config=config)
    res["mean_alpha"] = float(out["alpha"].mean())
    res["entries_per_tile"] = res["tile_entries"] / (math.ceil(W / 16) * math.ceil(H / 16))
    return res


def check() -> dict:
    """CUDA (shared-memory and plain kernels) vs the float64 brute-force reference, forward and gradients."""
    from reference_render import GRADCHECK_CONFIG, random_scene, reference_render, weighted_loss
    from reference_render import make_camera as ref_camera

    report = {}
    cam = ref_camera(width=53, height=37)
    for name, cfg, rcfg in (("defaults", RenderConfig(), None), ("gradcheck", RenderConfig(alpha_min=0.0, transmittance_min=0.0, k_max=10.0), GRADCHECK_CONFIG)):
        scene = random_scene(cam, 60, 3, seed=5)
        ref = reference_render(*[scene[k] for k in ("means", "quats", "scales", "opacities", "sh")], cam, config=rcfg)
        p64 = [scene[k].clone().requires_grad_(True) for k in ("means", "quats", "scales", "opacities", "sh")]
        ref = reference_render(*p64, cam, config=rcfg)
        g = torch.Generator().manual_seed(3)
        weights = {k: torch.randn(ref[k].shape, generator=g, dtype=torch.float64) for k in OUTPUT_KEYS}
        weighted_loss(ref, weights).backward()
        ok_pix = ref["margin"] > 1e-3  # pixels with no decision within float32 noise of its threshold
        for mode in ("tiled", "plain"):
            import gof_warp.kernels.renderer as R

            orig = R.use_tiled_kernels
            R.use_tiled_kernels = lambda device, settings, tiled=None, _m=mode: _m == "tiled"  # noqa: E731
            leaves = [x.detach().float().cuda().requires_grad_(True) for x in p64]
            out = rasterize(*leaves, cam, config=cfg)
            weighted_loss(out, {k: v.float().cuda() for k, v in weights.items()}).backward()
            R.use_tiled_kernels = orig
            fwd = {k: float(((out[k].double().cpu() - ref[k]).abs())[ok_pix].max()) for k in OUTPUT_KEYS}
            grd = {k: float((l.grad.double().cpu() - p.grad).abs().max() / max(1.0, p.grad.abs().max())) for k, l, p in
                   zip(("means", "quats", "scales", "opacities", "sh"), leaves, p64)}  # fmt: skip
            report[f"{name}/{mode}"] = dict(forward_max_abs=fwd, grad_max_rel=grd, pixels_checked=int(ok_pix.sum()))
    return report


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--sweep", action="store_true")
    ap.add_argument("--one", nargs=2, metavar=("N", "SIZE"))
    ap.add_argument("--iters", type=int, default=7)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "render" / "results"))
    ap.add_argument("--no-tile-cull", action="store_true",
                    help="bin each Gaussian into every tile of its bounding box (the exact tile-ellipse test off)")
    args = ap.parse_args()
    wp.init()
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.check:
        rep = check()
        print(json.dumps(rep, indent=1))
        (out_dir / "cuda_check.json").write_text(json.dumps(dict(machine=machine_info(), check=rep), indent=1))
    if args.one:
        res = bench_one(int(args.one[0]), args.one[1], args.iters, tile_cull=not args.no_tile_cull)
        print("RESULT " + json.dumps(res))
    if args.sweep:
        results = []
        for size in SIZES:
            for n in COUNTS:
                t0 = time.time()
                p = subprocess.run([sys.executable, __file__, "--one", str(n), size, "--iters", str(args.iters), "--out", str(out_dir)]
                                   + (["--no-tile-cull"] if args.no_tile_cull else []), capture_output=True, text=True, env=os.environ)  # fmt: skip
                line = [ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")]
                if not line:
                    print(p.stdout[-2000:], p.stderr[-4000:])
                    continue
                res = json.loads(line[0][7:])
                results.append(res)
                print(f"{size} n={n}: fwd {res['fwd_ms']:.2f} ms, fwd+bwd {res['fwd_bwd_ms']:.2f} ms, peak torch {res['peak_torch_mb']:.0f} MB "
                      f"+ warp {res['peak_warp_mb']:.0f} MB, entries/tile {res['entries_per_tile']:.0f}, stages {res['stages_tiled_ms']} plain {res['stages_plain_ms']} ({time.time()-t0:.0f} s)", flush=True)  # fmt: skip
                (out_dir / "sweep.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
