"""Per-Gaussian preprocessing: camera-space quantities, colours, exact screen bounds.

Two kernels, one per Gaussian:

* :func:`preprocess_gaussians` (differentiable, loop-free: its gradient is Warp's automatic adjoint) —
  ``μ_v = R_cam μ + t_cam``, ``P = S⁻¹ R_vᵀ`` with ``R_v = R_cam R(q)``, ``o_g = −P μ_v`` and the SH colour
  seen from the camera centre. These 15 floats + opacity are all the per-pixel loop reads.
* :func:`screen_bounds` (not differentiable) — culling, the exact bounding box of the projected
  binning ellipsoid ``{x : ‖S⁻¹R_vᵀ(x − μ_v)‖ ≤ k}``, its tile rectangle, radius and sort depth, and the
  conic of its exact silhouette (:mod:`.tile_overlap`) with which the binning keeps only the tiles of the
  rectangle that the ellipse meets (for an ellipsoid crossing the near plane: the general conic of the
  lines through the camera that meet it).

Bounding box (``docs/rendering.md``): image column ``u = fx x/z + cx`` is constant on planes through the
camera with normal ``n = (fx, 0, cx − u)``. Such a plane touches the ellipsoid (centre ``μ``, covariance
``Σ = R_v S² R_vᵀ``, radius ``k``) iff ``(n·μ)² = k² nᵀΣn``, a quadratic in ``w = u − cx``:
``w² (μz² − k²Σzz) − 2 w fx (μx μz − k²Σxz) + fx² (μx² − k²Σxx) = 0``; its two roots bound the ellipsoid's
image when the ellipsoid lies in front of the plane ``z = near`` (``μz − k√Σzz > near``). Otherwise the
whole image is used. Same for rows. Solved in float64 with ``k`` enlarged by ``BOUNDS_K_MARGIN`` so that
float32 rounding in the per-pixel test can never admit a pixel outside the box.
"""

from __future__ import annotations

import warp as wp

from .gaussian_math import quat_to_rotation, sh_to_color
from .render_types import CameraParams, RasterSettings
from .tile_overlap import TileEllipses, store_ellipse, tile_ellipse

# Relative enlargement of k for the box: the per-pixel float32 d² has a relative error ~1e-6.
BOUNDS_K_MARGIN = wp.constant(1.0e-4)


@wp.kernel
def preprocess_gaussians(
    means: wp.array(dtype=wp.vec3),
    quats: wp.array(dtype=wp.vec4),
    scales: wp.array(dtype=wp.vec3),
    sh_dc: wp.array(dtype=wp.vec3),
    sh_rest: wp.array2d(dtype=wp.vec3),
    sh_degree: int,
    R_cam: wp.mat33,
    t_cam: wp.vec3,
    cam_centre: wp.vec3,
    mu_v: wp.array(dtype=wp.vec3),
    P: wp.array(dtype=wp.mat33),
    o_g: wp.array(dtype=wp.vec3),
    colour: wp.array(dtype=wp.vec3),
):
    """Inputs ``means/scales [N] vec3``, ``quats [N] vec4`` (wxyz), ``sh_dc [N] vec3``, ``sh_rest [N, K−1] vec3``
    (see :func:`~.gaussian_math.sh_to_color`); outputs ``[N]``."""
    k = wp.tid()
    m = means[k]
    mv = R_cam * m + t_cam
    R_v = R_cam * quat_to_rotation(quats[k])
    s = scales[k]
    Pk = wp.diag(wp.vec3(1.0 / s[0], 1.0 / s[1], 1.0 / s[2])) * wp.transpose(R_v)
    mu_v[k] = mv
    P[k] = Pk
    o_g[k] = -(Pk * mv)
    colour[k] = sh_to_color(sh_dc, sh_rest, k, sh_degree, wp.normalize(m - cam_centre))


@wp.func
def _axis_bounds(m_a: wp.float64, m_z: wp.float64, s_aa: wp.float64, s_az: wp.float64, s_zz: wp.float64,
                 k2: wp.float64, f: wp.float64, c: wp.float64) -> wp.vec2d:  # fmt: skip
    """Image interval ``[lo, hi]`` (pixels) of the ellipsoid along one axis (see module docstring)."""
    qa = m_z * m_z - k2 * s_zz
    qb = m_a * m_z - k2 * s_az
    qc = m_a * m_a - k2 * s_aa
    disc = wp.sqrt(wp.max(qb * qb - qa * qc, wp.float64(0.0)))
    return wp.vec2d(f * (qb - disc) / qa + c, f * (qb + disc) / qa + c)


