"""Pseudo-SfM points for a synthetic scene (used by ``dp_whole.sh``): visible ground-truth surface points with 2 mm noise.

    python benchmarks/distributed/pseudo_sfm.py SCENE_DIR N [--seed 0]

Writes ``SCENE_DIR/points3d.ply``: ``N`` points sampled on ``gt_mesh.ply`` that at least two training views see
unoccluded (checked against the scene's z-depth maps), coloured from the photos. Needs ``trimesh``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def unoccluded_views(scene_dir: Path, scene, points: np.ndarray):
    """For each train view of a synthetic scene: ``(view, index [K], pixel [K, 2])`` of the ``points`` it sees
    unoccluded (in the image and within 1 % of the GT z-depth map at their pixel)."""
    frames = {f["file_path"].replace("/", "_"): f for f in json.loads((scene_dir / "transforms_train.json").read_text())["frames"]}
    for v in scene.train:
        depth = np.load(scene_dir / frames[v.name]["depth_path"])
        uv, z, ok = v.camera.in_image(points)
        idx = np.where(ok)[0]
        ij = np.floor(uv[idx]).astype(int)
        vis = np.abs(depth[ij[:, 1], ij[:, 0]] - z[idx]) < 0.01 * z[idx]
        yield v, idx[vis], ij[vis]


def pseudo_sfm(scene_dir: Path, n: int, seed: int = 0) -> None:
    """Write ``points3d.ply``: ``n`` visible GT-surface points with 2 mm noise, coloured from the photos."""
    import trimesh

    from gof_warp.data import DataConfig, load_scene

    rng = np.random.default_rng(seed)
    gt = trimesh.load(scene_dir / "gt_mesh.ply", process=False)
    pts, _ = trimesh.sample.sample_surface(gt, 20 * n, seed=seed)
    scene = load_scene(scene_dir, DataConfig())
    seen = np.zeros(len(pts), int)
    colour = np.zeros((len(pts), 3))
    for v, idx, ij in unoccluded_views(scene_dir, scene, pts):
        colour[idx] = v.image[ij[:, 1], ij[:, 0]]
        seen[idx] += 1
    cand = np.where(seen >= 2)[0]
    pick = rng.choice(cand, size=min(n, len(cand)), replace=False)
    p = pts[pick] + rng.normal(0.0, 0.002, (len(pick), 3))
    trimesh.PointCloud(p, colors=np.concatenate([colour[pick], np.full((len(pick), 1), 255)], 1).astype(np.uint8)).export(
        scene_dir / "points3d.ply")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("n", type=int)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    pseudo_sfm(a.scene, a.n, a.seed)


if __name__ == "__main__":
    main()
