"""Where one forward + backward of the renderer spends its time: every kernel (Warp's and torch's), and the GPU's idle gaps.

    python benchmarks/render/profile_render.py [--n 1000000] [--size 1920x1080] [--trace 10] [--out F.json]

On ``bench_render.py``'s synthetic scene and camera, the timed step of ``bench_render.py --one`` (``fwd_bwd``:
:func:`gof_warp.render.rasterize`, a fixed random weighted sum of the six outputs, ``backward()``) and the same step
as training runs it (``fwd_bwd_train``: :func:`gof_warp.render.render`'s path — no positivity read-back, a
``TileListSizer`` kept across calls, the leaves' ``.grad`` set to ``None`` before each step as the optimiser's
``zero_grad`` does, so no gradient accumulation kernel), each timed with CUDA events (median of ``--iters``) and
traced with ``torch.profiler`` for ``--trace`` steps: per-kernel milliseconds per step, the GPU's busy time (union of
its spans) against the wall time, and the census of the tile test's cases (``exact`` 0/1/2: whole rectangle,
ellipse rows, general conic) with the tiles the general-conic Gaussians span.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "train"))

from bench_render import OUTPUT_KEYS, SIZES, _loss_weights, _time, machine_info, make_camera, make_scene  # noqa: E402
from profile_train import summarise_trace  # noqa: E402

import warp as wp  # noqa: E402

from gof_warp.kernels.binning import TileListSizer  # noqa: E402
from gof_warp.kernels.project import preprocess_gaussians, screen_bounds  # noqa: E402
from gof_warp.kernels.render_types import camera_params_from  # noqa: E402
from gof_warp.kernels.renderer import sh_parts  # noqa: E402
from gof_warp.kernels.tile_overlap import empty_tile_ellipses  # noqa: E402
from gof_warp.render import DensifyStats, RenderConfig, raster_settings_for, rasterize  # noqa: E402


def census(params, camera, config) -> dict:
    """How many Gaussians take each case of the tile test, and the rectangles of the general-conic ones."""
    means, quats, scales, opacities, sh = params
    n = means.shape[0]
    cam, settings = camera_params_from(camera), raster_settings_for(camera, config)
    w = [wp.from_torch(x.contiguous(), dtype=t) for x, t in zip(params, (wp.vec3, wp.vec4, wp.vec3, None, wp.vec3))]
    mu_v, P, o_g, col = (wp.empty(n, dtype=t) for t in (wp.vec3, wp.mat33, wp.vec3, wp.vec3))
    wp.launch(preprocess_gaussians, dim=n, inputs=[w[0], w[1], w[2], *sh_parts(w[4]), 3, cam.R, cam.t, cam.centre], outputs=[mu_v, P, o_g, col])
    rect, touched, radii, depth = (wp.empty(n, dtype=t) for t in (wp.vec4i, wp.int32, wp.int32, float))
    ellipse = empty_tile_ellipses(n)
    wp.launch(screen_bounds, dim=n, inputs=[mu_v, w[1], w[2], w[3], cam, settings], outputs=[rect, touched, radii, depth, ellipse])
    timed = {}
    if wp.get_device().is_cuda:  # screen_bounds with and without the tile test's conic (its share of the kernel)
        for cull in (1, 0):
            settings.tile_cull = cull
            times = []
            for _ in range(8):
                e0, e1 = wp.Event(enable_timing=True), wp.Event(enable_timing=True)
                wp.record_event(e0)
                wp.launch(screen_bounds, dim=n, inputs=[mu_v, w[1], w[2], w[3], cam, settings], outputs=[rect, touched, radii, depth, ellipse])
                wp.record_event(e1)
                wp.synchronize()
                times.append(wp.get_event_elapsed_time(e0, e1))
            timed[f"screen_bounds_ms_tile_cull{cull}"] = float(np.median(times[1:]))
        settings.tile_cull = 1
        wp.launch(screen_bounds, dim=n, inputs=[mu_v, w[1], w[2], w[3], cam, settings], outputs=[rect, touched, radii, depth, ellipse])
    r, exact = rect.numpy(), ellipse.exact.numpy()
    tiles = (r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1])
    rows = r[:, 3] - r[:, 1]
    out = {f"exact{e}": int(((exact == e) & (tiles > 0)).sum()) for e in (0, 1, 2)}
    g = (exact == 2) & (tiles > 0)
    out["exact2_rect_tiles_max"] = int(tiles[g].max()) if g.any() else 0
    out["exact2_rect_tiles_sum"] = int(tiles[g].sum())
    e1 = (exact == 1) & (tiles > 0)
    out["exact1_rows_max"] = int(rows[e1].max()) if e1.any() else 0
    out["exact1_rows_sum"] = int(rows[e1].sum())
    return {**out, **timed}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--size", default="1920x1080", choices=sorted(SIZES))
    ap.add_argument("--iters", type=int, default=9)
    ap.add_argument("--trace", type=int, default=10)
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    from torch.profiler import ProfilerActivity, profile as torch_profile

    wp.init()
    W, H = SIZES[a.size]
    camera = make_camera(W, H)
    params = make_scene(a.n)
    config = RenderConfig()
    leaves = [p.clone().requires_grad_(True) for p in params]
    stats = DensifyStats(a.n, device="cuda")
    weights = _loss_weights(rasterize(*params, camera, config=config))
    sizer = TileListSizer()

    def fwd_bwd():  # bench_render.py --one's step, as timed there
        out = rasterize(*leaves, camera, stats=stats, config=config)
        sum((out[k] * weights[k]).sum() for k in OUTPUT_KEYS).backward()

    def fwd_bwd_train():  # the trainer's path through the renderer
        for p in leaves:
            p.grad = None
        out = rasterize(*leaves, camera, stats=stats, config=config, check_values=False, tile_lists=sizer)
        sum((out[k] * weights[k]).sum() for k in OUTPUT_KEYS).backward()

    res = dict(n=a.n, size=a.size, machine=machine_info(), census=census(params, camera, config))
    for name, fn in (("fwd_bwd", fwd_bwd), ("fwd_bwd_train", fwd_bwd_train)):
        med, lo = _time(fn, a.iters)
        for _ in range(2):
            fn()
        torch.cuda.synchronize()
        with torch_profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
            for _ in range(a.trace):
                fn()
            torch.cuda.synchronize()
        with tempfile.TemporaryDirectory() as tmp:
            trace = Path(tmp) / "trace.json"
            prof.export_chrome_trace(str(trace))
            events = json.loads(trace.read_text())
        events = events["traceEvents"] if isinstance(events, dict) else events
        summary = summarise_trace(events, a.trace)
        summary.pop("stages", None)
        res[name] = dict(ms=med, ms_min=lo, **summary)
        print(name, f"{med:.2f} ms (min {lo:.2f}), GPU busy {summary['device_busy_ms_per_it']:.2f} ms/step, "
              f"{summary['kernel_launches_per_it']:.0f} launches")  # fmt: skip
        for k in summary["top_kernels"][:18]:
            print(f"  {k['ms_per_it']:7.3f} ms x{k['calls_per_it']:<5} {k['name'][:100]}")
    print("census", json.dumps(res["census"]))
    res["sizer"] = sizer.stats()
    if a.out:
        Path(a.out).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
