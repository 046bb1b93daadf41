"""Collision mesh (gof_warp.mesh.collision) of a trained run, checked and scored against the exact geometry.

    python benchmarks/collision/bench_collision.py RUN [--out benchmarks/collision/results.json]
        [--resolution 128 ...] [--faces 20000]

RUN: a training output folder of a built-in synthetic scene (``python -m gof_warp.train --out RUN``: its
``RUN/scene/gt_mesh.ply`` is the exact mesh). For every (resolution, face budget) pair: the time of the field and of
the meshing, trimesh's closedness checks, the enclosed volume against the exact mesh's, the volumetric IoU with the
exact solid (inside tests of the cell centres of a 160^3 grid over both meshes' box), the surface distances
(gof_warp.eval.geometry_metrics: accuracy, completeness, Chamfer, F-score) and the signed offset of the vertices
from the exact surface (negative: inside the exact solid). The extraction's own mesh of the run
(RUN/mesh_tetra.ply, when present) is checked the same way for comparison.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import trimesh

from gof_warp.core.io_utils import write_json_atomic
from gof_warp.eval.geometry_metrics import evaluate_mesh
from gof_warp.mesh.collision import CollisionConfig, closed_report, collision_mesh
from gof_warp.training.run_folder import load_run


def inside_grid(mesh: trimesh.Trimesh, lo, hi, n: int) -> np.ndarray:
    """``[n, n, n]`` bool: which cell centres of the box ``lo``-``hi`` a closed mesh encloses, by the parity of the
    crossings of a +z line through each (x, y) column (exact line-triangle intersections, no acceleration
    structure needed)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    step = (hi - lo) / n
    cx = lo[0] + (np.arange(n) + 0.5) * step[0]
    cy = lo[1] + (np.arange(n) + 0.5) * step[1]
    cz = lo[2] + (np.arange(n) + 0.5) * step[2]
    tri = np.asarray(mesh.vertices, float)[np.asarray(mesh.faces)]
    i0 = np.clip(np.ceil((tri[:, :, 0].min(1) - lo[0]) / step[0] - 0.5), 0, n).astype(int)
    i1 = np.clip(np.floor((tri[:, :, 0].max(1) - lo[0]) / step[0] - 0.5), -1, n - 1).astype(int)
    j0 = np.clip(np.ceil((tri[:, :, 1].min(1) - lo[1]) / step[1] - 0.5), 0, n).astype(int)
    j1 = np.clip(np.floor((tri[:, :, 1].max(1) - lo[1]) / step[1] - 0.5), -1, n - 1).astype(int)
    ni, nj = np.maximum(0, i1 - i0 + 1), np.maximum(0, j1 - j0 + 1)
    count = ni * nj
    t = np.repeat(np.arange(len(tri)), count)
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    ii, jj = i0[t] + k // np.maximum(nj[t], 1), j0[t] + k % np.maximum(nj[t], 1)
    px, py = cx[ii], cy[jj]
    a, b, c = tri[t, 0], tri[t, 1], tri[t, 2]
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = np.abs(det) > 1e-300
    u = ((px - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (py - a[:, 1])) / np.where(ok, det, 1)
    w = ((b[:, 0] - a[:, 0]) * (py - a[:, 1]) - (px - a[:, 0]) * (b[:, 1] - a[:, 1])) / np.where(ok, det, 1)
    hit = ok & (u >= 0) & (w >= 0) & (u + w < 1)
    z = a[:, 2] + u * (b[:, 2] - a[:, 2]) + w * (c[:, 2] - a[:, 2])
    col = (ii * n + jj)[hit]
    z = z[hit]
    # crossings below each cell centre, per column: parity says inside
    below = np.zeros((n * n, n), np.int32)
    kz = np.clip(np.floor((z - lo[2]) / step[2] + 0.5), 0, n).astype(int)  # first centre above the crossing
    np.add.at(below, (col[kz < n], kz[kz < n]), 1)
    return (np.cumsum(below, 1) % 2 == 1).reshape(n, n, n)


def volume_iou(a: trimesh.Trimesh, b: trimesh.Trimesh, n: int = 160) -> float:
    lo = np.minimum(a.bounds[0], b.bounds[0]) - 1e-3
    hi = np.maximum(a.bounds[1], b.bounds[1]) + 1e-3 * np.pi  # cell centres off any grid-aligned surface
    ia, ib = inside_grid(a, lo, hi, n), inside_grid(b, lo, hi, n)
    return float((ia & ib).sum() / max(1, (ia | ib).sum()))


def winding_numbers(points: np.ndarray, mesh: trimesh.Trimesh, chunk: int = 100) -> np.ndarray:
    """Generalised winding number of ``points [P, 3]`` in a closed mesh (1 inside, 0 outside): the triangles' solid
    angles (Van Oosterom and Strackee) summed over 4 pi, brute force in float64."""
    tri = np.asarray(mesh.vertices, np.float64)[np.asarray(mesh.faces)]
    out = np.zeros(len(points))
    for i in range(0, len(points), chunk):
        q = np.asarray(points[i:i + chunk], np.float64)[:, None, :]
        a, b, c = (tri[None, :, k, :] - q for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=-1) for x in (a, b, c))
        num = np.einsum("pij,pij->pi", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pij,pij->pi", a, b) * lc + np.einsum("pij,pij->pi", b, c) * la
               + np.einsum("pij,pij->pi", c, a) * lb)
        out[i:i + chunk] = 2.0 * np.arctan2(num, den).sum(1) / (4.0 * np.pi)
    return out


