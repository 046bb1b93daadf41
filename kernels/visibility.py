"""Which faces of a mesh some camera sees: a ray from a camera centre to a point of the face meets nothing first.

Each face is probed at its centroid ``g`` and, in an image where its farthest corner lies at least ``PROBE_MIN_PX``
pixels from ``g``, at ``0.25 g + 0.75 v`` towards each of its corners ``v`` too (a large face half behind something
can show its other half; a small one's probes would fall within a few pixels of ``g``). A probe ``x`` is seen by
camera ``k`` (world-to-camera ``R, t``, centre ``o = −Rᵀ t``, OpenCV axes, pixel centres at ``i + 0.5``) when it lies
in front of the camera (``z > near_k`` for ``(.., .., z) = R x + t``), projects inside the image ``[0, W) × [0, H)``,
and the ray from ``o`` towards ``x`` hits no triangle of the mesh before ``‖x − o‖ − ε``, with ``ε = eps_px · z / fx``
(``eps_px`` pixel footprints at the probe's depth: the face itself, or a neighbour where the ray grazes, lies within
it). A face is seen when one of its probes is. One thread per face walks the cameras and stops at the first that sees
it, so a visible face costs a few ray queries (``wp.mesh_query_ray`` on the mesh's BVH) and a hidden one one per
camera whose image it falls in (four where it is large). Pure Warp (no torch).
"""

from __future__ import annotations

import warp as wp


PROBE_TO_CORNER = wp.constant(0.75)  # a corner probe lies this far from the centroid towards its corner
PROBE_MIN_PX = wp.constant(4.0)  # corner probes only where the face's farthest corner lies this many pixels from g


@wp.func
def probe_seen(mesh: wp.uint64, x: wp.vec3, R: wp.mat33, t: wp.vec3, f: wp.vec2, c: wp.vec2, wh: wp.vec2, near: float,
               eps_px: float) -> bool:
    """Whether the camera ``R, t, f = (fx, fy), c = (cx, cy), wh = (W, H)`` sees the point ``x`` of the mesh."""
    p = R @ x + t
    z = p[2]
    if z <= near:
        return False
    u = p[0] / z * f[0] + c[0]
    v = p[1] / z * f[1] + c[1]
    if u < 0.0 or u >= wh[0] or v < 0.0 or v >= wh[1]:
        return False
    o = -(wp.transpose(R) @ t)
    d = x - o
    dist = wp.length(d)
    reach = dist - eps_px * z / f[0]
    if reach <= 0.0:
        return True
    q = wp.mesh_query_ray(mesh, o, d / dist, reach)
    return not q.result


@wp.kernel
def faces_seen(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    faces: wp.array2d(dtype=wp.int32),
    R: wp.array(dtype=wp.mat33),
    t: wp.array(dtype=wp.vec3),
    f: wp.array(dtype=wp.vec2),
    c: wp.array(dtype=wp.vec2),
    wh: wp.array(dtype=wp.vec2),
    near: wp.array(dtype=float),
    eps_px: float,
    seen: wp.array(dtype=wp.int8),
):
    """``seen[i] = 1`` when some camera sees face ``i`` (module docstring), else 0. ``mesh``: the id of the
    ``wp.Mesh`` of ``points [V]`` and ``faces [F, 3]``; cameras ``[C]``: world-to-camera ``R``, ``t``,
    ``f = (fx, fy)``, ``c = (cx, cy)``, ``wh = (W, H)``, ``near`` (depth)."""
    i = wp.tid()
    a = points[faces[i, 0]]
    b = points[faces[i, 1]]
    e = points[faces[i, 2]]
    g = (a + b + e) / 3.0
    extent = wp.max(wp.max(wp.length(a - g), wp.length(b - g)), wp.length(e - g))  # corner farthest from g
    hit = wp.int8(0)
    for k in range(R.shape[0]):
        if probe_seen(mesh, g, R[k], t[k], f[k], c[k], wh[k], near[k], eps_px):
            hit = wp.int8(1)
            break
        z = (R[k] @ g + t[k])[2]
        if z > near[k] and extent * f[k][0] < PROBE_MIN_PX * z:
            continue  # a face this small in this image: its corner probes lie within a few pixels of g
        if (probe_seen(mesh, g + PROBE_TO_CORNER * (a - g), R[k], t[k], f[k], c[k], wh[k], near[k], eps_px)
                or probe_seen(mesh, g + PROBE_TO_CORNER * (b - g), R[k], t[k], f[k], c[k], wh[k], near[k], eps_px)
                or probe_seen(mesh, g + PROBE_TO_CORNER * (e - g), R[k], t[k], f[k], c[k], wh[k], near[k], eps_px)):
            hit = wp.int8(1)
            break
    seen[i] = hit
