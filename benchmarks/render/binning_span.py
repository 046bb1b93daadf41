"""The binning's count pass with the closed-form row span against the tile-by-tile scan it replaced.

    python benchmarks/render/binning_span.py [--model MODEL.ply --scene SCENE] [--synthetic N WxH ...] [--out F.json]

For every camera of ``SCENE`` rendering ``MODEL`` (e.g. the trained DTU scan 24 model) and for the synthetic
benchmark scenes of ``bench_render.py``: ``preprocess_gaussians`` and ``screen_bounds`` once, then the count pass
``count_tile_keys`` (per row :func:`row_tile_span`, O(1)) and the same pass with :func:`row_tile_span_scan` (the
tile test from both ends of each row, the code before), each timed with CUDA events (median of ``--iters``), and
their per-Gaussian counts compared. The write pass (``write_tile_keys``) runs the same span per row, so it gains
about as much; the trainer profile (``../train/profile_train.py``) shows both kernels.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import warp as wp

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from gof_warp.kernels.binning import conic_tile_count, count_tile_keys  # noqa: E402
from gof_warp.kernels.project import preprocess_gaussians, screen_bounds  # noqa: E402
from gof_warp.kernels.render_types import CameraParams, RasterSettings, camera_params_from  # noqa: E402
from gof_warp.kernels.renderer import sh_parts  # noqa: E402
from gof_warp.kernels.tile_overlap import TileEllipses, empty_tile_ellipses, load_ellipse, row_tile_span_scan  # noqa: E402
from gof_warp.render import RenderConfig, raster_settings_for  # noqa: E402

wp.set_module_options({"fuse_fp": False, "enable_backward": False})


@wp.kernel
def count_tile_keys_scan(rect: wp.array(dtype=wp.vec4i), ellipse: TileEllipses, cam: CameraParams,
                         settings: RasterSettings, tiles_touched: wp.array(dtype=wp.int32)):  # fmt: skip
    """``count_tile_keys`` as it was: each row's span found by :func:`row_tile_span_scan`."""
    k = wp.tid()
    r = rect[k]
    e = load_ellipse(ellipse, k)
    n = int(0)
    if e.exact == 2:
        n = conic_tile_count(r, e, cam, settings)
    else:
        for ty in range(r[1], r[3]):
            span = row_tile_span_scan(e, ty, r[0], r[2], cam, settings)
            n += span[1] - span[0]
    tiles_touched[k] = n


def _timed(kernel, n, inputs, out, iters):
    """Median milliseconds of one launch (CUDA events; wall clock on the CPU, for a smoke run)."""
    times = []
    for _ in range(iters + 1):
        if wp.get_device().is_cuda:
            e0, e1 = wp.Event(enable_timing=True), wp.Event(enable_timing=True)
            wp.record_event(e0)
            wp.launch(kernel, dim=n, inputs=inputs, outputs=[out])
            wp.record_event(e1)
            wp.synchronize()
            times.append(wp.get_event_elapsed_time(e0, e1))
        else:
            t0 = time.perf_counter()
            wp.launch(kernel, dim=n, inputs=inputs, outputs=[out])
            times.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(times[1:]))


def compare_view(params, camera, config, iters):
    """One camera: count-pass milliseconds of both spans, entries, Gaussians whose counts differ."""
    means, quats, scales, opacities, sh = params
    cam = camera_params_from(camera)
    settings = raster_settings_for(camera, config)
    n = means.shape[0]
    wpar = [wp.from_torch(x.contiguous(), dtype=t) for x, t in zip(params, (wp.vec3, wp.vec4, wp.vec3, None, wp.vec3))]
    mu_v, P, o_g, col = (wp.empty(n, dtype=t) for t in (wp.vec3, wp.mat33, wp.vec3, wp.vec3))
    wp.launch(preprocess_gaussians, dim=n, inputs=[wpar[0], wpar[1], wpar[2], *sh_parts(wpar[4]), int(round(sh.shape[1] ** 0.5)) - 1, cam.R, cam.t, cam.centre],
              outputs=[mu_v, P, o_g, col])  # fmt: skip
    rect, touched, radii, depth = (wp.empty(n, dtype=t) for t in (wp.vec4i, wp.int32, wp.int32, float))
    ellipse = empty_tile_ellipses(n)
    wp.launch(screen_bounds, dim=n, inputs=[mu_v, wpar[1], wpar[2], wpar[3], cam, settings], outputs=[rect, touched, radii, depth, ellipse])
    closed, scan = wp.empty(n, dtype=wp.int32), wp.empty(n, dtype=wp.int32)
    inputs = [rect, ellipse, cam, settings]
    ms_closed = _timed(count_tile_keys, n, inputs, closed, iters)
    ms_scan = _timed(count_tile_keys_scan, n, inputs, scan, iters)
    c, s = closed.numpy(), scan.numpy()
    exact = ellipse.exact.numpy()
    return dict(count_ms_closed=ms_closed, count_ms_scan=ms_scan, entries_closed=int(c.sum()), entries_scan=int(s.sum()),
                gaussians_differing=int((c != s).sum()), gaussians_fewer=int((c < s).sum()),
                rows_exact1=int(((rect.numpy()[:, 3] - rect.numpy()[:, 1]) * (exact == 1)).sum()))  # fmt: skip


def _summary(views):
    keys = ("count_ms_closed", "count_ms_scan", "entries_closed", "entries_scan", "gaussians_differing", "gaussians_fewer")
    tot = {k: float(sum(v[k] for v in views)) for k in keys}
    tot["views"] = len(views)
    tot["speedup"] = tot["count_ms_scan"] / max(tot["count_ms_closed"], 1e-9)
    return tot


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model")
    ap.add_argument("--scene")
    ap.add_argument("--synthetic", nargs=2, action="append", metavar=("N", "WxH"), default=[])
    ap.add_argument("--iters", type=int, default=7)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    wp.init()
    wp.set_device(a.device)
    gpu = torch.cuda.get_device_name(0) if a.device.startswith("cuda") else "cpu"
    res = dict(gpu=gpu, torch=torch.__version__, warp=wp.__version__, iters=a.iters)
    if a.model:
        from gof_warp.data import load_scene
        from gof_warp.model import Gaussians

        g = Gaussians.load_ply(a.model, device=a.device)
        scene = load_scene(a.scene)
        params = [x.detach().contiguous() for x in (g.means, g.rotations, g.scales, g.opacities, g.sh)]
        config = RenderConfig(background=tuple(float(c) for c in scene.background))
        views = [compare_view(params, v.camera, config, a.iters) for v in scene.train]
        res["model"] = dict(path=a.model, gaussians=int(g.means.shape[0]), image=[scene.train[0].camera.width, scene.train[0].camera.height],
                            total=_summary(views), views=views)  # fmt: skip
        print("model", json.dumps(res["model"]["total"]))
    if a.synthetic:
        from bench_render import SIZES, make_camera, make_scene

        for n, size in a.synthetic:
            W, H = SIZES[size]
            params = [x.contiguous() for x in make_scene(int(n), device=a.device)]
            v = compare_view(params, make_camera(W, H), RenderConfig(), a.iters)
            res.setdefault("synthetic", {})[f"{n}@{size}"] = v
            print(n, size, json.dumps(v))
    if a.out:
        Path(a.out).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
