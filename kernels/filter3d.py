"""The 3D filter's sampling depth: for each Gaussian centre, the nearest camera-space depth over the cameras
that see it (Mip-Splatting's 3D filter as GOF computes it; the host side, the variance and the schedule
live in :mod:`gof_warp.filter3d`).

A camera sees a centre ``x`` when ``z > near`` for ``(x_c, y_c, z) = R x + t`` and its projection
``(u, v) = (fx x_c / z + cx, fy y_c / z + cy)`` lies in ``[−g W, (1 + g) W] × [−g H, (1 + g) H]`` (GOF: a
guard band ``g = 0.15``). One thread per centre loops over the cameras, so memory is ``O(N)`` whatever
their number. Pure Warp (no torch).
"""

from __future__ import annotations

import warp as wp

from .render_types import CameraParams


@wp.kernel
def nearest_seen_depth(
    means: wp.array(dtype=wp.vec3),
    cameras: wp.array(dtype=CameraParams),
    near: float,
    guard: float,
    depth: wp.array(dtype=float),
):
    """``depth[i]`` = the smallest ``z`` of ``means[i]`` over the ``cameras`` that see it; ``+inf`` if none does."""
    i = wp.tid()
    x = means[i]
    d = float(wp.inf)
    for k in range(cameras.shape[0]):
        cam = cameras[k]
        p = cam.R @ x + cam.t
        z = p[2]
        if z > near:
            w = float(cam.width)
            h = float(cam.height)
            u = p[0] / z * cam.fx + cam.cx
            v = p[1] / z * cam.fy + cam.cy
            if u >= -guard * w and u <= (1.0 + guard) * w and v >= -guard * h and v <= (1.0 + guard) * h:
                d = wp.min(d, z)
    depth[i] = d
