"""Mesh of a run's baked opacity volume (gof_warp.mesh.volume_mesh) vs its tetra mesh, both against the ground truth.

    python benchmarks/warp_embedding/volume_vs_tetra.py RUN [--out JSON] [--tetra RUN/mesh_full.ply]
        [--gt RUN/scene/gt_mesh.ply] [--nvdb RUN/opacity_volume.nvdb] [--binary-steps 4] [--save-mesh PLY]

Needs ``RUN/opacity_volume.nvdb`` + ``.json`` (``python -m gof_warp.extract RUN --volume``) and a tetra mesh.
Writes one JSON: per mesh its Chamfer / F-score against the GT (``gof_warp.eval.geometry_metrics.evaluate_mesh``, the
GT's default density, max_dist and tau, so both are scored alike), the Chamfer between the two meshes (same
parameters, tetra mesh as the reference), the relative gap ``(C_volume − C_tetra) / C_tetra``, the voxel size,
the volume's bytes and the times.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from gof_warp.eval.geometry_metrics import default_eval_params, evaluate_mesh, load_geometry  # noqa: E402
from gof_warp.mesh.volume import load_volume  # noqa: E402
from gof_warp.mesh.volume_mesh import volume_mesh  # noqa: E402


def _summary(ev: dict) -> dict:
    m = ev["metrics"]
    return {k: m[k] for k in ("chamfer", "accuracy", "completeness", "tau", "precision", "recall", "fscore",
                              "pred_outlier_fraction", "gt_outlier_fraction")} | {
        "faces": ev["mesh_stats"]["faces"], "vertices": ev["mesh_stats"]["vertices"],
        "components": ev["mesh_stats"]["connected_components"], "watertight": ev["mesh_stats"]["watertight"]}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--tetra", type=Path)
    ap.add_argument("--gt", type=Path)
    ap.add_argument("--nvdb", type=Path)
    ap.add_argument("--binary-steps", type=int, default=4)
    ap.add_argument("--save-mesh", type=Path)
    ap.add_argument("--device", default="cpu", help="Warp device of the volume meshing (cpu, cuda:0)")
    ap.add_argument("--exact-search", action="store_true",
                    help="bisect on the run's exact opacity field instead of the volume's trilinear field")
    a = ap.parse_args(argv)
    nvdb = a.nvdb or a.run / "opacity_volume.nvdb"
    tetra_path, gt_path = a.tetra or a.run / "mesh_full.ply", a.gt or a.run / "scene" / "gt_mesh.ply"
    info = json.loads(nvdb.with_suffix(".json").read_text())
    t0 = time.perf_counter()
    vol = load_volume(nvdb, device=a.device)
    t_load = time.perf_counter() - t0
    exact = None
    if a.exact_search:
        from gof_warp.rendering.opacity_field import opacity_field
        from gof_warp.training.run_folder import load_run

        g, cams, _, render_config = load_run(a.run, None, "cuda" if a.device.startswith("cuda") else "cpu")
        exact = lambda x: opacity_field(g, cams, x, render_config=render_config).cpu().numpy()  # noqa: E731
    t0 = time.perf_counter()
    verts, faces = volume_mesh(vol, info, binary_steps=a.binary_steps, exact_field=exact)
    t_mesh = time.perf_counter() - t0
    vmesh = trimesh.Trimesh(verts, faces, process=False)
    if a.save_mesh:
        vmesh.export(a.save_mesh)
    gt, tetra = load_geometry(gt_path), load_geometry(tetra_path)
    p = default_eval_params(gt)
    kw = dict(tau=p["tau"], density=p["density"], max_dist=p["max_dist"])
    t0 = time.perf_counter()
    ev_v, ev_t = evaluate_mesh(vmesh, gt, **kw), evaluate_mesh(tetra, gt, **kw)
    between = evaluate_mesh(vmesh, tetra, **kw)
    t_eval = time.perf_counter() - t0
    cv, ct = ev_v["metrics"]["chamfer"], ev_t["metrics"]["chamfer"]
    result = {
        "run": str(a.run), "nvdb": str(nvdb), "tetra_mesh": str(tetra_path), "gt": str(gt_path),
        "device": a.device, "cpu_cores": __import__("os").cpu_count(), "platform": platform.platform(),
        "voxel_size": info["voxel_size"], "volume_bytes": info["bytes"], "active_voxels": info["active_voxels"],
        "bake_time_s": info["time_s"]["total"], "binary_steps": a.binary_steps, "exact_search": a.exact_search,
        "eval_params": {k: p[k] for k in ("density", "max_dist", "tau", "gt_diagonal")},
        "volume_mesh": _summary(ev_v) | {"time_s": t_mesh, "load_time_s": t_load},
        "tetra_mesh_vs_gt": _summary(ev_t),
        "chamfer_gap_relative": (cv - ct) / ct,
        "chamfer_volume_vs_tetra": between["metrics"]["chamfer"],
        "chamfer_volume_vs_tetra_over_gt_diagonal": between["metrics"]["chamfer"] / p["gt_diagonal"],
        "chamfer_volume_vs_tetra_over_voxel_size": between["metrics"]["chamfer"] / info["voxel_size"],
        "volume_vs_tetra": _summary(between),
        "eval_time_s": t_eval,
    }
    text = json.dumps(result, indent=2)
    if a.out:
        a.out.write_text(text + "\n")
    print(text)
    return result


if __name__ == "__main__":
    main()
