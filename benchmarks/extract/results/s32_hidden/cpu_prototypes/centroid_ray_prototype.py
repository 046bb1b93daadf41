"""Experiment: keep the faces that some training camera sees: the ray from the camera centre to the face's centroid
meets nothing of the mesh before d - eps (eps = eps_px pixel footprints at that depth)."""
import sys, time
import numpy as np
import trimesh
import warp as wp
from gof_warp.data import load_scene

@wp.kernel
def face_seen(mesh: wp.uint64, centroid: wp.array(dtype=wp.vec3), R: wp.array(dtype=wp.mat33), t: wp.array(dtype=wp.vec3),
              origin: wp.array(dtype=wp.vec3), f: wp.array(dtype=wp.vec2), c: wp.array(dtype=wp.vec2), wh: wp.array(dtype=wp.vec2),
              eps_px: float, seen: wp.array(dtype=wp.int8)):
    i = wp.tid()
    x = centroid[i]
    hit = wp.int8(0)
    for k in range(R.shape[0]):
        p = R[k] @ x + t[k]
        z = p[2]
        if z > 1.0e-6:
            u = p[0] / z * f[k][0] + c[k][0]
            v = p[1] / z * f[k][1] + c[k][1]
            if u >= 0.0 and u < wh[k][0] and v >= 0.0 and v < wh[k][1]:
                d = x - origin[k]
                dist = wp.length(d)
                eps = eps_px * z / f[k][0]
                if dist - eps <= 0.0:
                    hit = wp.int8(1)
                    break
                q = wp.mesh_query_ray(mesh, origin[k], d / dist, dist - eps)
                if not q.result:
                    hit = wp.int8(1)
                    break
    seen[i] = hit

src, scene, out, eps_px = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
wp.init()
m = trimesh.load(src, process=False)
V = np.asarray(m.vertices, np.float32); F = np.asarray(m.faces, np.int32)
mesh = wp.Mesh(points=wp.array(V, dtype=wp.vec3, device="cpu"), indices=wp.array(F.ravel(), dtype=wp.int32, device="cpu"))
C = V[F].mean(axis=1).astype(np.float32)
cams = [v.camera for v in load_scene(scene).train]
arr = lambda a, dt: wp.array(np.asarray(a, np.float32), dtype=dt, device="cpu")
R = arr([c.R for c in cams], wp.mat33); T = arr([c.t for c in cams], wp.vec3)
O = arr([-(np.asarray(c.R).T @ np.asarray(c.t)) for c in cams], wp.vec3)
f = arr([[c.fx, c.fy] for c in cams], wp.vec2); cc = arr([[c.cx, c.cy] for c in cams], wp.vec2)
wh = arr([[c.width, c.height] for c in cams], wp.vec2)
seen = wp.zeros(len(F), dtype=wp.int8, device="cpu")
t0 = time.time()
wp.launch(face_seen, dim=len(F), inputs=[mesh.id, wp.array(C, dtype=wp.vec3, device="cpu"), R, T, O, f, cc, wh, eps_px], outputs=[seen], device="cpu")
wp.synchronize()
vis = seen.numpy().astype(bool)
print(f"{len(cams)} cameras, {time.time()-t0:.1f} s: {vis.sum()} of {len(F)} faces seen", flush=True)
sub = trimesh.Trimesh(V, F[vis], process=False)
sub.remove_unreferenced_vertices()
sub.export(out)
