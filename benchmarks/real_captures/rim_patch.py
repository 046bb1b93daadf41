"""What the mesh does over one short ground patch at the rim, where a ground meets its background (session 30).

    python benchmarks/real_captures/rim_patch.py MESH.ply GT_MESH.ply CX CY [--ground-z -0.9] [--patch 0.1]

Prints how much of the exact surface inside the patch (``CX, CY`` its centre, ``--patch`` its side) the mesh covers
within a few distances, where the nearest mesh lies for the uncovered part, and the mesh's height profile along the
radius through the patch (min / median / max of its samples in 5 cm bins, in a ±0.01 rad wedge): a mesh that leaves
the ground before the background starts shows its lowest point there above ``--ground-z``.
"""

from __future__ import annotations

import argparse

import numpy as np
import trimesh
from scipy.spatial import cKDTree


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mesh")
    ap.add_argument("gt")
    ap.add_argument("cx", type=float)
    ap.add_argument("cy", type=float)
    ap.add_argument("--patch", type=float, default=0.1)
    ap.add_argument("--ground-z", type=float, default=-0.9)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    np.random.seed(a.seed)  # trimesh's even sampling draws from numpy's global generator
    h = a.patch / 2
    gt = trimesh.load(a.gt, process=False)
    pts, _ = trimesh.sample.sample_surface_even(gt, 3_000_000)
    inside = pts[(np.abs(pts[:, 0] - a.cx) < h) & (np.abs(pts[:, 1] - a.cy) < h)]
    ground = inside[np.abs(inside[:, 2] - a.ground_z) < 1e-3]
    r_g = np.linalg.norm(ground[:, :2], axis=1)
    print(f"exact ground samples in the patch: {len(ground)}, radius {r_g.min():.3f}-{r_g.max():.3f}")
    mesh = trimesh.load(a.mesh, process=False)
    near = np.linalg.norm(mesh.triangles_center[:, :2] - [a.cx, a.cy], axis=1) < 0.4
    samples, _ = trimesh.sample.sample_surface_even(trimesh.Trimesh(mesh.vertices, mesh.faces[near], process=False),
                                                    400_000)
    tree = cKDTree(samples)
    d, j = tree.query(ground)
    for t in (0.01, 0.02, 0.035, 0.0863):
        print(f"ground covered within {t:g}: {np.mean(d < t):.3f}")
    miss = d >= 0.035
    if miss.any():
        off = samples[j[miss]] - ground[miss]
        print(f"uncovered ({miss.sum()}): radius from {np.linalg.norm(ground[miss, :2], axis=1).min():.3f}; nearest mesh "
              f"{np.median(d[miss]):.3f} away (median), offset (x, y, z) {np.round(np.median(off, axis=0), 3).tolist()}")
    r = np.linalg.norm(samples[:, :2], axis=1)
    wedge = np.abs(np.arctan2(samples[:, 1], samples[:, 0]) - np.arctan2(a.cy, a.cx)) < 0.01
    lo_r = np.floor(r_g.min() * 20) / 20 - 0.25
    for lo in np.arange(lo_r, r_g.max() + 0.05, 0.05):
        b = wedge & (r >= lo) & (r < lo + 0.05)
        if b.any():
            z = samples[b, 2] - a.ground_z
            print(f"radius {lo:.2f}-{lo + 0.05:.2f}: mesh height above the ground min / median / max "
                  f"{z.min():.3f} / {np.median(z):.3f} / {z.max():.3f} ({b.sum()} samples)")


if __name__ == "__main__":
    main()
