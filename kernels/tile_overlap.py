"""Exact, conservative tile–ellipse overlap for the tile binning (float64 ``@wp.func`` only).

A Gaussian affects a pixel only if the pixel's ray passes within Mahalanobis distance ``k`` of its mean,
i.e. meets the ellipsoid ``{x : (x − μ)ᵀΣ⁻¹(x − μ) ≤ k²}`` (``kernels/project.py``). The ray ``t d``,
``d = (a, b, 1)`` with normalised image coordinates ``a = (u − cx)/fx``, ``b = (v − cy)/fy``, passes at
squared Mahalanobis distance ``min_t ‖P(t d − μ)‖² = ‖Pμ × Pd‖² / ‖Pd‖²`` (``P = S⁻¹R_vᵀ``), and
``Pμ × Pd = cof(P)(μ × d)`` gives ``(μ × d)ᵀ Σ (μ × d) / (dᵀ adj(Σ) d)``. So the ray meets the ellipsoid iff

    q(d) = dᵀ Q d ≤ 0,   Q = [μ]ₓᵀ Σ [μ]ₓ − k² adj(Σ),   adj(Σ) = R_v diag(s₁²s₂², s₀²s₂², s₀²s₁²) R_vᵀ,

the image of the tangent cone (it equals ``−adj(K(k²Σ − μμᵀ)Kᵀ)`` up to a positive factor, the dual conic
whose vertical tangents are the box edges of ``screen_bounds``). No ``Σ⁻¹`` appears, so flat Gaussians are
fine. When the ellipsoid lies in front of the near plane, ``q ≤ 0`` is a filled ellipse (its 2×2 block is
positive definite) containing the projected mean ``(μx/μz, μy/μz)``.

A rectangle meets a filled ellipse iff one of its points lies inside: either the projected mean lies in
the rectangle (the ellipse could be wholly inside it) or ``q``'s minimum over one of the four edges is
``≤ 0`` (on an edge ``q`` is a 1-D convex quadratic: minimise in closed form, clamp to the segment).
Rounding: evaluating ``q`` in float64 errs by far less than ``τ (|μ|² tr Σ + k² tr adj Σ) |d|²`` with
``τ = 1e-10`` (≈10⁶ ulps of the terms' magnitudes), so that amount is subtracted from ``Q``'s diagonal
(the test keeps every tile within a few millipixels of the ellipse). The tile is the pixel-centre
rectangle of its in-image pixels grown by ``pixel_pad`` on each side (as the box of ``screen_bounds``).
"""

from __future__ import annotations

import warp as wp

from .render_types import CameraParams, RasterSettings

vec6d = wp.types.vector(length=6, dtype=wp.float64)

# Relative float64 rounding allowance of the conic test (see the module docstring).
CONIC_TOL = wp.constant(1.0e-10)


@wp.struct
class TileEllipse:
    """Per-Gaussian input of the tile test (written by ``screen_bounds``, read by both binning passes)."""

    conic: vec6d  # (q00, q01, q02, q11, q12, q22) of Q (tolerance included); inside iff dᵀQd ≤ 0
    centre: wp.vec2d  # the projected mean in normalised coordinates (a point inside the ellipse)
    exact: int  # 1: test each tile; 0: every tile of the bounding rectangle (near plane crossed, degenerate)


@wp.func
def tile_ellipse(mu: wp.vec3d, R_v: wp.mat33d, s: wp.vec3d, Sigma: wp.mat33d, k2: wp.float64) -> TileEllipse:
    """The tile test's conic for the ellipsoid ``(μ, Σ = R_v diag(s²) R_vᵀ, k² = k2)``, which must lie in front
    of the near plane. ``exact = 0`` if the conic is not a proper ellipse (degenerate input)."""
    e = TileEllipse()
    e.exact = 0
    e.centre = wp.vec2d(mu[0] / mu[2], mu[1] / mu[2])
    zero = wp.float64(0.0)
    mx = wp.mat33d(zero, -mu[2], mu[1], mu[2], zero, -mu[0], -mu[1], mu[0], zero)  # [μ]ₓ d = μ × d
    s2 = wp.cw_mul(s, s)
    G = R_v * wp.diag(wp.vec3d(s2[1] * s2[2], s2[0] * s2[2], s2[0] * s2[1])) * wp.transpose(R_v)
    Q = wp.transpose(mx) * Sigma * mx - k2 * G
    tol = wp.float64(CONIC_TOL) * (wp.dot(mu, mu) * (Sigma[0, 0] + Sigma[1, 1] + Sigma[2, 2]) + k2 * (G[0, 0] + G[1, 1] + G[2, 2]))
    q00 = Q[0, 0] - tol
    q11 = Q[1, 1] - tol
    q01 = wp.float64(0.5) * (Q[0, 1] + Q[1, 0])
    e.conic = vec6d(q00, q01, wp.float64(0.5) * (Q[0, 2] + Q[2, 0]), q11, wp.float64(0.5) * (Q[1, 2] + Q[2, 1]), Q[2, 2] - tol)
    if q00 > zero and q11 > zero and q00 * q11 - q01 * q01 > zero:
        e.exact = 1
    return e


