"""Ray–Gaussian math shared by the renderer's kernels (``@wp.func`` only, float32).

Conventions (``docs/rendering.md``): quaternions are ``wxyz`` and used as given (the caller
normalises); ``R`` has the Gaussian's local axes as columns; ``S = diag(scales)``. Everything per pixel is
evaluated in camera space (ray origin 0, ray ``r = ((i+0.5-cx)/fx, (j+0.5-cy)/fy, 1)``, so the ray
parameter is depth), with the per-Gaussian quantities of :mod:`gof_warp.kernels.project`:

* ``P = S⁻¹ R_vᵀ`` (``[3,3]``, ``R_v = R_cam R``): world-aligned camera vectors → the Gaussian's normalised
  frame, so ``r_g = P r``;
* ``o_g = -P μ_v``: the ray origin (camera centre) in that frame.

Along the ray, the Gaussian's exponent ``½‖o_g + t r_g‖²`` is smallest at ``t* = -(o_g·r_g)/(r_g·r_g)``
(GOF Sec. 3.1); ``d² = ‖o_g + t* r_g‖² = C − B²/A`` is the squared Mahalanobis distance of the ray from the
mean. We evaluate it as the squared norm of the closest point ``x_c = o_g + t* r_g`` instead of
``C − B²/A``: both are the same number, but the latter cancels catastrophically in float32 for tiny scales
(``C ≈ B²/A ≈ 1e16`` for ``s = 1e-8``) and can go negative, which would make an invisible Gaussian opaque.
"""

from __future__ import annotations

import warp as wp

SH_C0 = wp.constant(0.28209479177387814)
SH_C1 = wp.constant(0.4886025119029199)
SH_C2_0 = wp.constant(1.0925484305920792)
SH_C2_1 = wp.constant(-1.0925484305920792)
SH_C2_2 = wp.constant(0.31539156525252005)
SH_C2_3 = wp.constant(-1.0925484305920792)
SH_C2_4 = wp.constant(0.5462742152960396)
SH_C3_0 = wp.constant(-0.5900435899266435)
SH_C3_1 = wp.constant(2.890611442640554)
SH_C3_2 = wp.constant(-0.4570457994644658)
SH_C3_3 = wp.constant(0.3731763325901154)
SH_C3_4 = wp.constant(-0.4570457994644658)
SH_C3_5 = wp.constant(1.445305721320277)
SH_C3_6 = wp.constant(-0.5900435899266435)


@wp.func
def quat_to_rotation(q: wp.vec4) -> wp.mat33:
    """Rotation matrix of a unit quaternion ``q = (w, x, y, z)``; columns are the local axes in world."""
    w = q[0]
    x = q[1]
    y = q[2]
    z = q[3]
    return wp.mat33(
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
        2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
        2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y),
    )  # fmt: skip


@wp.func
def sh_to_color(sh_dc: wp.array(dtype=wp.vec3), sh_rest: wp.array2d(dtype=wp.vec3), k: int, degree: int,
                d: wp.vec3) -> wp.vec3:  # fmt: skip
    """3DGS colour ``max(0, Σ_l≤degree SH_l(d) · sh[k, l] + 0.5)`` at unit direction ``d``.

    The RGB coefficients come in two arrays, as a model keeps them (their learning rates differ): ``sh_dc [N]``
    holds ``sh[:, 0]`` and ``sh_rest [N, (D+1)² − 1]`` holds ``sh[:, 1:]`` (so ``sh[k, l] = sh_rest[k, l − 1]``);
    :func:`gof_warp.kernels.renderer.sh_parts` makes both views of one ``[N, K]`` array. The real SH basis and
    constants are those of 3DGS. Loop-free, so Warp's automatic adjoint differentiates it exactly (w.r.t. both
    arrays and ``d``).
    """
    c = SH_C0 * sh_dc[k]
    if degree > 0:
        x = d[0]
        y = d[1]
        z = d[2]
        c = c - SH_C1 * y * sh_rest[k, 0] + SH_C1 * z * sh_rest[k, 1] - SH_C1 * x * sh_rest[k, 2]
        if degree > 1:
            xx = x * x
            yy = y * y
            zz = z * z
            c = (
                c
                + SH_C2_0 * x * y * sh_rest[k, 3]
                + SH_C2_1 * y * z * sh_rest[k, 4]
                + SH_C2_2 * (2.0 * zz - xx - yy) * sh_rest[k, 5]
                + SH_C2_3 * x * z * sh_rest[k, 6]
                + SH_C2_4 * (xx - yy) * sh_rest[k, 7]
            )
            if degree > 2:
                c = (
                    c
                    + SH_C3_0 * y * (3.0 * xx - yy) * sh_rest[k, 8]
                    + SH_C3_1 * x * y * z * sh_rest[k, 9]
                    + SH_C3_2 * y * (4.0 * zz - xx - yy) * sh_rest[k, 10]
                    + SH_C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy) * sh_rest[k, 11]
                    + SH_C3_4 * x * (4.0 * zz - xx - yy) * sh_rest[k, 12]
                    + SH_C3_5 * z * (xx - yy) * sh_rest[k, 13]
                    + SH_C3_6 * x * (xx - 3.0 * yy) * sh_rest[k, 14]
                )
    c = c + wp.vec3(0.5)
    return wp.vec3(wp.max(c[0], 0.0), wp.max(c[1], 0.0), wp.max(c[2], 0.0))