@wp.kernel
def screen_bounds(
    mu_v: wp.array(dtype=wp.vec3),
    quats: wp.array(dtype=wp.vec4),
    scales: wp.array(dtype=wp.vec3),
    opacities: wp.array(dtype=float),
    cam: CameraParams,
    settings: RasterSettings,
    rect: wp.array(dtype=wp.vec4i),
    tiles_touched: wp.array(dtype=wp.int32),
    radii: wp.array(dtype=wp.int32),
    depth: wp.array(dtype=float),
    ellipse: TileEllipses,
):
    """Outputs per Gaussian (``[N]`` each): tile rectangle ``(x0, y0, x1, y1)`` (half-open) of the bounding
    box, its tile count (an upper bound of the binned tiles: ``bin_gaussians`` recounts with ``ellipse``),
    the screen radius in pixels (0 = not visible), the sort depth ``μ_v.z`` and the silhouette conic of
    the tile test (``exact = 0``: all tiles of ``rect``, as when ``settings.tile_cull == 0`` or the camera
    centre is inside the ellipsoid). An ellipsoid crossing the near plane keeps the whole image as its
    box and its radius (``max(W, H)``), but the binning keeps only the tiles that lines through the
    camera and the ellipsoid reach (``exact = 2``, :mod:`.tile_overlap`)."""
    k = wp.tid()
    mv = mu_v[k]
    depth[k] = mv[2]
    ellipse.exact[k] = 0
    rect[k] = wp.vec4i(0, 0, 0, 0)
    tiles_touched[k] = 0
    radii[k] = 0
    op = opacities[k]
    kk = settings.k_max
    if settings.alpha_min > 0.0:
        if not (op > settings.alpha_min):
            return
        kk = wp.min(kk, wp.sqrt(2.0 * wp.log(op / settings.alpha_min)))
    if not (mv[2] > settings.near):
        return
    k64 = wp.float64(kk) * (wp.float64(1.0) + wp.float64(BOUNDS_K_MARGIN))
    k2 = k64 * k64
    R_v = wp.mat33d(cam.R * quat_to_rotation(quats[k]))
    s = wp.vec3d(scales[k])
    Sigma = R_v * wp.diag(wp.cw_mul(s, s)) * wp.transpose(R_v)
    mx = wp.float64(mv[0])
    my = wp.float64(mv[1])
    mz = wp.float64(mv[2])
    W = cam.width
    H = cam.height
    x0 = 0
    x1 = W - 1
    y0 = 0
    y1 = H - 1
    radius = wp.max(W, H)
    in_front = mz - k64 * wp.sqrt(Sigma[2, 2]) > wp.float64(settings.near)
    x_inside = False  # the silhouette's box lies within the image columns (rows): not clamped
    y_inside = False
    if in_front:
        bu = _axis_bounds(mx, mz, Sigma[0, 0], Sigma[0, 2], Sigma[2, 2], k2, wp.float64(cam.fx), wp.float64(cam.cx))
        bv = _axis_bounds(my, mz, Sigma[1, 1], Sigma[1, 2], Sigma[2, 2], k2, wp.float64(cam.fy), wp.float64(cam.cy))
        half = wp.float64(0.5)
        pad = wp.float64(settings.pixel_pad)
        # pixel i is covered when its centre i + 0.5 lies in [lo − pad, hi + pad] (pad 0.5: any point of
        # the pixel, for rays through arbitrary points); clamp before converting to int
        lim = wp.float64(1.0e9)
        ux0 = int(wp.ceil(wp.clamp(bu[0] - half - pad, -lim, lim)))
        ux1 = int(wp.floor(wp.clamp(bu[1] - half + pad, -lim, lim)))
        vy0 = int(wp.ceil(wp.clamp(bv[0] - half - pad, -lim, lim)))
        vy1 = int(wp.floor(wp.clamp(bv[1] - half + pad, -lim, lim)))
        x_inside = ux0 >= x0 and ux1 <= x1
        y_inside = vy0 >= y0 and vy1 <= y1
        x0 = wp.max(x0, ux0)
        x1 = wp.min(x1, ux1)
        y0 = wp.max(y0, vy0)
        y1 = wp.min(y1, vy1)
        ext = wp.max(bu[1] - bu[0], bv[1] - bv[0]) * half
        radius = int(wp.ceil(wp.min(ext, lim)))
    if x0 > x1 or y0 > y1:
        return
    ts = settings.tile_size
    r = wp.vec4i(x0 / ts, y0 / ts, x1 / ts + 1, y1 / ts + 1)
    rect[k] = r
    tiles_touched[k] = (r[2] - r[0]) * (r[3] - r[1])
    radii[k] = wp.max(radius, 1)
    # An elliptic silhouette whose whole box lies in one tile row (or column) meets every tile of that row
    # between its leftmost and rightmost points: the float64 conic (the costliest part of this kernel) is
    # built only where culling can remove a tile.
    one_row = r[3] - r[1] == 1 and y_inside
    one_column = r[2] - r[0] == 1 and x_inside
    if settings.tile_cull != 0 and not (one_row or one_column):
        store_ellipse(ellipse, k, tile_ellipse(wp.vec3d(mx, my, mz), R_v, s, Sigma, k2, in_front))
