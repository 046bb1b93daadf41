"""Per-Gaussian preprocessing: camera-space quantities, colours, exact screen bounds.

Kernels, one thread per Gaussian:

* :func:`preprocess_gaussians` (differentiable, loop-free) — ``μ_v = R_cam μ + t_cam``, ``P = S⁻¹ R_vᵀ`` with
  ``R_v = R_cam R(q)``, ``o_g = −P μ_v`` and the SH colour seen from the camera centre. These 15 floats + opacity
  are all the per-pixel loop reads. Its gradient, as the renderer computes it, comes in two parts: Warp's automatic
  adjoint of :func:`project_frames` (the same kernel without the colour) and :func:`sh_colour_backward` (the
  colour's gradient written out, a thread per coefficient). Warp's adjoint of the whole kernel gives the same
  numbers.
* :func:`screen_bounds` (not differentiable) — culling, the exact bounding box of the projected
  binning ellipsoid ``{x : ‖S⁻¹R_vᵀ(x − μ_v)‖ ≤ k}``, its tile rectangle, radius and sort depth, and the
  conic of its exact silhouette (:mod:`.tile_overlap`) with which the binning keeps only the tiles of the
  rectangle that the ellipse meets (for an ellipsoid crossing the near plane: the general conic of the
  lines through the camera that meet it).
* :func:`ray_conics` (not differentiable) — the same silhouette at the per-pixel cutoff, in normalised image
  coordinates and float32, with which the per-pixel kernels and the opacity field skip a (ray, Gaussian) pair in a
  few operations instead of the ray–Gaussian maths (pairs it skips are ones the exact test drops too).

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

from .gaussian_math import quat_to_rotation, sh_basis, sh_to_color
from .render_types import CameraParams, RasterSettings
from .tile_overlap import TileEllipses, ray_conic, store_ellipse, tile_ellipse

# Relative enlargement of k for the box: the per-pixel float32 d² has a relative error ~1e-6.
BOUNDS_K_MARGIN = wp.constant(1.0e-4)
# Relative enlargement of k for the per-pixel early reject (ray_conics): its silhouette is stored in float32 and
# tested on float32 rays; 1 % keeps every pair the exact test could keep far inside it.
PIXEL_CONIC_K_MARGIN = wp.constant(1.0e-2)


@wp.func
def _project(means: wp.array(dtype=wp.vec3), quats: wp.array(dtype=wp.vec4), scales: wp.array(dtype=wp.vec3), k: int,
             R_cam: wp.mat33, t_cam: wp.vec3, mu_v: wp.array(dtype=wp.vec3), P: wp.array(dtype=wp.mat33),
             o_g: wp.array(dtype=wp.vec3)):  # fmt: skip
    """Gaussian ``k``'s ``μ_v = R_cam μ + t_cam``, ``P = S⁻¹ R_vᵀ`` (``R_v = R_cam R(q)``) and ``o_g = −P μ_v``."""
    mv = R_cam * means[k] + t_cam
    R_v = R_cam * quat_to_rotation(quats[k])
    s = scales[k]
    Pk = wp.diag(wp.vec3(1.0 / s[0], 1.0 / s[1], 1.0 / s[2])) * wp.transpose(R_v)
    mu_v[k] = mv
    P[k] = Pk
    o_g[k] = -(Pk * mv)


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
    _project(means, quats, scales, k, R_cam, t_cam, mu_v, P, o_g)
    colour[k] = sh_to_color(sh_dc, sh_rest, k, sh_degree, wp.normalize(means[k] - cam_centre))


@wp.kernel
def project_frames(
    means: wp.array(dtype=wp.vec3),
    quats: wp.array(dtype=wp.vec4),
    scales: wp.array(dtype=wp.vec3),
    R_cam: wp.mat33,
    t_cam: wp.vec3,
    mu_v: wp.array(dtype=wp.vec3),
    P: wp.array(dtype=wp.mat33),
    o_g: wp.array(dtype=wp.vec3),
):
    """:func:`preprocess_gaussians` without the colour. Its automatic adjoint and :func:`sh_colour_backward` together
    are the gradient of :func:`preprocess_gaussians` (the renderer's backward launches both)."""
    _project(means, quats, scales, wp.tid(), R_cam, t_cam, mu_v, P, o_g)


