"""Cost of one 3D-filter update (``gof_warp.filter3d.compute_filter_3d``) on a trained model, and of the same kernel
reading its cameras from an array of the ``CameraParams`` struct (as before session 9), which the generated CUDA
loads one byte at a time.

    python benchmarks/train/filter3d_cost.py MODEL.ply SCENE [--out F.json]

Both kernels give the same depths (checked); CUDA events, median of 9 launches after one warm-up.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from gof_warp.data import load_scene  # noqa: E402
from gof_warp.filter3d import SCREEN_GUARD, compute_filter_3d  # noqa: E402
from gof_warp.kernels.render_types import CameraParams, camera_params_from  # noqa: E402
from gof_warp.model import Gaussians  # noqa: E402


@wp.kernel
def nearest_seen_depth_struct_array(means: wp.array(dtype=wp.vec3), cameras: wp.array(dtype=CameraParams), near: float,
                                    guard: float, depth: wp.array(dtype=float)):  # fmt: skip
    """The kernel as it was: ``cam = cameras[k]`` (an element of an array of structs)."""
    i = wp.tid()
    x = means[i]
    d = float(wp.inf)
    for k in range(cameras.shape[0]):
        cam = cameras[k]
        p = cam.R @ x + cam.t
        z = p[2]
        if z > near:
            u = p[0] / z * cam.fx + cam.cx
            v = p[1] / z * cam.fy + cam.cy
            w = float(cam.width)
            h = float(cam.height)
            if u >= -guard * w and u <= (1.0 + guard) * w and v >= -guard * h and v <= (1.0 + guard) * h:
                d = wp.min(d, z)
    depth[i] = d


def _median_ms(fn, reps=9):
    fn()
    times = []
    for _ in range(reps):
        e0, e1 = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
        e0.record()
        fn()
        e1.record()
        torch.cuda.synchronize()
        times.append(e0.elapsed_time(e1))
    return float(np.median(times))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model")
    ap.add_argument("scene")
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    wp.init()
    g = Gaussians.load_ply(a.model, device="cuda")
    cameras = [v.camera for v in load_scene(a.scene).train]
    means = g.means.detach().contiguous()
    res = dict(gpu=torch.cuda.get_device_name(0), gaussians=int(means.shape[0]), cameras=len(cameras))
    res["compute_filter_3d_ms"] = _median_ms(lambda: compute_filter_3d(means, cameras))
    cams = wp.array([camera_params_from(c) for c in cameras], dtype=CameraParams, device="cuda:0")
    depth = torch.empty(means.shape[0], device="cuda")

    def old():
        wp.launch(nearest_seen_depth_struct_array, dim=means.shape[0], inputs=[wp.from_torch(means, dtype=wp.vec3), cams, 0.2,
                  float(SCREEN_GUARD)], outputs=[wp.from_torch(depth)], stream=wp.stream_from_torch())  # fmt: skip

    res["struct_array_kernel_ms"] = _median_ms(old)
    from gof_warp.filter3d import _nearest_seen_depth_warp

    new = _nearest_seen_depth_warp(means, cameras, 0.2)
    res["plain_arrays_kernel_ms"] = _median_ms(lambda: _nearest_seen_depth_warp(means, cameras, 0.2))
    old()
    torch.cuda.synchronize()
    res["same_depths"] = bool(torch.equal(new, depth))
    print(json.dumps(res))
    if a.out:
        Path(a.out).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
