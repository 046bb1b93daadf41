"""Experiment: keep the faces whose centroid passes some training camera's depth test against the mesh's own depth
buffer: z_centroid <= max over a 3x3 window of the buffer + tol_px pixel footprints (z / fx)."""
import sys, time
import numpy as np
import trimesh
import warp as wp
from scipy.ndimage import maximum_filter
from gof_warp.data import load_scene
from gof_warp.kernels.raycast import cast_pinhole_rays

src, scene, out, tol_px = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
wp.init()
m = trimesh.load(src, process=False)
V = np.asarray(m.vertices, np.float32); F = np.asarray(m.faces, np.int32)
mesh = wp.Mesh(points=wp.array(V, dtype=wp.vec3, device="cpu"), indices=wp.array(F.ravel(), dtype=wp.int32, device="cpu"))
C = V[F].mean(axis=1).astype(np.float64)
s = load_scene(scene)
vis = np.zeros(len(F), bool)
t0 = time.time()
for v in s.train:
    c = v.camera
    h = cast_pinhole_rays(mesh, c.R, c.t, c.fx, c.fy, c.cx, c.cy, c.width, c.height)
    D = h["depth"].numpy().astype(np.float64)
    D[h["face"].numpy() < 0] = np.inf
    Dmax = maximum_filter(D, size=3, mode="nearest")
    x = C @ np.asarray(c.R, np.float64).T + np.asarray(c.t, np.float64)
    z = x[:, 2]
    ok = z > 1e-6
    u = np.full(len(F), -1.0); w = np.full(len(F), -1.0)
    u[ok] = x[ok, 0] / z[ok] * c.fx + c.cx; w[ok] = x[ok, 1] / z[ok] * c.fy + c.cy
    inside = ok & (u >= 0) & (u < c.width) & (w >= 0) & (w < c.height)
    idx = np.nonzero(inside)[0]
    zb = Dmax[w[idx].astype(int), u[idx].astype(int)]
    vis[idx[z[idx] <= zb + tol_px * z[idx] / c.fx]] = True
print(f"{len(s.train)} cameras, {time.time()-t0:.1f} s: {vis.sum()} of {len(F)} faces visible", flush=True)
sub = trimesh.Trimesh(V, F[vis], process=False)
sub.remove_unreferenced_vertices()
sub.export(out)
