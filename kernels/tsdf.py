"""Truncated signed distance fusion of depth maps on a dense voxel grid (the 2DGS/3DGS mesh baseline).

Projective TSDF as Open3D's integration does it: for a voxel centre ``p`` seen by a camera at depth
``z`` through pixel ``(⌊u⌋, ⌊v⌋)`` whose depth is ``d`` (0 = no depth), the signed distance along the
viewing axis is ``sdf = d − z`` (> 0 in front of the surface). Voxels with ``sdf < −trunc`` (hidden
behind the surface) are not updated; others get ``min(1, sdf / trunc)`` averaged with weight 1 per view.
Pure Warp; the grid is ``[X, Y, Z]`` with voxel ``(i, j, k)`` at ``origin + voxel_size · (i, j, k)``.
"""

from __future__ import annotations

import warp as wp

from .render_types import CameraParams


@wp.kernel
def integrate_tsdf(
    depth: wp.array2d(dtype=float),
    colour: wp.array2d(dtype=wp.vec3),
    cam: CameraParams,
    origin: wp.vec3,
    voxel_size: float,
    trunc: float,
    depth_max: float,
    tsdf: wp.array3d(dtype=float),
    weight: wp.array3d(dtype=float),
    rgb: wp.array3d(dtype=wp.vec3),
):
    """One thread per voxel; ``depth`` ``[H, W]`` z-depth (0 = none), ``colour`` ``[H, W]`` RGB."""
    i, j, k = wp.tid()
    p = origin + voxel_size * wp.vec3(float(i), float(j), float(k))
    pc = cam.R * p + cam.t
    z = pc[2]
    if z <= 0.0:
        return
    u = cam.fx * pc[0] / z + cam.cx
    v = cam.fy * pc[1] / z + cam.cy
    if u < 0.0 or v < 0.0:
        return
    px = int(wp.floor(u))
    py = int(wp.floor(v))
    if px >= cam.width or py >= cam.height:
        return
    d = depth[py, px]
    if d <= 0.0 or d > depth_max:
        return
    sdf = d - z
    if sdf < -trunc:
        return
    value = wp.min(1.0, sdf / trunc)
    w = weight[i, j, k]
    tsdf[i, j, k] = (tsdf[i, j, k] * w + value) / (w + 1.0)
    rgb[i, j, k] = (rgb[i, j, k] * w + colour[py, px]) / (w + 1.0)
    weight[i, j, k] = w + 1.0