@wp.func
def conic_at(c: vec6d, a: wp.float64, b: wp.float64) -> wp.float64:
    """``q(a, b) = (a, b, 1) Q (a, b, 1)ᵀ``."""
    two = wp.float64(2.0)
    return c[0] * a * a + two * c[1] * a * b + c[3] * b * b + two * c[2] * a + two * c[4] * b + c[5]


@wp.func
def rect_meets_ellipse(e: TileEllipse, a0: wp.float64, a1: wp.float64, b0: wp.float64, b1: wp.float64) -> bool:
    """Whether the rectangle ``[a0, a1] × [b0, b1]`` (normalised coordinates) meets the filled ellipse."""
    c = e.conic
    zero = wp.float64(0.0)
    if e.centre[0] >= a0 and e.centre[0] <= a1 and e.centre[1] >= b0 and e.centre[1] <= b1:
        return True
    # vertical edges a = a0, a1: q(a, ·) is smallest at b = −(q01 a + q12)/q11
    if conic_at(c, a0, wp.clamp(-(c[1] * a0 + c[4]) / c[3], b0, b1)) <= zero:
        return True
    if conic_at(c, a1, wp.clamp(-(c[1] * a1 + c[4]) / c[3], b0, b1)) <= zero:
        return True
    # horizontal edges b = b0, b1: q(·, b) is smallest at a = −(q01 b + q02)/q00
    if conic_at(c, wp.clamp(-(c[1] * b0 + c[2]) / c[0], a0, a1), b0) <= zero:
        return True
    return conic_at(c, wp.clamp(-(c[1] * b1 + c[2]) / c[0], a0, a1), b1) <= zero


@wp.func
def tile_meets_ellipse(e: TileEllipse, tx: int, ty: int, cam: CameraParams, settings: RasterSettings) -> bool:
    """Whether tile ``(tx, ty)`` — the centres of its in-image pixels, grown by ``pixel_pad`` — meets ``e``."""
    ts = settings.tile_size
    half_pad = wp.float64(0.5) - wp.float64(wp.max(settings.pixel_pad, 0.0))  # centre 0.5, minus the pad
    u0 = wp.float64(tx * ts) + half_pad
    u1 = wp.float64(wp.min(tx * ts + ts, cam.width)) - half_pad
    v0 = wp.float64(ty * ts) + half_pad
    v1 = wp.float64(wp.min(ty * ts + ts, cam.height)) - half_pad
    fx = wp.float64(cam.fx)
    fy = wp.float64(cam.fy)
    cx = wp.float64(cam.cx)
    cy = wp.float64(cam.cy)
    return rect_meets_ellipse(e, (u0 - cx) / fx, (u1 - cx) / fx, (v0 - cy) / fy, (v1 - cy) / fy)


@wp.func
def row_tile_span(e: TileEllipse, ty: int, x0: int, x1: int, cam: CameraParams, settings: RasterSettings) -> wp.vec2i:
    """Half-open column range ``[lo, hi)`` of the tiles of row ``ty`` within ``[x0, x1)`` that are binned:
    from the first to the last tile that meets the ellipse (the tiles of a row that meet a convex set are
    contiguous), all of ``[x0, x1)`` when ``e.exact == 0``, empty (``lo == hi``) when none meets it."""
    if e.exact == 0:
        return wp.vec2i(x0, x1)
    lo = x0
    while lo < x1 and not tile_meets_ellipse(e, lo, ty, cam, settings):
        lo += 1
    if lo == x1:
        return wp.vec2i(x1, x1)
    hi = x1 - 1
    while hi > lo and not tile_meets_ellipse(e, hi, ty, cam, settings):
        hi -= 1
    return wp.vec2i(lo, hi + 1)
