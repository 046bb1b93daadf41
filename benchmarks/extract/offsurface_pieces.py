"""Where two meshes of one model differ off the true surface: ``offsurface_pieces.py A.ply B.ply GT.ply --crop x0 y0 z0
x1 y1 z1 --tau T --out OUT.json``. Samples each mesh inside the box (by area), marks the samples farther than ``tau``
from the exact mesh (off-surface), and says how many of A's off-surface samples have B within ``tau`` (shared: the
field puts a surface there, both grids find it) or not (A's own), with the sizes of A's own pieces (connected
components of A's faces that hold them) and their height above the box floor. Written for the octree vs Delaunay
grid comparison of session 11."""

import argparse
import json

import numpy as np
import trimesh
from scipy.spatial import cKDTree


def crop(mesh, box):
    inside = np.all((mesh.triangles_center >= box[:3]) & (mesh.triangles_center <= box[3:]), axis=1)
    return mesh.submesh([np.nonzero(inside)[0]], append=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("a"); ap.add_argument("b"); ap.add_argument("gt")
    ap.add_argument("--crop", type=float, nargs=6, required=True)
    ap.add_argument("--tau", type=float, required=True)
    ap.add_argument("--density", type=float, default=2e5, help="samples per unit area")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    box = np.asarray(a.crop)
    meshes = {k: crop(trimesh.load(p, process=False), box) for k, p in (("a", a.a), ("b", a.b), ("gt", a.gt))}
    samples, faces = {}, {}
    for k, m in meshes.items():
        n = int(min(4e6, max(1e4, m.area * a.density)))
        samples[k], faces[k] = trimesh.sample.sample_surface(m, n, seed=0)
    gt_tree = cKDTree(samples["gt"])
    res = {"tau": a.tau, "crop": a.crop, "area": {k: float(m.area) for k, m in meshes.items()}}
    d_a = gt_tree.query(samples["a"])[0]
    d_b = gt_tree.query(samples["b"])[0]
    off_a, off_b = d_a > a.tau, d_b > a.tau
    near_b = cKDTree(samples["b"]).query(samples["a"][off_a])[0] <= a.tau
    res["off_surface_fraction"] = {"a": float(off_a.mean()), "b": float(off_b.mean())}
    res["off_surface_area"] = {"a": float(off_a.mean() * meshes["a"].area), "b": float(off_b.mean() * meshes["b"].area)}
    res["a_off_shared_with_b"] = float(near_b.mean()) if off_a.any() else None
    # A's own off-surface pieces: components of A holding them
    own_faces = np.unique(faces["a"][off_a][~near_b])
    labels = trimesh.graph.connected_component_labels(meshes["a"].face_adjacency, node_count=len(meshes["a"].faces))
    comp_area = np.bincount(labels, weights=meshes["a"].area_faces)
    own_comps = np.unique(labels[own_faces])
    res["a_own_pieces"] = {"count": int(len(own_comps)), "area_total": float(comp_area[own_comps].sum()),
                           "area_quantiles": [float(x) for x in np.quantile(comp_area[own_comps], [0.5, 0.9, 1.0])]
                           if len(own_comps) else []}  # areas of the whole components that hold them
    z = samples["a"][off_a][~near_b][:, 2] - box[2]
    res["a_own_height_above_floor_quantiles"] = [float(x) for x in np.quantile(z, [0.1, 0.5, 0.9])] if len(z) else []
    res["a_own_dist_to_gt_quantiles"] = [float(x) for x in np.quantile(d_a[off_a][~near_b], [0.5, 0.9])] if len(z) else []
    in_big = np.isin(labels[faces["a"][off_a][~near_b]], np.argsort(comp_area)[-1:])
    res["a_own_in_largest_component"] = float(in_big.mean()) if len(z) else None
    print(json.dumps(res, indent=1))
    with open(a.out, "w") as f:
        json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
