"""Cost of the unbounded preset's near-camera test (`in_front_of_cameras`, run at every late prune: every 100
iterations after 15k) and of the spike's ray census (`near_ray_census`, once per listed spike), on the device.

A colmap_can-like setting without its data: 62 cameras of 720×1280 (fx = fy = 1000) on a ring of radius 4 looking at
the origin, N Gaussians uniform in a 4-unit cube (scales 0.01–0.1, random rotations and opacities), plus 500
opaque ones planted 0.3 in front of randomly chosen cameras; bounds 0.75 (a quarter of 3). Checks that every
planted Gaussian is flagged. Pure torch: runs where torch sees a GPU, without Warp.

    python3 benchmarks/real_captures/late_prune_cost.py OUT.json
Measured on one NVIDIA H200 (session 14, results/s14_camera_near_h200/late_prune_cost.json): one in-front test
96 ms at N = 150,000 and 102 ms at 300,000 (about 1 ms per iteration at one test per 100 iterations), every planted
Gaussian flagged; one ray census 7-12 ms. On the 2-core CPU dev box with N = 3,000: 4.9 s per in-front test.
"""
import json
import sys
import time

import numpy as np
import torch

from gof_warp.camera import look_at
from gof_warp.near_camera import in_front_of_cameras, near_ray_census, stack_cameras

dev = "cuda" if torch.cuda.is_available() else "cpu"
rng = np.random.default_rng(0)
cams = []
for k in range(62):
    a = 2 * np.pi * k / 62
    cams.append(look_at(eye=(4 * np.cos(a), 4 * np.sin(a), 1.0), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0),
                        fx=1000.0, fy=1000.0, width=720, height=1280, name=f"{k:04d}"))
stack = stack_cameras(cams, dev)
bounds = torch.full((62,), 0.75, device=dev)


def timed(fn, repeat):
    fn()
    if dev == "cuda":
        torch.cuda.synchronize()
    t0 = time.perf_counter()
    for _ in range(repeat):
        out = fn()
    if dev == "cuda":
        torch.cuda.synchronize()
    return (time.perf_counter() - t0) / repeat * 1000, out


rows = []
for n in (150_000, 300_000):
    means = torch.tensor(rng.uniform(-2, 2, (n, 3)), dtype=torch.float32, device=dev)
    which = rng.integers(0, 62, 500)
    planted = np.stack([cams[c].center + 0.3 * cams[c].R[2] for c in which])
    means[:500] = torch.tensor(planted, dtype=torch.float32, device=dev)
    quats = torch.randn(n, 4, device=dev)
    scales = torch.rand(n, 3, device=dev) * 0.09 + 0.01
    opac = torch.rand(n, device=dev)
    opac[:500] = 0.95
    ms, flagged = timed(lambda: in_front_of_cameras(means, quats, scales, opac, stack, bounds), 5)
    census_ms, census = timed(lambda: near_ray_census(means, quats, scales, opac, cams[int(which[0])], within=1.86),
                              5)
    rows.append({"gaussians": n, "in_front_ms": round(ms, 2), "per_iteration_ms_at_interval_100": round(ms / 100, 3),
                 "flagged": int(flagged.sum()), "planted_all_flagged": bool(flagged[:500].all()),
                 "ray_census_ms": round(census_ms, 2), "census_covered": census["covered"]})
    print(rows[-1], flush=True)
result = {"device": torch.cuda.get_device_name(0) if dev == "cuda" else "cpu", "torch": torch.__version__,
          "cameras": 62, "image": [720, 1280], "rows": rows}
with open(sys.argv[1], "w") as f:
    json.dump(result, f, indent=1)
