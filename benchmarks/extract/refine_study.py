"""Surface-error-driven octree refinement, tried and not kept (issue 11, session 11).

Builds the octree grid at ``FACTOR``, marches, then for ``PASSES`` passes flags every triangle whose centroid has no
level crossing within ``±RHO × (its leaf's side)`` along its normal (two field evaluations per triangle), refines
the leaves holding flagged triangles by one level (re-balanced), evaluates the field at the new points only and
marches again. Prints one JSON line per pass and one with the final mesh's score against the exact mesh.

    python benchmarks/extract/refine_study.py RUN FACTOR PASSES RHO [STEPS [SAVE.ply [SCENE]]]

Result (2-core CPU, the README job's model; ``results/refine_s11/``): no setting beats a uniform smaller cell factor
at equal faces, so the default stays uniform.
"""
import sys, time, json
import numpy as np, torch, trimesh
from pathlib import Path
from gof_warp.run_folder import load_run
from gof_warp.tetra import _checked_scales, frustum_mask, BOX_SIGMAS, TetraConfig
from gof_warp import octree_tets as ot
from gof_warp.opacity_field import opacity_field, OpacityFieldConfig
from gof_warp.marching import marching_tetrahedra
from gof_warp.geometry_metrics import evaluate_mesh

run = Path(sys.argv[1]); factor = float(sys.argv[2]); passes = int(sys.argv[3]); rho = float(sys.argv[4])
steps = int(sys.argv[5]) if len(sys.argv) > 5 else 4
save = sys.argv[6] if len(sys.argv) > 6 else None
scene = sys.argv[7] if len(sys.argv) > 7 else None
dev = "cuda" if torch.cuda.is_available() else "cpu"
g, cams, _, rc = load_run(run, scene, dev)
fc = OpacityFieldConfig(unseen_value=-1.0)
def field(p): return opacity_field(g, cams, p, config=fc, render_config=rc)
def field1(p): return opacity_field(g, cams, p, render_config=rc)
t0 = time.perf_counter()
mu = g.means.detach(); s = _checked_scales(g.scales.detach(), mu.shape[0], mu.device)
keep = frustum_mask(mu, cams, TetraConfig.near, TetraConfig.far)
c = mu[keep].double(); r = (BOX_SIGMAS * s[keep].max(dim=1).values).double()
depth = ot.MAX_DEPTH
lo, size = ot.root_cube(c, r)
asked = ot._asked_cells(c, r, lo, size, depth, factor)
level = 0.5
prev_keys = prev_vals = None
def locate(tree, lat):
    lev = torch.full((lat.shape[0],), -1, dtype=torch.int64, device=lat.device)
    for l in range(depth + 1):
        k = tree.leaves[l]
        if k.numel():
            u = 1 << (depth + 1 - l)
            srt, _ = torch.sort(k)
            kl = ot.pack(torch.floor(lat / u).long().clamp(min=0))
            lev[ot.contains(srt, kl)] = l
    return lev
for it in range(passes + 1):
    tree = ot.tree_from_asked(asked, lo, size, depth)
    pts, tets, keys = ot.octree_tetrahedra(tree, return_keys=True)
    vals = torch.empty(pts.shape[0], device=pts.device)
    if prev_keys is not None:
        i = torch.searchsorted(prev_keys, keys).clamp(max=prev_keys.numel() - 1); old = prev_keys[i] == keys
        vals[old] = prev_vals[i[old]]; vals[~old] = field(pts[~old]); n_new = int((~old).sum())
    else:
        vals = field(pts); n_new = pts.shape[0]
    prev_keys, prev_vals = keys, vals
    seen = vals >= 0
    tets_v = tets[seen[tets.long()].all(1)]
    (v, f), = marching_tetrahedra(pts, tets_v, torch.where(seen, vals, torch.ones_like(vals)), field1, levels=(level,), binary_steps=steps, oriented=True)
    info = dict(it=it, points=pts.shape[0], new_points=n_new, tets=tets_v.shape[0], faces=len(f), t=round(time.perf_counter()-t0,1))
    if it == passes:
        print(json.dumps(info)); break
    V = torch.as_tensor(v, device=pts.device).double(); F = torch.as_tensor(f, device=pts.device).long()
    tri = V[F]; cen = tri.mean(1)
    nrm = torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]); nrm = nrm / nrm.norm(dim=1, keepdim=True).clamp(min=1e-30)
    lat = (cen - lo) / tree.unit()
    lev = locate(tree, lat)
    side = size / (2.0 ** lev.double())
    t = rho * side
    q = torch.cat([cen + t[:, None] * nrm, cen - t[:, None] * nrm]).float()
    fq = field1(q).double()
    a, b = fq[:F.shape[0]], fq[F.shape[0]:]
    flag = ((a >= level) == (b >= level)) & (lev < depth) & (lev >= 0)
    info["flagged"] = int(flag.sum()); print(json.dumps(info), flush=True)
    if not flag.any(): break
    for l in torch.unique(lev[flag]).tolist():
        sel = flag & (lev == l); u = 1 << (depth - l)
        kc = ot.pack(torch.floor(lat[sel] / u).long())
        asked[l + 1] = torch.unique(torch.cat([asked[l + 1], kc]))
t_all = time.perf_counter() - t0
res = dict(factor=factor, passes=passes, rho=rho, faces=len(f), total_s=round(t_all,1))
if save: trimesh.Trimesh(v, f, process=False).export(save)
gt = run / "scene/gt_mesh.ply"
if gt.exists():
    m = evaluate_mesh(trimesh.Trimesh(v, f, process=False), str(gt))["metrics"]
    res.update(chamfer=m["chamfer"], acc=m["accuracy"], comp=m["completeness"], fscore=m["fscore"])
print(json.dumps(res))
