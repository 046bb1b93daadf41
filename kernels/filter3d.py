"""The 3D filter's sampling depth: for each Gaussian centre, the nearest camera-space depth over the cameras
that see it (Mip-Splatting's 3D filter as GOF computes it; the host side, the variance and the schedule
live in :mod:`gof_warp.training.filter3d`).

A camera sees a centre ``x`` when ``z > near`` for ``(x_c, y_c, z) = R x + t`` and its projection
``(u, v) = (fx x_c / z + cx, fy y_c / z + cy)`` lies in ``[−g W, (1 + g) W] × [−g H, (1 + g) H]`` (GOF: a
guard band ``g = 0.15``). One thread per centre loops over the cameras, so memory is ``O(N)`` whatever
their number. Pure Warp (no torch).
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def nearest_seen_depth(
    means: wp.array(dtype=wp.vec3),
    R: wp.array(dtype=wp.mat33),
    t: wp.array(dtype=wp.vec3),
    f: wp.array(dtype=wp.vec2),
    c: wp.array(dtype=wp.vec2),
    wh: wp.array(dtype=wp.vec2),
    near: float,
    guard: float,
    depth: wp.array(dtype=float),
):
    """``depth[i]`` = the smallest ``z`` of ``means[i]`` over the cameras that see it; ``+inf`` if none does.

    Camera ``k``: world-to-camera ``R[k]``, ``t[k]``; ``f[k] = (fx, fy)``, ``c[k] = (cx, cy)``, ``wh[k] = (W, H)``
    (``[C]`` each: plain arrays, not an array of a camera struct, whose elements the generated CUDA would read
    byte by byte)."""
    i = wp.tid()
    x = means[i]
    d = float(wp.inf)
    for k in range(R.shape[0]):
        p = R[k] @ x + t[k]
        z = p[2]
        if z > near:
            fk = f[k]
            ck = c[k]
            w = wh[k][0]
            h = wh[k][1]
            u = p[0] / z * fk[0] + ck[0]
            v = p[1] / z * fk[1] + ck[1]
            if u >= -guard * w and u <= (1.0 + guard) * w and v >= -guard * h and v <= (1.0 + guard) * h:
                d = wp.min(d, z)
    depth[i] = d
