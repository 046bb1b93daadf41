"""Experiment: keep only the mesh faces some training camera's pixel ray hits first (+ k rings of neighbours)."""
import sys, time
import numpy as np
import trimesh
import warp as wp
from gof_warp.data import load_scene
from gof_warp.kernels.raycast import cast_pinhole_rays

src, scene, out_stem = sys.argv[1], sys.argv[2], sys.argv[3]
rings = [int(r) for r in sys.argv[4].split(",")]
samples = int(sys.argv[5]) if len(sys.argv) > 5 else 1
wp.init()
m = trimesh.load(src, process=False)
V = np.asarray(m.vertices, np.float32); F = np.asarray(m.faces, np.int32)
mesh = wp.Mesh(points=wp.array(V, dtype=wp.vec3, device="cpu"), indices=wp.array(F.ravel(), dtype=wp.int32, device="cpu"))
s = load_scene(scene)
seen = np.zeros(len(F), bool)
t0 = time.time()
for v in s.train:
    c = v.camera
    h = cast_pinhole_rays(mesh, c.R, c.t, c.fx, c.fy, c.cx, c.cy, c.width, c.height, samples=samples)
    f = h["face"].numpy().ravel()
    seen[f[f >= 0]] = True
print(f"{len(s.train)} cameras, {time.time()-t0:.1f} s: {seen.sum()} of {len(F)} faces seen", flush=True)
adj = m.face_adjacency
for k in rings:
    keep = seen.copy()
    for _ in range(k):
        grow = keep.copy()
        a, b = adj[:, 0], adj[:, 1]
        grow[a[keep[b]]] = True; grow[b[keep[a]]] = True
        keep = grow
    sub = trimesh.Trimesh(V, F[keep], process=False)
    sub.remove_unreferenced_vertices()
    sub.export(f"{out_stem}_r{k}.ply")
    print(f"rings {k}: {keep.sum()} faces kept", flush=True)
