"""The shell's top band of `background_full` in one sector, meshed on the CPU from a trained model (2-core box).

``top_band_sector.py MODEL.ply SCENE OUT_DIR``: keeps the model's Gaussians in the box x 3-7, |y| < 2.5, z -0.3-3.2
(the shell's top band and what lies in front of it on the +x side), meshes them twice with ``extract --min-views 2``
(all of them; without those whose centres fewer than two training cameras see) and scores each mesh in the inner box
x 4-6.5, |y| < 1.5, z 0.5-2.6, where the only surface is the shell (the sphere r = 6): precision = mesh samples inside
the box and in some camera's image within tau of r = 6; recall = samples of the sphere in the box that some camera's
frustum holds (occlusion ignored) with a mesh sample within tau; tau = 0.5 % of the whole seen region's diagonal.
The Gaussians outside the box are left out, so the field near the box's faces is not the full model's: the inner
box keeps 1 m from them. MODEL.ply: e.g. ``../extract/pack_model.py unpack`` of a packed run.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from gof_warp.data import load_scene
from gof_warp.ply import read_ply_vertices, write_ply_vertices

TAU = 0.0863  # 0.5 % of background_full's seen-region diagonal (17.27)
SHELL_RADIUS = 6.0


def in_outer(p):
    return (p[:, 0] > 3.0) & (p[:, 0] < 7.0) & (np.abs(p[:, 1]) < 2.5) & (p[:, 2] > -0.3) & (p[:, 2] < 3.2)


def in_inner(p):
    return (p[:, 0] > 4.0) & (p[:, 0] < 6.5) & (np.abs(p[:, 1]) < 1.5) & (p[:, 2] > 0.5) & (p[:, 2] < 2.6)


def views_seeing(points, cameras) -> np.ndarray:
    """How many cameras' images (frusta, no occlusion) hold each point."""
    return sum(cam.in_image(points, near=0.05)[2].astype(int) for cam in cameras)


def score(mesh_path: Path, cameras, gt_seen: np.ndarray) -> dict:
    mesh = trimesh.load(mesh_path)
    pts, _ = trimesh.sample.sample_surface(mesh, 3_000_000, seed=0)
    pts = pts[in_inner(pts)]
    pts = pts[views_seeing(pts, cameras) >= 1]
    precision = float(np.mean(np.abs(np.linalg.norm(pts, axis=1) - SHELL_RADIUS) <= TAU))
    recall = float(np.mean(cKDTree(pts).query(gt_seen, distance_upper_bound=TAU)[0] <= TAU))
    centre = mesh.triangles_center
    inside = in_inner(centre)
    off = inside & (np.abs(np.linalg.norm(centre, axis=1) - SHELL_RADIUS) > TAU)
    return {"precision": precision, "recall": recall, "fscore": 2 * precision * recall / (precision + recall),
            "area_in_box": float(mesh.area_faces[inside].sum()), "off_area": float(mesh.area_faces[off].sum())}


def main() -> int:
    model, scene_dir, out = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
    out.mkdir(parents=True, exist_ok=True)
    cameras = load_scene(scene_dir).train_cameras
    az, zz = np.meshgrid(np.linspace(-0.3, 0.3, 1200), np.linspace(0.5, 2.6, 1000))
    ring = np.sqrt(SHELL_RADIUS ** 2 - zz ** 2)
    gt = np.stack([ring * np.cos(az), ring * np.sin(az), zz], -1).reshape(-1, 3)
    gt = gt[in_inner(gt)]
    gt = gt[views_seeing(gt, cameras) >= 1]
    g = read_ply_vertices(model)
    x = np.stack([g["x"], g["y"], g["z"]], 1).astype(np.float64)
    box = in_outer(x)
    seen = views_seeing(x, cameras)
    for name, keep in (("all", box), ("seen_by_2", box & (seen >= 2))):
        ply = out / f"{name}.ply"
        write_ply_vertices(ply, {k: np.asarray(a)[keep] for k, a in g.items()})
        mesh = out / f"{name}_views2.ply"
        subprocess.run([sys.executable, "-m", "gof_warp.extract", str(ply), "--scene", str(scene_dir), "--out",
                        str(mesh), "--min-views", "2", "--no-pictures", "--quiet"], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        s = score(mesh, cameras, gt)
        print(f"{name}: {int(keep.sum())} Gaussians; P {s['precision']:.4f} R {s['recall']:.4f} F {s['fscore']:.4f}; "
              f"off-surface {s['off_area']:.2f} of {s['area_in_box']:.2f} m2", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
