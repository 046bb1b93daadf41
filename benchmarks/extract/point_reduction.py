"""What does reducing the tetrahedral grid's points cost in mesh accuracy? (issue 5)

Extracts a mesh with ``--method tetra`` from one trained model under several point reductions
(``TetraConfig.opacity_min``, ``TetraConfig.corner_min_extent`` as a fraction of the scene size, both)
and scores each against the scene's ``gt_mesh.ply`` (``gof_warp.geometry_metrics.evaluate_mesh``,
default thresholds: τ = 0.5 % and 1 % of the GT diagonal). Writes JSON and prints a Markdown table.

The model: ``--run RUN`` (a training output folder; the GT is ``RUN/scene/gt_mesh.ply`` or ``--gt``), or
else a synthetic ``default`` scene is rendered and trained with the ``quick`` preset into ``--work``.

    python benchmarks/extract/point_reduction.py --run /tmp/run --binary-steps 0 \
        --machine "2-core CPU dev box" --out benchmarks/extract/results_point_reduction_cpu.json
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

from gof_warp.extract import MeshConfig, StageTimer, extract_mesh, load_run
from gof_warp.geometry_metrics import evaluate_mesh
from gof_warp.io_utils import write_json_atomic
from gof_warp.tetra import TetraConfig
from gof_warp.tsdf import gaussian_bounds

# (name, opacity_min, corner_min_extent as a fraction of the scene's diagonal)
SETTINGS = {
    "none": (None, None),
    "opacity>=0.05": (0.05, None),
    "opacity>=0.1": (0.1, None),
    "opacity>=0.2": (0.2, None),
    "corner<2.5%": (None, 0.025),
    "corner<3.5%": (None, 0.035),
    "corner<5%": (None, 0.05),
    "opacity>=0.1+corner<2.5%": (0.1, 0.025),
    "opacity>=0.1+corner<3.5%": (0.1, 0.035),
    "opacity>=0.2+corner<3.5%": (0.2, 0.035),
    "opacity>=0.2+corner<5%": (0.2, 0.05),
}


def scene_diagonal(gaussians) -> float:
    """Diagonal of the robust box of the Gaussians (as the TSDF/cubes bounds use, unpadded)."""
    box = gaussian_bounds(gaussians.means.detach().cpu().numpy(), 0.5, 0.0)
    return float(np.linalg.norm(box[3:] - box[:3]))


def train_synthetic(work: Path, iterations: int, resolution: int, device: str) -> tuple[Path, Path]:
    """Render the ``default`` synthetic scene and train it with the quick preset; ``(run, gt_mesh)``."""
    from gof_warp.data import load_scene
    from gof_warp.synthetic import make_scene
    from gof_warp.train import resolve_config
    from gof_warp.trainer import Trainer

    scene_dir = make_scene("default", work / "scene", resolution=(resolution, resolution), force=True)
    run = work / "run"
    trainer = Trainer(load_scene(scene_dir), resolve_config("quick", [], iterations), run, device)
    trainer.run()
    return run, scene_dir / "gt_mesh.ply"


def study(run: Path, gt: Path, names: list[str], binary_steps: int, device: str) -> dict:
    gaussians, cameras, _, render_config = load_run(run, None, device)
    diag = scene_diagonal(gaussians)
    rows = []
    for name in names:
        opacity_min, frac = SETTINGS[name]
        tetra = TetraConfig(grid="delaunay", opacity_min=opacity_min,
                            corner_min_extent=None if frac is None else frac * diag)
        timer = StageTimer(gaussians.device)
        t0 = time.perf_counter()
        (verts, faces), = extract_mesh(gaussians, cameras, MeshConfig(binary_steps=binary_steps, tetra=tetra),
                                       render_config=render_config, timer=timer)
        total = time.perf_counter() - t0
        import trimesh

        metrics = evaluate_mesh(trimesh.Trimesh(verts, faces, process=False), str(gt))["metrics"]
        rows.append({"setting": name, "opacity_min": opacity_min, "corner_min_extent_fraction": frac,
                     "corner_min_extent": tetra.corner_min_extent, **timer.stages["counts"],
                     "delaunay_s": timer.stages["tetra_points+delaunay"]["substages_s"]["delaunay"],
                     "total_s": round(total, 3), "stages": timer.stages,
                     "vertices": len(verts), "faces": len(faces),
                     "chamfer": metrics["chamfer"], "accuracy": metrics["accuracy"],
                     "completeness": metrics["completeness"], "tau": metrics["tau"], "fscore": metrics["fscore"]})
        r = rows[-1]
        print(f"{name}: {r['points']} points, {r['tetrahedra']} tets, {total:.1f} s, chamfer {r['chamfer']:.5f}, "
              f"F {r['fscore']}", flush=True)
    return {"run": str(run), "gt": str(gt), "num_gaussians": len(gaussians), "num_views": len(cameras),
            "scene_diagonal": diag, "binary_steps": binary_steps, "device": device, "rows": rows}


def markdown(result: dict) -> str:
    base = result["rows"][0]
    lines = ["| setting | points | tets | Delaunay | total | Chamfer | F@0.5% | F@1% | ΔF@0.5% |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        lines.append(f"| {r['setting']} | {r['points']:,} ({r['points'] / base['points']:.0%}) | {r['tetrahedra']:,} | "
                     f"{r['delaunay_s']:.2f} s | {r['total_s']:.1f} s | {r['chamfer']:.5f} | {r['fscore'][0]:.4f} | "
                     f"{r['fscore'][1]:.4f} | {r['fscore'][0] - base['fscore'][0]:+.4f} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", type=Path, default=None, help="trained run folder (else train a synthetic scene)")
    ap.add_argument("--gt", type=Path, default=None, help="GT mesh (default RUN/scene/gt_mesh.ply)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/gof_point_reduction"))
    ap.add_argument("--iterations", type=int, default=1200)
    ap.add_argument("--resolution", type=int, default=96)
    ap.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--binary-steps", type=int, default=0, help="GOF uses 8 (costly on CPU: 8 field calls)")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--machine", default=platform.node())
    ap.add_argument("--out", type=Path, default=Path("point_reduction.json"))
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    if a.run is None:
        run, gt = train_synthetic(a.work, a.iterations, a.resolution, a.device)
    else:
        run, gt = a.run, a.gt or a.run / "scene" / "gt_mesh.ply"
    result = study(run, gt, a.settings, a.binary_steps, a.device)
    result["machine"] = a.machine
    result["versions"] = {"torch": torch.__version__, "numpy": np.__version__, "python": platform.python_version()}
    write_json_atomic(a.out, result)
    print(markdown(result))
    print(json.dumps({"wrote": str(a.out)}))


if __name__ == "__main__":
    main()
