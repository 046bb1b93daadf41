"""TSDF marching cubes + binary search: trilinear samples in Warp on the grid's device (now) vs numpy on
the host (before), on an analytic sphere TSDF of ``R³`` voxels.

    python benchmarks/extract/bench_tsdf_search.py --resolution 128 256 --device cpu \
        --out benchmarks/extract/results_tsdf_search_cpu.json
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from gof_warp.io_utils import write_json_atomic
from gof_warp.marching import marching_cubes
from gof_warp.tsdf import TSDFVolume, extract_tsdf_mesh

TRUNC_VOXELS = 4.0


def sphere_volume(res: int) -> TSDFVolume:
    """TSDF of a sphere of radius 0.6 in ``[-1, 1]³``, truncated at ``TRUNC_VOXELS`` voxels, all observed."""
    voxel = 2.0 / (res - 1)
    x = np.linspace(-1, 1, res, dtype=np.float32)
    r = np.sqrt(x[:, None, None] ** 2 + x[None, :, None] ** 2 + x[None, None, :] ** 2)
    tsdf = np.clip((r - 0.6) / (TRUNC_VOXELS * voxel), -1, 1).astype(np.float32)
    return TSDFVolume(tsdf, np.ones_like(tsdf), np.zeros(tsdf.shape + (3,), np.float32), np.full(3, -1.0), voxel)


def host_numpy_search(volume: TSDFVolume, *, binary_steps: int, device: str):
    """The previous path: the field is ``TSDFVolume.sample`` in float64 numpy on the host."""
    grid = -volume.tsdf
    res = np.array(volume.tsdf.shape)
    bounds = np.stack([volume.origin, volume.origin + volume.voxel_size * (res - 1)])
    return marching_cubes(lambda p: volume.sample(np.asarray(p, np.float64), grid).astype(np.float32), bounds,
                          tuple(int(r) for r in res), level=0.0, binary_steps=binary_steps, device=device)


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, round(time.perf_counter() - t0, 3)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=int, nargs="+", default=[128])
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--machine", default="")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    rows = []
    for res in a.resolution:
        vol = sphere_volume(res)
        row = {"resolution": res, "steps": a.steps}
        for name, fn, steps in (("host_numpy", host_numpy_search, a.steps), ("host_numpy_0_steps", host_numpy_search, 0),
                                ("warp", extract_tsdf_mesh, a.steps), ("warp_0_steps", extract_tsdf_mesh, 0)):
            out, row[f"{name}_s"] = timed(lambda: fn(vol, binary_steps=steps, device=a.device))  # noqa: B023
            row[f"{name}_radius_err_max"] = float(np.abs(np.linalg.norm(out[0], axis=1) - 0.6).max())
            row["vertices"] = len(out[0])
        rows.append(row)
        print(row, flush=True)
    if a.out:
        write_json_atomic(a.out, {"machine": a.machine, "device": a.device, "rows": rows})


if __name__ == "__main__":
    main()