SH_LANES = wp.constant(16)  # threads per Gaussian in sh_colour_backward: one per SH coefficient (degree ≤ 3)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
// the launch is a multiple of 16 threads: a warp holds two whole groups, or (the last one) lanes 0-15 only
const unsigned mask = (tid | 31) < threads ? 0xffffffffu : 0x0000ffffu;
for (int o = 8; o > 0; o >>= 1) {
    x[0] += __shfl_xor_sync(mask, x[0], o);
    x[1] += __shfl_xor_sync(mask, x[1], o);
    x[2] += __shfl_xor_sync(mask, x[2], o);
}
#endif
return x;
""")
def sum_over_sh_lanes(x: wp.vec3, tid: int, threads: int) -> wp.vec3:
    """Sum of ``x`` over the 16 CUDA lanes of one Gaussian (aligned groups of 16 threads, every thread of the launch
    calls it; ``threads``: the launch's size, a multiple of 16); identity on the CPU, where :func:`sh_lanes_summed` is 0
    and every thread adds its own."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return 1;
#else
return 0;
#endif
""")
def sh_lanes_summed() -> int:
    """1 where :func:`sum_over_sh_lanes` sums over the lanes (CUDA), 0 where it is the identity (CPU)."""
    ...


@wp.kernel
def sh_colour_backward(
    means: wp.array(dtype=wp.vec3),
    sh_rest: wp.array2d(dtype=wp.vec3),
    sh_degree: int,
    cam_centre: wp.vec3,
    colour: wp.array(dtype=wp.vec3),
    adj_colour: wp.array(dtype=wp.vec3),
    grad_means: wp.array(dtype=wp.vec3),
    grad_dc: wp.array(dtype=wp.vec3),
    grad_rest: wp.array2d(dtype=wp.vec3),
    accumulate: int,
):
    """The colour's part of the gradient of :func:`preprocess_gaussians`, written out. Launch ``N · SH_LANES``
    threads: thread ``(k, j)`` handles coefficient ``j`` of Gaussian ``k`` (``j = 0``: ``sh_dc``; ``j ≥ 1``:
    ``sh_rest[:, j − 1]``), so that neighbouring threads read and write neighbouring coefficients.

    Writes ``∂L/∂sh = SH_j(d) · g`` into ``grad_dc``/``grad_rest`` (``accumulate = 1``: added; ``0``: written, for
    arrays that hold zeros; coefficients above ``sh_degree`` are left as they are), where ``g`` is
    ``adj_colour = ∂L/∂colour`` on the channels whose forward ``colour`` is > 0 (the clamp at 0 passes no gradient, as
    the adjoint of ``wp.max``), and adds the view direction's share ``(I − d dᵀ)/‖μ − c‖ · Σ_j ∂SH_j/∂d (sh_j · g)``
    (``d = normalize(μ − c)``) into ``grad_means``. Warp's automatic adjoint of the whole kernel adds the same numbers
    with one scattered atomic per coefficient and thread per Gaussian.

    On CUDA the 16 lanes of a Gaussian run the same instructions: :func:`~.gaussian_math.sh_basis` selects lane
    ``j``'s function instead of branching to it (a branch per ``j`` would make every warp run all 16 branches in turn,
    with their divergence bookkeeping)."""
    tid = wp.tid()
    # tid // 16 in unsigned arithmetic (a launch has fewer than 2³¹ threads): a shift, and k is then known to be
    # non-negative, which spares the sign fix-ups of a signed floor division and the negative-index wrap of every
    # array access below (Warp indexes arrays Python-style)
    k = int(wp.uint32(tid) // wp.uint32(SH_LANES))
    j = tid - k * SH_LANES
    v = means[k] - cam_centre
    length = wp.length(v)
    d = wp.normalize(v)
    c = colour[k]
    a = adj_colour[k]
    g = wp.vec3(wp.where(c[0] > 0.0, a[0], 0.0), wp.where(c[1] > 0.0, a[1], 0.0), wp.where(c[2] > 0.0, a[2], 0.0))
    grad_d = wp.vec3(0.0)
    if j < (sh_degree + 1) * (sh_degree + 1) and j <= sh_rest.shape[1]:
        basis = sh_basis(j, d)
        value = basis[3] * g
        if j == 0:
            if accumulate != 0:
                value = value + grad_dc[k]
            grad_dc[k] = value
        else:
            if accumulate != 0:
                value = value + grad_rest[k, j - 1]
            grad_rest[k, j - 1] = value
            grad_d = wp.dot(sh_rest[k, j - 1], g) * wp.vec3(basis[0], basis[1], basis[2])
    grad_d = sum_over_sh_lanes(grad_d, tid, means.shape[0] * SH_LANES)
    if length > 0.0 and (j == 0 or sh_lanes_summed() == 0):
        grad_means[k] = grad_means[k] + (grad_d - d * wp.dot(d, grad_d)) / length


@wp.func
def _axis_bounds(m_a: wp.float64, m_z: wp.float64, s_aa: wp.float64, s_az: wp.float64, s_zz: wp.float64,
                 k2: wp.float64, f: wp.float64, c: wp.float64) -> wp.vec2d:  # fmt: skip
    """Image interval ``[lo, hi]`` (pixels) of the ellipsoid along one axis (see module docstring)."""
    qa = m_z * m_z - k2 * s_zz
    qb = m_a * m_z - k2 * s_az
    qc = m_a * m_a - k2 * s_aa
    disc = wp.sqrt(wp.max(qb * qb - qa * qc, wp.float64(0.0)))
    return wp.vec2d(f * (qb - disc) / qa + c, f * (qb + disc) / qa + c)


@wp.func
def cutoff_k(op: float, settings: RasterSettings) -> float:
    """The Mahalanobis radius beyond which the per-pixel test drops a Gaussian of opacity ``op``:
    ``min(k_max, √(2 ln(op / alpha_min)))`` (its alpha falls under ``alpha_min`` there), or −1 when it can reach no
    pixel at all (``op ≤ alpha_min``)."""
    kk = settings.k_max
    if settings.alpha_min > 0.0:
        if not (op > settings.alpha_min):
            return -1.0
        kk = wp.min(kk, wp.sqrt(2.0 * wp.log(op / settings.alpha_min)))
    return kk


@wp.func
def view_covariance(R_cam: wp.mat33, quat: wp.vec4, scale: wp.vec3):
    """The Gaussian's axes in camera space ``R_v = R_cam R(q)``, its scales and its covariance
    ``Σ = R_v diag(s²) R_vᵀ``, in float64 (the frame :func:`screen_bounds` and :func:`ray_conics` build the
    silhouette from)."""
    R_v = wp.mat33d(R_cam * quat_to_rotation(quat))
    s = wp.vec3d(scale)
    return R_v, s, R_v * wp.diag(wp.cw_mul(s, s)) * wp.transpose(R_v)


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
    kk = cutoff_k(opacities[k], settings)
    if kk < 0.0 or not (mv[2] > settings.near):
        return
    k64 = wp.float64(kk) * (wp.float64(1.0) + wp.float64(BOUNDS_K_MARGIN))
    k2 = k64 * k64
    R_v, s, Sigma = view_covariance(cam.R, quats[k], scales[k])
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


@wp.kernel
def ray_conics(
    mu_v: wp.array(dtype=wp.vec3),
    quats: wp.array(dtype=wp.vec4),
    scales: wp.array(dtype=wp.vec3),
    opacities: wp.array(dtype=float),
    radii: wp.array(dtype=wp.int32),
    cam: CameraParams,
    settings: RasterSettings,
    conic: wp.array(dtype=wp.vec3),
    centre: wp.array(dtype=wp.vec2),
):
    """The early reject of the per-pixel kernels and the opacity field (``[N]`` each, after :func:`screen_bounds`,
    whose ``radii`` say which Gaussians any tile lists): the silhouette of the ellipsoid at the opacity-aware cutoff
    :func:`cutoff_k` enlarged by ``PIXEL_CONIC_K_MARGIN``, in normalised image coordinates
    (:class:`~.tile_overlap.RayConic`). A ray outside it passes farther than ``k (1 + margin)`` from the Gaussian
    (Mahalanobis), so the exact test (``d² ≤ k²`` at the line's closest point) rejects the pair anyway; the 1 % margin
    is far above float32 rounding in either test. Ellipsoids that reach the near plane, or contain the camera, get
    ``conic = 0`` (nothing rejected)."""
    k = wp.tid()
    conic[k] = wp.vec3(0.0)
    centre[k] = wp.vec2(0.0)
    if radii[k] == 0:
        return
    kk = cutoff_k(opacities[k], settings)
    mv = mu_v[k]
    if kk < 0.0:
        return
    k64 = wp.float64(kk) * (wp.float64(1.0) + wp.float64(PIXEL_CONIC_K_MARGIN))
    R_v, s, Sigma = view_covariance(cam.R, quats[k], scales[k])
    mz = wp.float64(mv[2])
    if not (mz - k64 * wp.sqrt(Sigma[2, 2]) > wp.float64(settings.near)):
        return
    rc = ray_conic(tile_ellipse(wp.vec3d(wp.float64(mv[0]), wp.float64(mv[1]), mz), R_v, s, Sigma, k64 * k64, True))
    conic[k] = rc.conic
    centre[k] = rc.centre
