"""The faces of an extracted mesh that some training camera sees (``MeshConfig.drop_hidden``).

The level set of GOF's opacity field has parts no photo can see: level crossings under a ground, inside objects,
behind walls, where the field hovers near the level because a few views see through a thin or half-transparent
surface. The Delaunay grid rarely finds them (it has points only at the Gaussians' box corners and centres); the
octree grid, which fills the cells around the boxes, does (e.g. a skirt 5–14 cm under the ground of the
``background`` scene). Nothing in the photos supports such faces; the
extraction drops the faces that no training camera sees (:func:`faces_seen`; the Warp kernel
:func:`gof_warp.kernels.visibility.faces_seen`, one thread per face, on the model's device): a face is seen when the
ray from some camera's centre to the face's centroid, or for a face that spans a few pixels one of three points towards
its corners, meets no other part of the mesh first, within ``eps_px`` pixel footprints. The mesh then covers what the
cameras see: hidden pockets and closed interiors go, and a surface is closed only where the cameras see all around it.

Cost: a ``wp.Mesh`` (BVH) of the mesh, 12 B per face of indices, 1 B per face; a few ray queries per seen face
and one per camera whose image a hidden face falls in (four where it spans a few pixels).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import warp as wp

from ..core.arrays import check_triangles
from ..core.camera import Camera, camera_arrays
from ..core.devices import warp_device
from ..core.errors import GofError
from ..kernels.visibility import PROBE_MIN_PX, PROBE_TO_CORNER
from ..kernels.visibility import faces_seen as _faces_seen_kernel

HIDDEN_EPS_PX = 1.0  # pixel footprints a face may lie behind what the ray meets first and still count as seen


def _checked(verts, faces, cameras) -> tuple[np.ndarray, np.ndarray, list]:
    # float32 from the extraction: the kernel's precision, no float64 copy
    v, f = check_triangles(verts, np.asarray(faces, np.int64), "faces_seen", GofError)
    if not np.isfinite(v).all():
        raise GofError("faces_seen: verts has NaN/inf entries")
    cams = list(cameras)
    if not cams:
        raise GofError("faces_seen: needs at least one camera")
    return v, f, cams


def _camera_arrays(cams: Sequence[Camera], near: float) -> dict[str, np.ndarray]:
    """:func:`~gof_warp.core.camera.camera_arrays` and each camera's near plane, the larger of ``near`` and its own (as
    rendered)."""
    return {**camera_arrays(cams), "near": np.array([max(float(near), float(c.near)) for c in cams], np.float64)}


def faces_seen(verts, faces, cameras: Sequence[Camera], *, near: float = 0.0, eps_px: float = HIDDEN_EPS_PX,
               device="cpu") -> np.ndarray:
    """``[F]`` bool: whether some camera sees each face of ``verts [V, 3]``, ``faces [F, 3]`` (module docstring):
    one of the face's probes (its centroid ``g``, and where the face spans ``PROBE_MIN_PX`` pixels or more in that
    image ``0.25 g + 0.75 v`` towards each corner ``v``) lies in front of the camera (depth ``>`` the larger of
    ``near`` and the camera's own ``near``, as the renderer clips) and inside its image, and the ray from the camera's
    centre to it meets nothing of the mesh before ``eps_px`` pixel footprints short of it. Float32 Warp kernel on
    ``device``; :func:`faces_seen_reference` is its float64 reference."""
    v, f, cams = _checked(verts, faces, cameras)
    if len(f) == 0:
        return np.zeros(0, bool)
    if not (eps_px >= 0 and np.isfinite(eps_px)):
        raise GofError(f"faces_seen: eps_px must be a finite number >= 0, got {eps_px!r}")
    wp.init()
    dev = warp_device(device)
    cam = _camera_arrays(cams, near)
    arr = lambda a, dt: wp.array(np.ascontiguousarray(a, np.float32), dtype=dt, device=dev)  # noqa: E731
    points = arr(v, wp.vec3)
    indices = wp.array(f.astype(np.int32, copy=False), dtype=wp.int32, device=dev)
    mesh = wp.Mesh(points=points, indices=indices.flatten())
    seen = wp.zeros(len(f), dtype=wp.int8, device=dev)
    wp.launch(_faces_seen_kernel, dim=len(f), device=dev,
              inputs=[mesh.id, points, indices, arr(cam["R"], wp.mat33), arr(cam["t"], wp.vec3),
                      arr(cam["f"], wp.vec2), arr(cam["c"], wp.vec2), arr(cam["wh"], wp.vec2),
                      arr(cam["near"], float), float(eps_px)],
              outputs=[seen])
    return seen.numpy().astype(bool)


def faces_seen_reference(verts, faces, cameras: Sequence[Camera], *, near: float = 0.0,
                         eps_px: float = HIDDEN_EPS_PX) -> np.ndarray:
    """:func:`faces_seen` in float64 numpy, every ray against every triangle (Möller–Trumbore; small meshes)."""
    v, f, cams = _checked(verts, faces, cameras)
    v = v.astype(np.float64)
    cam = _camera_arrays(cams, near)
    g = v[f].mean(axis=1)  # [F, 3] centroids, then the probes towards each corner
    probes = [g] + [g + PROBE_TO_CORNER * (v[f[:, j]] - g) for j in range(3)]
    extent = np.max([np.linalg.norm(v[f[:, j]] - g, axis=1) for j in range(3)], axis=0)  # farthest corner from g
    p0, e1, e2 = v[f[:, 0]], v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    seen = np.zeros(len(f), bool)
    for k in range(len(cams)):
        R, t = cam["R"][k], cam["t"][k]
        o = -R.T @ t
        zg = g @ R[2] + t[2]
        small = (zg > cam["near"][k]) & (extent * cam["f"][k, 0] < PROBE_MIN_PX * zg)
        for n, x in enumerate(probes):
            p = x @ R.T + t
            z = p[:, 2]
            front = z > cam["near"][k]
            zs = np.where(front, z, 1.0)
            u = np.where(front, p[:, 0] / zs * cam["f"][k, 0] + cam["c"][k, 0], -1)
            w = np.where(front, p[:, 1] / zs * cam["f"][k, 1] + cam["c"][k, 1], -1)
            ok = front & (u >= 0) & (u < cam["wh"][k, 0]) & (w >= 0) & (w < cam["wh"][k, 1]) & ~seen
            if n > 0:
                ok &= ~small
            for i in np.nonzero(ok)[0]:
                d = x[i] - o
                dist = np.linalg.norm(d)
                reach = dist - eps_px * z[i] / cam["f"][k, 0]
                if reach <= 0:
                    seen[i] = True
                    continue
                d = d / dist
                pv = np.cross(d, e2)
                det = np.einsum("ij,ij->i", e1, pv)
                valid = np.abs(det) > 1e-12
                inv = np.where(valid, 1.0 / np.where(valid, det, 1.0), 0.0)
                s = o - p0
                a = np.einsum("ij,ij->i", s, pv) * inv
                qv = np.cross(s, e1)
                b = (qv @ d) * inv
                tt = np.einsum("ij,ij->i", e2, qv) * inv
                blocked = valid & (a >= 0) & (b >= 0) & (a + b <= 1) & (tt >= 0) & (tt < reach)
                seen[i] = not blocked.any()
    return seen