def signed_offset(v, gt: trimesh.Trimesh, n: int = 3000, seed: int = 0) -> dict:
    """Where a mesh's vertices lie against the exact surface: distance, negative inside the exact solid (a seeded
    sample of ``n`` vertices)."""
    from gof_warp.eval.geometry_metrics import point_mesh_distance

    v = np.asarray(v, np.float64)
    p = v[np.random.default_rng(seed).choice(len(v), min(n, len(v)), replace=False)]
    d = point_mesh_distance(p, np.asarray(gt.vertices), np.asarray(gt.faces))
    s = np.where(winding_numbers(p, gt) > 0.5, -d, d)
    return {"mean": round(float(s.mean()), 6), "median": round(float(np.median(s)), 6),
            "inside_fraction": round(float((s < 0).mean()), 4), "vertices_sampled": int(len(p))}


def score(v, f, gt: trimesh.Trimesh) -> dict:
    m = trimesh.Trimesh(np.asarray(v, np.float64), np.asarray(f), process=False)
    check = closed_report(v, f)
    out = {"check": check, "volume_ratio_to_exact": round(check["volume"] / gt.volume, 4)}
    if check["is_volume"]:
        out["volume_iou_with_exact"] = round(volume_iou(m, gt), 4)
    metrics = evaluate_mesh(m, gt)["metrics"]
    out["surface"] = {k: metrics[k] for k in ("accuracy", "completeness", "chamfer", "fscore", "tau") if k in metrics}
    out["signed_offset_to_exact"] = signed_offset(v, gt)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("run")
    ap.add_argument("--out", default=str(Path(__file__).with_name("results_default_scene_cpu.json")))
    ap.add_argument("--resolution", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--faces", type=int, nargs="+", default=[20_000])
    ap.add_argument("--coarse-factor", type=int, default=4)
    ap.add_argument("--gt", default=None, help="the exact mesh (default: RUN/scene/gt_mesh.ply)")
    a = ap.parse_args()
    run = Path(a.run)
    gaussians, cameras, _, render_config = load_run(run, None, "cpu")
    gt = trimesh.load(a.gt or run / "scene" / "gt_mesh.ply", process=False)
    result = {"run": str(run), "machine": "2-core CPU dev box (shared with other jobs, so timings are upper bounds)",
              "python": platform.python_version(), "gaussians": len(gaussians), "views": len(cameras),
              "exact_volume": gt.volume, "exact_closed": bool(gt.is_volume), "runs": []}
    extracted = run / "mesh_tetra.ply"
    if extracted.is_file():
        m = trimesh.load(extracted, process=False)
        result["extraction_mesh"] = {"path": str(extracted), **score(m.vertices, m.faces, gt)}
    for res in a.resolution:
        for faces in a.faces:
            cfg = CollisionConfig(resolution=res, max_faces=faces, coarse_factor=a.coarse_factor)
            t0 = time.perf_counter()
            v, f, info = collision_mesh(gaussians, cameras, cfg, render_config=render_config)
            wall = time.perf_counter() - t0
            entry = {"resolution": res, "max_faces": faces, "coarse_factor": a.coarse_factor,
                     "wall_s": round(wall, 2), "time_s": info["time_s"], "route": info["route"],
                     "marching_cubes_faces": info["marching_cubes_faces"], "pieces": info["pieces"],
                     "decimate": info.get("decimate"),
                     "sampling": info["sampling"], "grid": info["grid"], **score(v, f, gt)}
            print(json.dumps(entry))
            result["runs"].append(entry)
            write_json_atomic(a.out, result)


if __name__ == "__main__":
    main()
