"""How much of a mesh-vs-mesh F-score is the grid: the Delaunay grid (one Qhull call) against itself with its points
moved, and against the octree grid, all on one model's field.

    python benchmarks/extract/jitter_grid.py RUN --out DIR [--amps 0.001 0.05 0.2] [--binary-steps 4]

Every Delaunay point is moved by ``amp ×`` its 3σ extent times a standard normal vector (seeded), so the grid samples
the same field at other places; the field, the levels and the search are unchanged. Each mesh is scored against the
unmoved Delaunay mesh as the extraction issue asks (``compare_meshes.py``: F at 0.1 % and 0.5 % of the diagonal),
the Delaunay mesh against itself (the sampling floor), and, when the run folder holds the scene's exact mesh
(``scene/gt_mesh.ply``, the built-in synthetic scenes), every mesh against it with ``gof_warp.evaluate --scene``.
Writes ``DIR/jitter_grid.json``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

import numpy as np

import gof_warp.tetra as tetra
from gof_warp.evaluate import main as evaluate_main
from gof_warp.extract import main as extract_main

sys.path.insert(0, str(Path(__file__).resolve().parent))
from compare_meshes import main as compare_main  # noqa: E402


@contextlib.contextmanager
def moved_points(amp: float, seed: int):
    """``tetra.tetra_points`` with every point moved by ``amp ×`` its extent (``amp = 0``: unchanged)."""
    original = tetra.tetra_points

    def moved(*args, **kwargs):
        points, owner, scale = original(*args, **kwargs)
        step = np.random.default_rng(seed).standard_normal(points.shape) * (amp * scale)[:, None]
        return (points + step).astype(np.float32), owner, scale

    tetra.tetra_points = moved if amp > 0 else original
    try:
        yield
    finally:
        tetra.tetra_points = original


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--out", required=True)
    ap.add_argument("--amps", type=float, nargs="+", default=[0.001, 0.05, 0.2])
    ap.add_argument("--binary-steps", type=int, default=4)
    a = ap.parse_args()
    run, out = Path(a.run), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    common = ["--binary-steps", str(a.binary_steps), "--no-pictures", "--quiet"]
    meshes = {"delaunay": (["--grid", "delaunay", "--delaunay-workers", "1"], 0.0), "octree": ([], 0.0)}
    meshes.update({f"delaunay_moved_{amp:g}": (["--grid", "delaunay", "--delaunay-workers", "1"], amp) for amp in a.amps})
    result = {"run": str(run), "binary_steps": a.binary_steps, "meshes": {}}
    for seed, (name, (args, amp)) in enumerate(meshes.items()):
        path = out / f"{name}.ply"
        with moved_points(amp, seed):
            if extract_main([str(run), "--out", str(path), *args, *common]) != 0:
                raise SystemExit(f"extraction {name} failed")
        stats = json.loads(path.with_suffix(".json").read_text())
        entry = {"moved_by_fraction_of_extent": amp, "faces": stats["meshes"][0]["faces"],
                 "extract_s": stats["total_time_s"]}
        compare_main(str(path), str(out / "delaunay.ply"), str(out / f"{name}_vs_delaunay.json"))
        entry["vs_delaunay"] = json.loads((out / f"{name}_vs_delaunay.json").read_text())["metrics"]
        gt = run / "scene" / "gt_mesh.ply"
        if gt.is_file():
            evaluate_main(["--mesh", str(path), "--gt", str(gt), "--scene", str(run / "scene"),
                           "--json", str(out / f"{name}_vs_gt.json")])
            entry["vs_gt"] = json.loads((out / f"{name}_vs_gt.json").read_text())["metrics"]
        result["meshes"][name] = entry
        (out / "jitter_grid.json").write_text(json.dumps(result, indent=1))
    for name, e in result["meshes"].items():
        f = e["vs_delaunay"]["fscore"]
        gt = e.get("vs_gt", {})
        print(f"{name:24s} F vs Delaunay @0.1/0.5 %: {f[0]:.4f} / {f[1]:.4f}; "
              f"vs GT: Chamfer {gt.get('chamfer', float('nan')):.6f}, F {gt.get('fscore', [float('nan')])[0]:.4f}")


if __name__ == "__main__":
    main()
