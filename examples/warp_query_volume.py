"""Query a baked GOF opacity volume (NanoVDB ``.nvdb``) at arbitrary points inside your own Warp kernel.

Bake one from a trained run with ``python -m gof_warp.extract RUN --volume`` (or
``gof_warp.mesh.volume.bake_run``); this program needs only Warp and numpy (no torch, no gof_warp):

    python examples/warp_query_volume.py --nvdb RUN/opacity_volume.nvdb --points 1000000

Without ``--nvdb`` it builds a stand-in volume (a smooth opacity of a ground plane and a sphere) so that it
runs anywhere. Prints the volume's size, the fraction of occupied points and the query throughput.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import warp as wp

LEVEL = 0.5  # GOF's surface level: opacity >= LEVEL is "inside"


@wp.func
def opacity_at(volume: wp.uint64, x: wp.vec3) -> float:
    """Trilinear opacity at world point ``x`` (0 outside the stored band)."""
    return wp.volume_sample_f(volume, wp.volume_world_to_index(volume, x), wp.Volume.LINEAR)


@wp.kernel
def occupancy_query(volume: wp.uint64, points: wp.array(dtype=wp.vec3), level: float,
                    opacity: wp.array(dtype=float), inside: wp.array(dtype=wp.int32)):
    """A user kernel: the opacity at each point and whether it is inside the scene's surface."""
    t = wp.tid()
    o = opacity_at(volume, points[t])
    opacity[t] = o
    inside[t] = wp.where(o >= level, 1, 0)


@wp.kernel
def _fill_stand_in(volume: wp.uint64, voxels: wp.array(dtype=wp.vec3i), centre: wp.vec3, radius: float,
                   width: float):
    """Smooth opacity of {z <= 0} ∪ sphere: 0.5 on the surface, 0 → 1 across ``width``."""
    t = wp.tid()
    c = voxels[t]
    x = wp.volume_index_to_world(volume, wp.vec3(float(c[0]), float(c[1]), float(c[2])))
    sdf = wp.min(x[2], wp.length(x - centre) - radius)
    wp.volume_store_f(volume, c[0], c[1], c[2], wp.clamp(0.5 - sdf / width, 0.0, 1.0))


def stand_in_volume(device, voxel_size: float = 0.04) -> wp.Volume:
    """A small dense stand-in for a baked volume: ground z = 0 and a sphere (centre (0, 0, 0.45), r 0.3)."""
    vol = wp.Volume.allocate(min=[-1.0, -1.0, -0.3], max=[1.0, 1.0, 1.0], voxel_size=voxel_size, bg_value=0.0,
                             points_in_world_space=True, translation=(0.0, 0.0, 0.0), device=device)
    voxels = vol.get_voxels()
    wp.launch(_fill_stand_in, dim=voxels.shape[0], device=device,
              inputs=[vol.id, wp.array(voxels.numpy(), dtype=wp.vec3i, device=device), wp.vec3(0.0, 0.0, 0.45), 0.3,
                      4.0 * voxel_size])
    return vol


def world_bounds(vol: wp.Volume) -> tuple[np.ndarray, np.ndarray]:
    """World box ``(lo [3], hi [3])`` of the volume's active voxels (corners of the index box mapped)."""
    ijk = vol.get_voxels().numpy().astype(np.float64)
    info = vol.get_grid_info()
    m = np.array(info.transform_matrix, dtype=np.float64).reshape(3, 3)
    tr = np.array(info.translation, dtype=np.float64)
    corners = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], dtype=np.float64)
    box = ijk.min(0) + corners * (ijk.max(0) - ijk.min(0))
    world = box @ m.T + tr
    return world.min(0), world.max(0)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda" if wp.is_cuda_available() else "cpu")
    parser.add_argument("--nvdb", default=None, help="a baked opacity volume (.nvdb); default: a stand-in")
    parser.add_argument("--points", type=int, default=1 << 18, help="query points per launch")
    parser.add_argument("--repeats", type=int, default=5, help="timed launches")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    wp.init()
    if args.nvdb:
        with open(args.nvdb, "rb") as f:
            vol = wp.Volume.load_from_nvdb(f, device=args.device)
        source = args.nvdb
    else:
        vol = stand_in_volume(args.device)
        source = "stand-in (ground + sphere)"
    lo, hi = world_bounds(vol)
    rng = np.random.default_rng(args.seed)
    pts = wp.array(rng.uniform(lo, hi, size=(args.points, 3)).astype(np.float32), dtype=wp.vec3, device=args.device)
    opacity = wp.zeros(args.points, dtype=float, device=args.device)
    inside = wp.zeros(args.points, dtype=wp.int32, device=args.device)
    launch = dict(dim=args.points, device=args.device, inputs=[vol.id, pts, LEVEL], outputs=[opacity, inside])
    wp.launch(occupancy_query, **launch)  # compile + warm up
    wp.synchronize_device(args.device)
    t0 = time.perf_counter()
    for _ in range(args.repeats):
        wp.launch(occupancy_query, **launch)
    wp.synchronize_device(args.device)
    seconds = (time.perf_counter() - t0) / args.repeats
    o = opacity.numpy()
    result = {
        "source": source, "device": str(args.device), "voxel_size": list(vol.get_voxel_size()),
        "active_voxels": int(vol.get_voxel_count()), "bytes": int(vol.array().shape[0]),
        "bounds_min": lo.tolist(), "bounds_max": hi.tolist(), "points": args.points,
        "inside_fraction": float(inside.numpy().mean()), "opacity_mean": float(o.mean()),
        "seconds_per_launch": seconds, "points_per_second": args.points / seconds,
    }
    print(f"volume: {source}: {result['active_voxels']:,} voxels of {result['voxel_size'][0]:.4g}, "
          f"{result['bytes'] / 1e6:.2f} MB, box {np.round(lo, 3).tolist()} .. {np.round(hi, 3).tolist()}")
    print(f"queried {args.points:,} points: {100 * result['inside_fraction']:.1f}% inside (opacity >= {LEVEL}), "
          f"mean opacity {result['opacity_mean']:.3f}")
    print(f"throughput: {result['points_per_second']:.4g} points/s ({1e3 * seconds:.3f} ms per launch on "
          f"{args.device})")
    print(f"torch imported: {'torch' in sys.modules}")
    return result


if __name__ == "__main__":
    main()
