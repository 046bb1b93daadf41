"""The octree grid against the Delaunay grid: time, points, tetrahedra, faces and accuracy (issue 11).

Extracts ``--method tetra`` meshes from one trained run with ``grid=delaunay`` (the official grid; the reference)
and ``grid=octree`` at each ``--cell-factors``, all with the same opacity field and search steps. Each mesh is scored
against the exact mesh when the run's scene has one (``RUN/scene/gt_mesh.ply``, ``evaluate_mesh`` defaults) and
against the Delaunay grid's mesh (F-score at τ = 0.1 % and 0.5 % of that mesh's diagonal: the issue's bar is ≥ 0.995
at 0.1 %), and checked for open edges (edges with one face) and non-manifold edges (more than two).

    python benchmarks/extract/octree_study.py RUN --cell-factors 1 0.5 --binary-steps 4 \
        --machine "2-core CPU dev box" --out benchmarks/extract/results/octree_default_cpu.json
"""

from __future__ import annotations

import argparse
import json
import logging
import platform
import time
from pathlib import Path

import numpy as np
import torch
import trimesh

from gof_warp.extraction import MeshConfig, StageTimer, extract_mesh, save_mesh
from gof_warp.geometry_metrics import evaluate_mesh
from gof_warp.io_utils import write_json_atomic
from gof_warp.octree_tets import OctreeConfig
from gof_warp.run_folder import load_run
from gof_warp.tetra import TetraConfig


def edge_census(faces: np.ndarray) -> dict:
    """Edges used by one face (open), two (manifold) and more (non-manifold)."""
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, count = np.unique(e, axis=0, return_counts=True)
    return {"open_edges": int((count == 1).sum()), "nonmanifold_edges": int((count > 2).sum())}


def extract(gaussians, cameras, render_config, tetra: TetraConfig, steps: int) -> tuple[dict, trimesh.Trimesh]:
    timer = StageTimer(gaussians.device)
    t0 = time.perf_counter()
    (v, f), = extract_mesh(gaussians, cameras, MeshConfig(binary_steps=steps, tetra=tetra),
                           render_config=render_config, timer=timer)
    row = {"total_s": round(time.perf_counter() - t0, 3), **timer.stages.pop("counts"), "stages": timer.stages,
           "vertices": int(len(v)), "faces": int(len(f)), **edge_census(np.asarray(f))}
    return row, trimesh.Trimesh(v, f, process=False)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--scene", default=None, help="scene folder for the cameras when RUN is a PLY")
    ap.add_argument("--gt", type=Path, default=None, help="exact mesh (default RUN/scene/gt_mesh.ply when present)")
    ap.add_argument("--cell-factors", type=float, nargs="+", default=[1.0, 0.5])
    ap.add_argument("--depth", type=int, default=OctreeConfig.depth)
    ap.add_argument("--binary-steps", type=int, default=8)
    ap.add_argument("--no-delaunay", action="store_true", help="skip the reference (then no mesh-vs-mesh F-score)")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--machine", default=platform.node())
    ap.add_argument("--meshes", type=Path, default=None, help="folder to keep the meshes in")
    ap.add_argument("--out", type=Path, default=Path("octree_study.json"))
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    gaussians, cameras, _, render_config = load_run(a.run, a.scene, a.device)
    gt = a.gt or (a.run / "scene" / "gt_mesh.ply" if (a.run / "scene" / "gt_mesh.ply").exists() else None)
    settings = [] if a.no_delaunay else [("delaunay", TetraConfig(grid="delaunay"))]
    settings += [(f"octree x{c:g}", TetraConfig(grid="octree", octree=OctreeConfig(cell_factor=c, depth=a.depth)))
                 for c in a.cell_factors]
    rows, reference = [], None
    result = {"run": str(a.run), "gt": str(gt) if gt else None, "num_gaussians": len(gaussians),
              "num_views": len(cameras), "binary_steps": a.binary_steps, "device": a.device, "machine": a.machine,
              "versions": {"torch": torch.__version__, "python": platform.python_version()}, "rows": rows}
    for name, tetra in settings:
        row, mesh = extract(gaussians, cameras, render_config, tetra, a.binary_steps)
        row["setting"] = name
        if a.meshes:
            a.meshes.mkdir(parents=True, exist_ok=True)
            save_mesh(a.meshes / f"{name.replace(' ', '_')}.ply", mesh.vertices, mesh.faces)
        if gt is not None:
            m = evaluate_mesh(mesh, str(gt))["metrics"]
            row["vs_exact"] = {k: m[k] for k in ("chamfer", "accuracy", "completeness", "tau", "fscore")}
        if reference is None and name == "delaunay":
            reference = mesh
        elif reference is not None:
            diag = float(np.linalg.norm(reference.bounds[1] - reference.bounds[0]))
            m = evaluate_mesh(mesh, reference, tau=[0.001 * diag, 0.005 * diag])["metrics"]
            row["vs_delaunay"] = {"tau": m["tau"], "fscore": m["fscore"], "chamfer": m["chamfer"]}
        rows.append(row)
        write_json_atomic(a.out, result)  # after every row: a call that runs out of time keeps what it measured
        print(json.dumps({k: row[k] for k in row if k != "stages"}), flush=True)
    print(json.dumps({"wrote": str(a.out)}))


if __name__ == "__main__":
    main()