@wp.func
def sh_basis(j: int, d: wp.vec3) -> wp.vec4:
    """The real SH basis function ``j`` (0–15, 3DGS's order, constants and signs, as :func:`sh_to_color` applies them)
    at the unit direction ``d = (x, y, z)``, with its gradient: ``(∂b/∂x, ∂b/∂y, ∂b/∂z, b)``.

    Branch-free: all 16 closed forms are evaluated and ``j``'s is kept. The 16 CUDA lanes of a Gaussian in
    :func:`~.project.sh_colour_backward` ask for 16 different ``j``; with a branch per function each warp would run
    all 16 branches in turn, each with its divergence bookkeeping, whereas these selects run once for all lanes (the
    compiler makes them predicated multiplies and shares the common products). Selecting adds no rounding: the result
    is the closed form's float32 value."""
    x = d[0]
    y = d[1]
    z = d[2]
    xx = x * x
    yy = y * y
    zz = z * z
    r = wp.vec4(0.0, 0.0, 0.0, SH_C0)
    r = wp.where(j == 1, wp.vec4(0.0, -SH_C1, 0.0, -SH_C1 * y), r)
    r = wp.where(j == 2, wp.vec4(0.0, 0.0, SH_C1, SH_C1 * z), r)
    r = wp.where(j == 3, wp.vec4(-SH_C1, 0.0, 0.0, -SH_C1 * x), r)
    r = wp.where(j == 4, SH_C2_0 * wp.vec4(y, x, 0.0, x * y), r)
    r = wp.where(j == 5, SH_C2_1 * wp.vec4(0.0, z, y, y * z), r)
    r = wp.where(j == 6, SH_C2_2 * wp.vec4(-2.0 * x, -2.0 * y, 4.0 * z, 2.0 * zz - xx - yy), r)
    r = wp.where(j == 7, SH_C2_3 * wp.vec4(z, 0.0, x, x * z), r)
    r = wp.where(j == 8, SH_C2_4 * wp.vec4(2.0 * x, -2.0 * y, 0.0, xx - yy), r)
    r = wp.where(j == 9, SH_C3_0 * wp.vec4(6.0 * x * y, 3.0 * xx - 3.0 * yy, 0.0, y * (3.0 * xx - yy)), r)
    r = wp.where(j == 10, SH_C3_1 * wp.vec4(y * z, x * z, x * y, x * y * z), r)
    r = wp.where(
        j == 11, SH_C3_2 * wp.vec4(-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z, y * (4.0 * zz - xx - yy)), r
    )
    w = 2.0 * zz - 3.0 * xx - 3.0 * yy
    r = wp.where(j == 12, SH_C3_3 * wp.vec4(-6.0 * x * z, -6.0 * y * z, w + 4.0 * zz, z * w), r)
    r = wp.where(
        j == 13, SH_C3_4 * wp.vec4(4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z, x * (4.0 * zz - xx - yy)), r
    )
    r = wp.where(j == 14, SH_C3_5 * wp.vec4(2.0 * x * z, -2.0 * y * z, xx - yy, z * (xx - yy)), r)
    r = wp.where(j == 15, SH_C3_6 * wp.vec4(3.0 * xx - 3.0 * yy, -6.0 * x * y, 0.0, x * (xx - 3.0 * yy)), r)
    return r


@wp.func
def pixel_ray(px: int, py: int, fx: float, fy: float, cx: float, cy: float) -> wp.vec3:
    """Camera-space ray through the centre of pixel (column ``px``, row ``py``), with z = 1."""
    return wp.vec3((float(px) + 0.5 - cx) / fx, (float(py) + 0.5 - cy) / fy, 1.0)


@wp.struct
class RayHit:
    """Ray–Gaussian quantities for one (pixel, Gaussian) pair (all in the Gaussian's normalised frame)."""

    r_g: wp.vec3  # P r
    a: float  # A = r_g·r_g
    t: float  # t* = -(o_g·r_g)/A
    x_c: wp.vec3  # o_g + t* r_g (closest point of the ray to the mean)
    d2: float  # ‖x_c‖² = C − B²/A


@wp.func
def ray_gaussian(P: wp.mat33, o_g: wp.vec3, r: wp.vec3) -> RayHit:
    """Intersection quantities of the camera ray ``t r`` with the Gaussian ``(P, o_g)``."""
    h = RayHit()
    h.r_g = P * r
    h.a = wp.dot(h.r_g, h.r_g)
    h.t = -wp.dot(o_g, h.r_g) / h.a
    h.x_c = o_g + h.t * h.r_g
    h.d2 = wp.dot(h.x_c, h.x_c)
    return h


@wp.func
def normal_direction(P: wp.mat33, r_g: wp.vec3, a: float) -> wp.vec3:
    """Unnormalised normal ``−Pᵀ r_g / √A`` (GOF Sec. 3.2: ``n = −R S⁻¹ r_g``, camera space).

    Dividing by ``√A`` keeps its magnitude ``O(1/scale)`` (no float32 overflow for tiny scales) and does
    not change its direction. It faces the camera: ``n·r = −A/√A < 0``.
    """
    return -(wp.transpose(P) * r_g) / wp.sqrt(a)


@wp.func
def safe_normalize(n: wp.vec3) -> wp.vec3:
    """``n / ‖n‖`` (``‖n‖ > 0`` always holds for the normals above; guarded against 0 anyway)."""
    return n / wp.max(wp.length(n), 1.0e-30)
