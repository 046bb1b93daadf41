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


@wp.kernel
def sample_grid_trilinear(
    grid: wp.array3d(dtype=float),
    origin: wp.vec3,
    voxel_size: float,
    points: wp.array(dtype=wp.vec3),
    values: wp.array(dtype=float),
):
    """One thread per point: trilinear interpolation of ``grid`` ``[X, Y, Z]`` (node ``(i, j, k)`` at
    ``origin + voxel_size · (i, j, k)``) at ``points`` ``[M]``; points outside the grid are clamped onto
    its boundary (as ``TSDFVolume.sample``). Needs ``X, Y, Z >= 2``; writes ``values`` ``[M]``."""
    m = wp.tid()
    x = (points[m] - origin) / voxel_size
    i0 = wp.vec3i(0, 0, 0)
    f = wp.vec3(0.0, 0.0, 0.0)
    for a in range(3):
        upper = grid.shape[a] - 1
        xa = wp.clamp(x[a], 0.0, float(upper))
        ia = wp.min(int(wp.floor(xa)), upper - 1)  # cell [ia, ia + 1] always inside the grid
        i0[a] = ia
        f[a] = xa - float(ia)
    i, j, k = i0[0], i0[1], i0[2]
    c00 = grid[i, j, k] * (1.0 - f[0]) + grid[i + 1, j, k] * f[0]
    c10 = grid[i, j + 1, k] * (1.0 - f[0]) + grid[i + 1, j + 1, k] * f[0]
    c01 = grid[i, j, k + 1] * (1.0 - f[0]) + grid[i + 1, j, k + 1] * f[0]
    c11 = grid[i, j + 1, k + 1] * (1.0 - f[0]) + grid[i + 1, j + 1, k + 1] * f[0]
    c0 = c00 * (1.0 - f[1]) + c10 * f[1]
    c1 = c01 * (1.0 - f[1]) + c11 * f[1]
    values[m] = c0 * (1.0 - f[2]) + c1 * f[2]
