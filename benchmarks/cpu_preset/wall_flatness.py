"""How flat is the fox's wall in the mesh? The mesh is ray cast from one of the run's test views; the hits in a window
of the image that shows only the wall are fitted with a plane (least squares), and the
script reports the points' RMS distance from it (as a fraction of their mean depth) and the angle between each hit
face's normal and the plane's (median and 90th percentile, degrees): bumps show as spread normals.

    python benchmarks/cpu_preset/wall_flatness.py RUN [--mesh RUN/mesh_tetra.ply] [--view 0] [--strip 0 0.2]
        [--rows 0.3 1] [--json OUT]

The window is fractions of the image's width (x from, x to) and height (y from, y to); on the fox's test views 0001
and 0009 the left fifth below the top 30 % shows wallpaper only (above it hangs a picture frame).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def flatness(vertices: np.ndarray, faces: np.ndarray, camera, strip=(0.0, 0.2), rows=(0.0, 1.0)) -> dict:
    """The plane fit of the mesh's first hits in the window ``strip`` × ``rows`` (fractions of the width and of the
    height) of ``camera``'s image."""
    from gof_warp.mesh.colour import _cast, _wp_mesh

    hits = _cast(_wp_mesh(vertices, faces, "cpu"), camera)
    h, w = hits["face"].shape
    cols = np.zeros(w, bool)
    cols[int(strip[0] * w):int(np.ceil(strip[1] * w))] = True
    lines = np.zeros(h, bool)
    lines[int(rows[0] * h):int(np.ceil(rows[1] * h))] = True
    window = lines[:, None] & cols[None, :]
    sel = (hits["face"] >= 0) & window
    ys, xs = np.nonzero(sel)
    z = hits["depth"][sel]
    cam_pts = np.stack([(xs + 0.5 - camera.cx) / camera.fx * z, (ys + 0.5 - camera.cy) / camera.fy * z, z], 1)
    world = (cam_pts - camera.t) @ camera.R
    centre = world.mean(0)
    _, _, vt = np.linalg.svd(world - centre, full_matrices=False)
    normal = vt[2]
    dist = (world - centre) @ normal
    tri = vertices[faces[hits["face"][sel]]]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
    angle = np.degrees(np.arccos(np.clip(np.abs(fn @ normal), 0.0, 1.0)))
    return {"pixels": int(sel.sum()), "window_pixels": int(window.sum()),
            "rms_over_depth": float(np.sqrt(np.mean(dist**2)) / np.mean(z)),
            "normal_angle_median_deg": float(np.median(angle)), "normal_angle_p90_deg": float(np.percentile(angle, 90))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--mesh", type=Path, default=None)
    ap.add_argument("--view", type=int, default=0, help="index among the run's test views")
    ap.add_argument("--strip", type=float, nargs=2, default=(0.0, 0.2), help="x from, x to (fractions of the width)")
    ap.add_argument("--rows", type=float, nargs=2, default=(0.3, 1.0), help="y from, y to (fractions of the height)")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)

    import trimesh

    from gof_warp.training.run_folder import cameras_from_json

    mesh = trimesh.load(a.mesh or a.run / "mesh_tetra.ply", process=False, force="mesh")
    cam = cameras_from_json(a.run / "cameras.json", "test")[a.view]
    out = {"run": str(a.run), "view": cam.name, "strip": list(a.strip), "rows": list(a.rows),
           **flatness(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64), cam, a.strip, a.rows)}
    print(json.dumps(out, indent=1))
    if a.json:
        a.json.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
