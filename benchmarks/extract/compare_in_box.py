"""Score one mesh against another inside a box, with the sampling floor beside it.

    python benchmarks/extract/compare_in_box.py TEST.ply REF.ply --box -1 -1 -1 1 1 1 --out OUT.json

Only the faces whose centroid lies in the box are sampled (``--samples`` area-weighted points per mesh), so the score
is that of the region, not of a background that dominates the area (DTU: the object lies in the unit sphere of the
normalised frame, the background shell reaches ~10 units out). Distances are sample to nearest sample (KD-tree);
the **floor** is the reference scored against a second, independent sampling of itself: what this sampling can
resolve. τ: 0.1 % and 0.5 % of the box diagonal and 0.1 % of the reference's whole diagonal (the extraction issue's
bar, F ≥ 0.995 between two meshes of one model).
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from gof_warp.geometry_metrics import sample_surface


def in_box_faces(mesh: trimesh.Trimesh, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = mesh.vertices[mesh.faces].mean(axis=1)
    keep = np.all((c >= box[:3]) & (c <= box[3:]), axis=1)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)[keep]


def scores(a: np.ndarray, b: np.ndarray, taus: list[float]) -> dict:
    d_ab = cKDTree(b).query(a, workers=-1)[0]
    d_ba = cKDTree(a).query(b, workers=-1)[0]
    p = [float(np.mean(d_ab < t)) for t in taus]
    r = [float(np.mean(d_ba < t)) for t in taus]
    return {"chamfer": float(0.5 * (d_ab.mean() + d_ba.mean())), "precision": p, "recall": r,
            "fscore": [2 * x * y / (x + y) if x + y else 0.0 for x, y in zip(p, r)]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("test")
    ap.add_argument("ref")
    ap.add_argument("--box", type=float, nargs=6, default=[-1, -1, -1, 1, 1, 1])
    ap.add_argument("--samples", type=int, default=4_000_000)
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    box = np.asarray(a.box, float)
    test = trimesh.load(a.test, process=False)
    ref = trimesh.load(a.ref, process=False)
    box_diag = float(np.linalg.norm(box[3:] - box[:3]))
    ref_diag = float(np.linalg.norm(ref.bounds[1] - ref.bounds[0]))
    taus = [0.001 * box_diag, 0.005 * box_diag, 0.001 * ref_diag]
    parts = {name: in_box_faces(m, box) for name, m in (("test", test), ("ref", ref))}
    s_test = sample_surface(parts["test"], count=a.samples, seed=0, max_samples=a.samples)
    s_ref = sample_surface(parts["ref"], count=a.samples, seed=1, max_samples=a.samples)
    s_ref2 = sample_surface(parts["ref"], count=a.samples, seed=2, max_samples=a.samples)
    area = {k: float(trimesh.triangles.area(v[f]).sum()) for k, (v, f) in parts.items()}
    result = {"test": a.test, "ref": a.ref, "box": box.tolist(), "samples": a.samples,
              "tau": taus, "tau_meaning": ["0.1% box diagonal", "0.5% box diagonal", "0.1% reference diagonal"],
              "faces_in_box": {k: int(len(f)) for k, (_, f) in parts.items()}, "area_in_box": area,
              "faces_total": {"test": int(len(test.faces)), "ref": int(len(ref.faces))},
              "spacing": {k: float(np.sqrt(area[k] / a.samples)) for k in area},
              "score": scores(s_test, s_ref, taus), "floor": scores(s_ref2, s_ref, taus)}
    with open(a.out, "w") as f:
        json.dump(result, f, indent=1)
    print(json.dumps({k: result[k] for k in ("faces_in_box", "area_in_box", "spacing", "score", "floor")}))


if __name__ == "__main__":
    main()
