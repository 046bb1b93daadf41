"""Benchmark: bake a run's GOF opacity field into a NanoVDB volume and query it inside a Warp kernel.

    python benchmarks/warp_embedding/bake_volume.py RUN [--scene SCENE] [--voxel-size V] [--out results.json]

Measures the bake (time per stage, active voxels, NanoVDB bytes, .nvdb file bytes), the volume's error against
the exact field (``gof_warp.rendering.opacity_field``) at random points near the surface (within a voxel of stored voxels
whose value lies in [0.1, 0.9], inside the baked box), and the query throughput of a user kernel (points/s:
uniform in the volume's box, and near the surface). Writes one JSON object with the machine named (device,
warp/torch versions).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

import torch  # noqa: E402
import warp as wp  # noqa: E402

from gof_warp.core.devices import resolve_device, warp_device  # noqa: E402
from gof_warp.core.errors import GofError  # noqa: E402
from gof_warp.rendering.opacity_field import opacity_field  # noqa: E402
from gof_warp.training.run_folder import load_run  # noqa: E402
from gof_warp.mesh.volume import bake_opacity_volume, load_volume, sample_volume, save_volume  # noqa: E402


@wp.kernel
def query(volume: wp.uint64, points: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    """The user kernel timed: a trilinear opacity sample at a world point."""
    t = wp.tid()
    out[t] = wp.volume_sample_f(volume, wp.volume_world_to_index(volume, points[t]), wp.Volume.LINEAR)


def throughput(vol: wp.Volume, points: np.ndarray, repeats: int) -> float:
    """Points per second of :func:`query` (after one warm-up launch)."""
    dev = vol.device
    pts = wp.array(points.astype(np.float32), dtype=wp.vec3, device=dev)
    out = wp.zeros(len(points), dtype=float, device=dev)
    wp.launch(query, dim=len(points), inputs=[vol.id, pts], outputs=[out], device=dev)
    wp.synchronize_device(dev)
    t0 = time.perf_counter()
    for _ in range(repeats):
        wp.launch(query, dim=len(points), inputs=[vol.id, pts], outputs=[out], device=dev)
    wp.synchronize_device(dev)
    return len(points) * repeats / (time.perf_counter() - t0)


def near_surface_points(vol: wp.Volume, info: dict, n: int, rng) -> np.ndarray:
    """``[n, 3]`` points within a voxel of stored voxels whose value is in [0.1, 0.9] (the surface's band), kept
    inside the baked box."""
    ijk = vol.get_voxels().numpy()
    h = info["voxel_size"]
    centres = np.asarray(info["origin"]) + h * ijk.astype(np.float64)
    vals = sample_volume(vol, centres)
    band = centres[(vals > 0.1) & (vals < 0.9)]
    if len(band) == 0:
        band = centres
    pts = band[rng.integers(0, len(band), n)] + rng.uniform(-h, h, size=(n, 3))
    return np.clip(pts, info["bounds_min"], info["bounds_max"])  # the baked box: outside it the volume is empty


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", help="run folder or Gaussian PLY")
    parser.add_argument("--scene", default=None, help="the scene folder (cameras) when RUN is a PLY")
    parser.add_argument("--voxel-size", type=float, default=None)
    parser.add_argument("--band", type=int, default=4)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--points", type=int, default=None, help="query points (default 16M on CUDA, 1M on CPU)")
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--error-samples", type=int, default=200_000)
    parser.add_argument("--nvdb", default=None, help="where to write the volume (default: beside --out)")
    parser.add_argument("--out", default="bake_volume.json")
    args = parser.parse_args(argv)
    device = resolve_device(args.device)
    gaussians, cameras, _, render_config = load_run(Path(args.run), args.scene, device)
    wdev = warp_device(device)
    try:  # compile the kernels before timing
        bake_opacity_volume(gaussians.subset(torch.arange(min(len(gaussians), 64), device=gaussians.device)),
                            cameras[:2], render_config=render_config)
    except GofError:
        pass
    vol, info = bake_opacity_volume(gaussians, cameras, voxel_size=args.voxel_size, band=args.band,
                                    render_config=render_config)
    out = Path(args.out)
    nvdb = save_volume(vol, args.nvdb or out.with_suffix(".nvdb"))
    t0 = time.perf_counter()
    loaded = load_volume(nvdb, device=wdev)
    load_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    near = near_surface_points(loaded, info, args.error_samples, rng)
    exact = opacity_field(gaussians, cameras, near, render_config=render_config).cpu().numpy()
    err = np.abs(sample_volume(loaded, near) - exact)
    n_pts = args.points or ((1 << 24) if wdev.startswith("cuda") else (1 << 20))
    lo, hi = np.asarray(info["bounds_min"]), np.asarray(info["bounds_max"])
    result = {
        "run": str(args.run), "machine": {
            "device": wp.get_device(wdev).name, "warp_device": wdev, "platform": platform.platform(),
            "python": platform.python_version(), "warp": wp.config.version, "torch": torch.__version__},
        "n_gaussians": len(gaussians), "n_cameras": len(cameras), "bake": info,
        "nvdb": str(nvdb), "file_bytes": nvdb.stat().st_size, "load_s": load_s,
        "error_near_surface": {"samples": len(near), "mean": float(err.mean()),
                               "p95": float(np.percentile(err, 95)), "max": float(err.max())},
        "query": {"points": n_pts, "repeats": args.repeats,
                  "uniform_points_per_s": throughput(loaded, rng.uniform(lo, hi, size=(n_pts, 3)), args.repeats),
                  "near_surface_points_per_s": throughput(loaded, near_surface_points(loaded, info, n_pts, rng),
                                                          args.repeats)},
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"baked {info['active_voxels']:,} voxels of {info['voxel_size']:.4g} in {info['time_s']['total']:.2f} s, "
          f"{info['bytes'] / 1e6:.1f} MB; error near the surface mean {err.mean():.3f} p95 "
          f"{np.percentile(err, 95):.3f} max {err.max():.3f}; query {result['query']['uniform_points_per_s']:.3g} "
          f"points/s (uniform), {result['query']['near_surface_points_per_s']:.3g} (near the surface) on "
          f"{result['machine']['device']}; wrote {out}")
    return result


if __name__ == "__main__":
    main()
