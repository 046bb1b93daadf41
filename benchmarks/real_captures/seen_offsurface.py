"""Where a mesh's false surface lies in a synthetic scene's seen region, by the GT part it is nearest to:
``seen_offsurface.py MESH SCENE [--shell-radius 6] --out OUT.json``.

Crops and samples the mesh as ``evaluate --scene`` scores the whole seen region (the same region, density and tau:
``gof_warp.region_metrics``), then gives every predicted sample the GT part nearest to it (the parts of
``scene.json``, in the face order of ``gt_mesh.ply``) and its distance. Per part: the predicted area assigned to it
and the share farther than tau (what lowers precision). For a spherical background shell, the signed radial offset
``r - R`` of the samples assigned to it (negative: in front of the shell, seen from inside) in bins, so a layer in
front (the field's level before the true shell) and pieces far off are told apart. Written in session 17 for the
`background_detail` scene's whole-region precision (0.74 at tau = 9.4 cm)."""

import argparse
import json
import math
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from gof_warp.io_utils import write_json_atomic
from gof_warp.region_metrics import (DEFAULT_GT_MAX_EDGE_FRACTION, _box_diag, _soup, crop_mesh, read_scene, sample_soup,
                                     scored_region, split_triangles)

OFFSET_BINS = (-math.inf, -1.0, -0.5, -0.3, -0.2, -0.1, -0.05, 0.0, 0.05, 0.1, 0.2, math.inf)


Z_BINS = (-math.inf, -1.0, -0.5, -0.2, 0.0, 0.2, 0.4, 1.0, 2.0, math.inf)  # height above the ground plane


def _where(points: np.ndarray, ground: dict | None, area_per_sample: float) -> dict:
    """Area of ``points`` (the off samples) by height above the ground and by whether they lie over the ground's
    square (``inside``), beyond its edges (``beyond``): the gap between a finite ground and the shell."""
    if ground is None or not len(points):
        return {}
    z = points[:, 2] - ground["height"]
    (x0, y0), (x1, y1) = ground["extent"]
    over = (points[:, 0] >= x0) & (points[:, 0] <= x1) & (points[:, 1] >= y0) & (points[:, 1] <= y1)
    out = {"z_bins": [str(b) for b in Z_BINS]}
    for name, m in (("over_ground", over), ("beyond_ground", ~over)):
        hist, _ = np.histogram(z[m], bins=Z_BINS)
        out[name] = [round(float(h) * area_per_sample, 3) for h in hist]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mesh", type=Path)
    ap.add_argument("scene", type=Path)
    ap.add_argument("--shell-radius", type=float, default=6.0, help="radius of the part named 'shell' (origin-centred)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--samples-out", type=Path, default=None,
                    help="also write the off samples (position, distance, nearest part) to this .npz")
    ap.add_argument("--device", default=None)
    a = ap.parse_args(argv)
    cameras, scene = read_scene(a.scene)
    gt = trimesh.load(a.scene / "gt_mesh.ply", process=False)
    gv, gf = np.asarray(gt.vertices, np.float64), np.asarray(gt.faces, np.int64)
    names = [p["name"] for p in scene["parts"]]
    face_part = np.repeat(np.arange(len(names)), [p["faces"] for p in scene["parts"]])
    if len(face_part) != len(gf):
        raise SystemExit(f"scene.json's parts hold {len(face_part)} faces, gt_mesh.ply {len(gf)}")
    # the region of region_scores: the GT split (per part, to keep each piece's part), the seen test, the defaults
    max_edge = DEFAULT_GT_MAX_EDGE_FRACTION * _box_diag(gv)
    split = [split_triangles(gv[gf[face_part == k]], max_edge) for k in range(len(names))]
    part_of = np.concatenate([np.full(len(s), k) for k, s in enumerate(split)])
    gt_tri = np.concatenate(split)
    reg = scored_region(gt_tri, cameras, device=a.device)
    seen_tri, seen_part = gt_tri[reg.seen], part_of[reg.seen]
    diag, tau, max_dist, density, inside = reg.diagonal, reg.tau[0], reg.max_dist, reg.density, reg.inside

    gt_pts, gt_lab = [], []
    for k in range(len(names)):
        if (seen_part == k).any():
            s = sample_soup(crop_mesh(*_soup(seen_tri[seen_part == k]), inside, resolution=density), density, 1 + k)
            gt_pts.append(s)
            gt_lab.append(np.full(len(s), k))
    gt_pts, gt_lab = np.concatenate(gt_pts), np.concatenate(gt_lab)
    pred = trimesh.load(a.mesh, process=False)
    pred_pts = sample_soup(crop_mesh(np.asarray(pred.vertices, np.float64), np.asarray(pred.faces, np.int64), inside,
                                     resolution=density), density, 0)
    d, j = cKDTree(gt_pts).query(pred_pts)
    keep = d <= max_dist  # evaluate's truncation ("exclude"): farther samples are outliers, not scored
    area_per_sample = density ** 2
    parts = {}
    for k, name in enumerate(names):
        m = keep & (gt_lab[j] == k)
        if not m.any():
            continue
        parts[name] = {"pred_area": round(float(m.sum()) * area_per_sample, 3),
                       "gt_scored_area": round(float((gt_lab == k).sum()) * area_per_sample, 3),
                       "off_fraction": round(float((d[m] > tau).mean()), 4),
                       "off_area": round(float((m & (d > tau)).sum()) * area_per_sample, 3)}
    report = {"mesh": str(a.mesh), "scene": str(a.scene), "diagonal": diag, "tau": tau, "max_dist": max_dist,
              "density": density, "pred_samples": int(len(pred_pts)), "outliers_beyond_max_dist": int((~keep).sum()),
              "precision": round(float((d[keep] <= tau).mean()), 4), "parts": parts}
    if "shell" in names:
        m = keep & (gt_lab[j] == names.index("shell"))
        off = np.linalg.norm(pred_pts[m], axis=1) - a.shell_radius
        hist, _ = np.histogram(off, bins=OFFSET_BINS)
        report["shell_offset"] = {"radius": a.shell_radius, "bins": [str(b) for b in OFFSET_BINS],
                                  "area": [round(float(h) * area_per_sample, 3) for h in hist],
                                  "median": round(float(np.median(off)), 4) if len(off) else None,
                                  "quartiles": [round(float(q), 4) for q in np.percentile(off, [25, 75])]
                                  if len(off) else None}
        gm = gt_lab == names.index("shell")
        # the shell's GT samples with no prediction within tau: where the shell is missing, by height
        miss = gm & (cKDTree(pred_pts[keep]).query(gt_pts)[0] > tau) if keep.any() else gm
        def z_quartiles(mask):
            return [round(float(q), 3) for q in np.percentile(gt_pts[mask, 2], [25, 50, 75])] if mask.any() else None

        report["shell_missing"] = {"fraction": round(float(miss.sum() / max(gm.sum(), 1)), 4),
                                   "z_quartiles_missing": z_quartiles(miss), "z_quartiles_all": z_quartiles(gm)}
    is_off = keep & (d > tau)
    report["off_where"] = _where(pred_pts[is_off], scene.get("ground"), area_per_sample)
    if a.samples_out is not None:
        a.samples_out.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(a.samples_out, points=pred_pts[is_off].astype(np.float32), dist=d[is_off].astype(np.float32),
                            part=gt_lab[j[is_off]].astype(np.int8), parts=np.array(names))
    write_json_atomic(a.out, report)
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
