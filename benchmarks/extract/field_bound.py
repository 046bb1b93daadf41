"""What bounding each view's walk by the running minimum saves in the opacity field (bit-identical by construction).

``opacity_min_over_view`` stops a view's front-to-back compositing once its opacity reaches the minimum of the views
before it; ``opacity_min_over_view_whole`` walks every list to its end (the field before this change). Both run
here on the same model, cameras and points, one after the other, each timed over ``--repeats`` calls after one
untimed call (compilation), and their outputs are compared bit for bit.

Point sets, as extraction evaluates them:
- ``grid``: the tetrahedral grid's points (centres and 3σ box corners of every Gaussian, in some view's frustum);
- ``surface``: the vertices of ``RUN/mesh_tetra.ply`` moved by ±0.5 % of the model's extent along random
  directions — where the binary search evaluates the field (every point near the 0.5 level).

    python benchmarks/extract/field_bound.py RUN [--scene SCENE] [--max-points N] --machine "1x H200" --out F.json
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch
import warp as wp

from gof_warp import kernels as K
from gof_warp.devices import warp_device
from gof_warp.io_utils import write_json_atomic
from gof_warp.opacity_field import _min_over_views, _view_inputs
from gof_warp.run_folder import load_run
from gof_warp.tetra import TetraConfig, grid_points


def _timed(arrays, views, pts: wp.array, kernel, repeats: int):
    """``(field, seen, seconds per call)``: one untimed call, then the median of ``repeats`` timed ones."""
    times = []
    for r in range(repeats + 1):
        field = wp.ones(pts.shape[0], dtype=float, device=pts.device)
        seen = wp.zeros(pts.shape[0], dtype=wp.int32, device=pts.device)
        wp.synchronize_device(pts.device)
        t0 = time.perf_counter()
        _min_over_views(arrays, views, pts, field, seen, kernel=kernel)
        wp.synchronize_device(pts.device)
        if r:
            times.append(time.perf_counter() - t0)
    return field.numpy(), seen.numpy(), float(np.median(times))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run")
    ap.add_argument("--scene", default=None, help="scene folder when RUN is a PLY")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--max-points", type=int, default=2_000_000, help="random subset of each point set")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--machine", default=platform.node())
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    wp.init()
    gaussians, cameras, _, render_config = load_run(Path(a.run), a.scene, a.device)
    rng = np.random.default_rng(0)
    sets = {}
    grid, _, _ = grid_points(gaussians.means.detach(), gaussians.rotations.detach(), gaussians.scales.detach(),
                             gaussians.opacities.detach(), cameras, TetraConfig())
    sets["grid"] = np.asarray(grid)
    mesh = (Path(a.run) / "mesh_tetra.ply") if Path(a.run).is_dir() else None
    if mesh is not None and mesh.is_file():
        import trimesh

        v = np.asarray(trimesh.load(mesh, process=False).vertices, np.float64)
        extent = float(np.linalg.norm(np.ptp(gaussians.means.cpu().numpy(), axis=0)))
        d = rng.normal(size=v.shape)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        sets["surface"] = v + 0.005 * extent * rng.uniform(-1, 1, (len(v), 1)) * d
    arrays, views = _view_inputs(gaussians, cameras, render_config)
    rows = {}
    for name, p in sets.items():
        if len(p) > a.max_points:
            p = p[rng.choice(len(p), a.max_points, replace=False)]
        pts = wp.array(np.ascontiguousarray(p, np.float32), dtype=wp.vec3, device=warp_device(gaussians.device))
        f_w, s_w, t_w = _timed(arrays, views, pts, K.opacity_min_over_view_whole, a.repeats)
        f_b, s_b, t_b = _timed(arrays, views, pts, K.opacity_min_over_view, a.repeats)
        rows[name] = {"points": int(len(p)), "whole_walk_s": round(t_w, 4), "bounded_s": round(t_b, 4),
                      "speedup": round(t_w / t_b, 2), "bit_identical": bool(np.array_equal(f_w, f_b)
                                                                             and np.array_equal(s_w, s_b)),
                      "field_between_0.05_0.95": int(((f_b > 0.05) & (f_b < 0.95)).sum())}
        print(name, rows[name], flush=True)
    result = {"machine": a.machine, "device": str(gaussians.device), "gpu": torch.cuda.get_device_name()
              if gaussians.device.type == "cuda" else None, "warp": wp.config.version, "run": a.run,
              "gaussians": len(gaussians), "views": len(views), "sets": rows}
    if a.out:
        write_json_atomic(Path(a.out), result)
    else:
        print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
