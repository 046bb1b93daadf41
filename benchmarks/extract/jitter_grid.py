"""How much of a mesh-vs-mesh F-score is the grid: the Delaunay grid (one Qhull call) against itself with its points
moved, and against the octree grid, all on one model's field.

    python benchmarks/extract/jitter_grid.py RUN --out DIR [--amps 0.001 0.05 0.2] [--binary-steps 4]
    python benchmarks/extract/jitter_grid.py MODEL.ply --scene SCENE --out DIR [--crop X0 Y0 Z0 X1 Y1 Z1]

Every Delaunay point is moved by ``amp ×`` its 3σ extent times a standard normal vector (seeded), so the grid samples
the same field at other places; the field, the levels and the search are unchanged. Each mesh is scored against the
unmoved Delaunay mesh as the extraction issue asks (``compare_meshes.py``: F at 0.1 % and 0.5 % of the diagonal),
the Delaunay mesh against itself (the sampling floor), and, when the run folder holds the scene's exact mesh
(``scene/gt_mesh.ply``, the built-in synthetic scenes), every mesh against it with ``gof_warp.evaluate --scene``.
A Gaussian PLY (``pack_model.py unpack``) is meshed with ``--scene`` (whose ``gt_mesh.ply`` is used likewise). With
``--crop`` (a box, e.g. a ground-and-objects crop) every mesh is also scored against the exact surface inside it
(``evaluate --crop``) and against the Delaunay mesh inside it (``compare_in_box.py``, with its floor).
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
from compare_in_box import main as compare_in_box_main  # noqa: E402
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
    ap.add_argument("--scene", help="scene folder, when RUN is a Gaussian PLY")
    ap.add_argument("--crop", type=float, nargs=6, help="also score inside this box (x0 y0 z0 x1 y1 z1)")
    a = ap.parse_args()
    run, out = Path(a.run), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    scene = Path(a.scene) if a.scene else run / "scene"
    common = ["--binary-steps", str(a.binary_steps), "--no-pictures", "--quiet"]
    if a.scene:
        common += ["--scene", a.scene]
    crop = [str(x) for x in a.crop] if a.crop else None
    meshes = {"delaunay": (["--grid", "delaunay", "--delaunay-workers", "1"], 0.0), "octree": (["--grid", "octree"], 0.0)}
    meshes.update({f"delaunay_moved_{amp:g}": (["--grid", "delaunay", "--delaunay-workers", "1"], amp) for amp in a.amps})
    result = {"run": str(run), "scene": str(scene), "crop": a.crop, "binary_steps": a.binary_steps, "meshes": {}}
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
        if crop:
            compare_in_box_main([str(path), str(out / "delaunay.ply"), "--box", *crop,
                                 "--out", str(out / f"{name}_vs_delaunay_in_crop.json")])
            box = json.loads((out / f"{name}_vs_delaunay_in_crop.json").read_text())
            entry["vs_delaunay_in_crop"] = {"score": box["score"], "floor": box["floor"], "tau": box["tau"]}
        gt = scene / "gt_mesh.ply"
        if gt.is_file():
            for tag, extra in (("vs_gt", []), ("vs_gt_in_crop", ["--crop", *crop] if crop else None)):
                if extra is None:
                    continue
                evaluate_main(["--mesh", str(path), "--gt", str(gt), "--scene", str(scene), *extra,
                               "--json", str(out / f"{name}_{tag}.json")])
                report = json.loads((out / f"{name}_{tag}.json").read_text())
                entry[tag] = report["metrics"]
                entry[tag + "_floor"] = report.get("floor", {}).get("metrics")
        result["meshes"][name] = entry
        (out / "jitter_grid.json").write_text(json.dumps(result, indent=1))
    for name, e in result["meshes"].items():
        f = e["vs_delaunay"]["fscore"]
        gt = e.get("vs_gt", {})
        print(f"{name:24s} F vs Delaunay @0.1/0.5 %: {f[0]:.4f} / {f[1]:.4f}; "
              f"vs GT: Chamfer {gt.get('chamfer', float('nan')):.6f}, F {gt.get('fscore', [float('nan')])[0]:.4f}")


if __name__ == "__main__":
    main()
