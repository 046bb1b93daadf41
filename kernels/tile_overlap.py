"""Exact, conservative tile–ellipse overlap for the tile binning (float64 ``@wp.func`` only).

A Gaussian affects a pixel only if the pixel's ray passes within Mahalanobis distance ``k`` of its mean,
i.e. meets the ellipsoid ``{x : (x − μ)ᵀΣ⁻¹(x − μ) ≤ k²}`` (``kernels/project.py``). The ray ``t d``,
``d = (a, b, 1)`` with normalised image coordinates ``a = (u − cx)/fx``, ``b = (v − cy)/fy``, passes at
squared Mahalanobis distance ``min_t ‖P(t d − μ)‖² = ‖Pμ × Pd‖² / ‖Pd‖²`` (``P = S⁻¹R_vᵀ``), and
``Pμ × Pd = cof(P)(μ × d)`` gives ``(μ × d)ᵀ Σ (μ × d) / (dᵀ adj(Σ) d)`` (minimum over all real ``t``: the
whole line). So the line meets the ellipsoid (for an ellipsoid in front of the near plane: the ray) iff

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

Ellipsoids crossing the near plane (``exact = 2``; their box is the whole image). ``q(d) ≤ 0`` says that
the whole LINE through the camera centre along ``d`` meets the ellipsoid; that is necessary for the pixel
ray (the half-line ``t d``, ``t > near``) to meet it, whatever the near plane cuts away: the per-pixel
rule (``d² ≤ k²``, ``t* > near``, ``α ≥ alpha_min``) only removes pixels from ``{q ≤ 0}``. So a tile with
``q > 0`` at every point of its padded rectangle holds no pixel the Gaussian can affect, and dropping it
removes from that tile's list only entries that the per-pixel loop skips without touching any state
(no blending, no transmittance change, and no early stop either: only a Gaussian that passes the
per-pixel test can trigger it): every pixel sees the same passing Gaussians in the same order (the list
keeps its depth order), so every output and gradient is bitwise unchanged. Here
``{q ≤ 0}`` may be any conic region (a filled ellipse, a parabola's inside, one or two hyperbola pieces:
not convex in general), so no row-span shortcut; the test is the exact minimum of the 2-D quadratic
``q(a, b)`` over the rectangle, whose candidates are the 4 corners, on each edge the vertex of the 1-D
restriction when it is convex there (clamped to the edge: the edge minimum), and the interior critical
point when the 2×2 part is positive definite (clamped into the rectangle: any point of the rectangle is a
valid witness, and an interior minimiser is exactly reached). Every candidate is a point of the
rectangle, so the test never keeps a tile for a point outside it, and the minimum is among them, so it
never drops a tile that has a point with ``q ≤ 0`` (up to rounding, covered by the allowance above, which
is subtracted from ``Q`` in both cases). When the camera centre is inside the ellipsoid (``μᵀΣ⁻¹μ ≤ k²``,
evaluated as ``Σᵢ (R_vᵀμ)ᵢ² Πⱼ≠ᵢ sⱼ² ≤ k² Πⱼ sⱼ²``, no ``Σ⁻¹``) every line through the camera meets it,
``q ≤ 0`` everywhere, and ``exact = 0`` keeps the whole rectangle without testing (this is only a
shortcut: the general test would keep every tile too). To keep the cost of a whole-image rectangle low
the tiles are visited in 8 × 8 blocks: a block (its tiles' rectangle hull, gaps between tiles included)
that fails the test is skipped, else each 8-tile row segment, then each tile; skipping is conservative
because the hull contains every tile's rectangle, and the decision of each tile is a fixed function of
the Gaussian, so the count and write passes agree.
"""

from __future__ import annotations

import warp as wp

from .render_types import CameraParams, RasterSettings

vec6d = wp.types.vector(length=6, dtype=wp.float64)

# Relative float64 rounding allowance of the conic test (see the module docstring).
CONIC_TOL = wp.constant(1.0e-10)


@wp.struct
class TileEllipse:
    """One Gaussian's tile test, in registers (stored per Gaussian in :class:`TileEllipses`)."""

    conic: vec6d  # (q00, q01, q02, q11, q12, q22) of Q (tolerance included); inside iff dᵀQd ≤ 0
    centre: wp.vec2d  # the projected mean in normalised coordinates (a point inside the ellipse)
    exact: int  # 1: filled ellipse, row spans; 2: any conic, block/tile minimum test; 0: every tile of the rectangle


@wp.struct
class TileEllipses:
    """Per-Gaussian storage of the tile test (``[N]`` each; written by ``screen_bounds``, read by both binning passes):
    the fields of :class:`TileEllipse` in separate arrays of plain types. An array of the struct itself would be read
    and written byte by byte in the generated CUDA (one 8-bit access per byte of its 72), which made
    ``screen_bounds`` ~10× slower; here ``conic`` and ``centre`` are touched only where ``exact != 0``."""

    exact: wp.array(dtype=wp.int32)
    conic: wp.array(dtype=vec6d)
    centre: wp.array(dtype=wp.vec2d)


def empty_tile_ellipses(n: int, device=None, *, whole_rect: bool = False) -> TileEllipses:
    """Storage for ``n`` Gaussians' tile tests; ``whole_rect``: every ``exact = 0`` (bin the whole rectangle; no conic
    is stored or read then)."""
    el = TileEllipses()
    el.exact = (wp.zeros if whole_rect else wp.empty)(n, dtype=wp.int32, device=device)
    m = 0 if whole_rect else n
    el.conic = wp.empty(m, dtype=vec6d, device=device)
    el.centre = wp.empty(m, dtype=wp.vec2d, device=device)
    return el


@wp.func
def store_ellipse(el: TileEllipses, k: int, e: TileEllipse):
    """Write Gaussian ``k``'s tile test (the conic only when it is used)."""
    el.exact[k] = e.exact
    if e.exact != 0:
        el.conic[k] = e.conic
        el.centre[k] = e.centre


@wp.func
def load_ellipse(el: TileEllipses, k: int) -> TileEllipse:
    """Gaussian ``k``'s tile test as written by :func:`store_ellipse`."""
    e = TileEllipse()
    e.exact = el.exact[k]
    if e.exact != 0:
        e.conic = el.conic[k]
        e.centre = el.centre[k]
    return e


@wp.func
def tile_ellipse(mu: wp.vec3d, R_v: wp.mat33d, s: wp.vec3d, Sigma: wp.mat33d, k2: wp.float64, in_front: bool) -> TileEllipse:
    """The tile test's conic for the ellipsoid ``(μ, Σ = R_v diag(s²) R_vᵀ, k² = k2)``. ``in_front``: the
    ellipsoid lies beyond the near plane (``exact = 1`` if the conic is a proper ellipse, else the general
    test ``exact = 2``); otherwise ``exact = 0`` if the camera centre is inside the ellipsoid, else 2.
    ``exact = 0`` too for non-finite input."""
    e = TileEllipse()
    e.exact = 0
    e.centre = wp.vec2d(mu[0] / mu[2], mu[1] / mu[2])
    zero = wp.float64(0.0)
    mx = wp.mat33d(zero, -mu[2], mu[1], mu[2], zero, -mu[0], -mu[1], mu[0], zero)  # [μ]ₓ d = μ × d
    s2 = wp.cw_mul(s, s)
    g = wp.vec3d(s2[1] * s2[2], s2[0] * s2[2], s2[0] * s2[1])
    G = R_v * wp.diag(g) * wp.transpose(R_v)
    Q = wp.transpose(mx) * Sigma * mx - k2 * G
    tol = wp.float64(CONIC_TOL) * (wp.dot(mu, mu) * (Sigma[0, 0] + Sigma[1, 1] + Sigma[2, 2]) + k2 * (G[0, 0] + G[1, 1] + G[2, 2]))
    q00 = Q[0, 0] - tol
    q11 = Q[1, 1] - tol
    q01 = wp.float64(0.5) * (Q[0, 1] + Q[1, 0])
    e.conic = vec6d(q00, q01, wp.float64(0.5) * (Q[0, 2] + Q[2, 0]), q11, wp.float64(0.5) * (Q[1, 2] + Q[2, 1]), Q[2, 2] - tol)
    total = e.conic[0] + e.conic[1] + e.conic[2] + e.conic[3] + e.conic[4] + e.conic[5]
    if not (total - total == zero):  # inf or nan somewhere: keep the rectangle
        return e
    if in_front:
        if q00 > zero and q11 > zero and q00 * q11 - q01 * q01 > zero:
            e.exact = 1
        else:
            e.exact = 2
        return e
    w = wp.transpose(R_v) * mu  # μ in the Gaussian's frame: μᵀ adj(Σ) μ = Σᵢ wᵢ² gᵢ, det Σ = s₀²s₁²s₂²
    if w[0] * w[0] * g[0] + w[1] * w[1] * g[1] + w[2] * w[2] * g[2] > k2 * s2[0] * g[0]:
        e.exact = 2  # camera outside: test the tiles
    return e


@wp.struct
class RayConic:
    """An elliptic silhouette in normalised image coordinates ``(a, b) = (x/z, y/z)`` for the per-pixel kernels' early
    reject (:func:`ray_conic`): the camera-space ray ``r`` (``r.z = 1``) passes outside iff
    ``A da² + 2B da db + C db² > 1`` with ``da = r.x − centre.x``, ``db = r.y − centre.y``, stored factored as
    ``conic = (A, β, γ)`` with ``β = B/A`` and ``γ = C − B²/A`` (``A (da + β db)² + γ db²``: a sum of two non-negative
    terms, which float32 evaluates to ~1e-3 of its value even for a 3000:1 needle, where the expanded form's terms
    cancel to an error of ~0.7). ``conic = 0`` never rejects."""

    conic: wp.vec3
    centre: wp.vec2


@wp.func
def ray_conic(e: TileEllipse) -> RayConic:
    """The silhouette of ``e`` (a :func:`tile_ellipse`) centred on the ellipse: with ``M`` its 2×2 part and
    ``q_c < 0`` its value at the centre ``c = −M⁻¹ (q02, q12)``, a ray is outside iff ``(r − c)ᵀ M (r − c) > −q_c``.
    Only a proper ellipse (``exact == 1``) gives one; anything else (a conic that is not an ellipse, non-finite values,
    an empty ellipse) gives ``conic = 0``, which rejects nothing. Centre-relative, so that float32 evaluation errs
    little."""
    out = RayConic()
    out.conic = wp.vec3(0.0)
    out.centre = wp.vec2(0.0)
    if e.exact != 1:
        return out
    c = e.conic
    zero = wp.float64(0.0)
    det = c[0] * c[3] - c[1] * c[1]
    if not (det > zero):
        return out
    ca = -(c[3] * c[2] - c[1] * c[4]) / det
    cb = (c[1] * c[2] - c[0] * c[4]) / det
    neg_qc = -(c[5] + c[2] * ca + c[4] * cb)
    if not (neg_qc > zero):
        return out
    A = c[0] / neg_qc
    B = c[1] / neg_qc
    C = c[3] / neg_qc
    total = A + B + C + ca + cb
    lim = wp.float64(1.0e30)
    if not (total - total == zero) or not (A > zero) or A > lim or C > lim or wp.abs(ca) > lim or wp.abs(cb) > lim:
        return out
    beta = B / A
    gamma = det / (c[0] * neg_qc)  # = C − B²/A, from the determinant (no cancellation)
    out.conic = wp.vec3(float(A), float(beta), float(gamma))
    out.centre = wp.vec2(float(ca), float(cb))
    return out


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
def tiles_pixel_rect(tx0: int, tx1: int, ty0: int, ty1: int, cam: CameraParams, settings: RasterSettings) -> wp.vec4d:
    """``(u0, u1, v0, v1)``: the pixel-coordinate rectangle of the tiles ``[tx0, tx1) × [ty0, ty1)`` — from the first
    tile's first in-image pixel centre to the last tile's last, grown by ``pixel_pad``."""
    ts = settings.tile_size
    half_pad = wp.float64(0.5) - wp.float64(wp.max(settings.pixel_pad, 0.0))  # centre 0.5, minus the pad
    return wp.vec4d(wp.float64(tx0 * ts) + half_pad, wp.float64(wp.min(tx1 * ts, cam.width)) - half_pad,
                    wp.float64(ty0 * ts) + half_pad, wp.float64(wp.min(ty1 * ts, cam.height)) - half_pad)  # fmt: skip


@wp.func
def tiles_rect(tx0: int, tx1: int, ty0: int, ty1: int, cam: CameraParams, settings: RasterSettings) -> wp.vec4d:
    """``(a0, a1, b0, b1)``: :func:`tiles_pixel_rect` in normalised coordinates."""
    u = tiles_pixel_rect(tx0, tx1, ty0, ty1, cam, settings)
    fx = wp.float64(cam.fx)
    fy = wp.float64(cam.fy)
    cx = wp.float64(cam.cx)
    cy = wp.float64(cam.cy)
    return wp.vec4d((u[0] - cx) / fx, (u[1] - cx) / fx, (u[2] - cy) / fy, (u[3] - cy) / fy)


@wp.func
def tile_meets_ellipse(e: TileEllipse, tx: int, ty: int, cam: CameraParams, settings: RasterSettings) -> bool:
    """Whether tile ``(tx, ty)`` — the centres of its in-image pixels, grown by ``pixel_pad`` — meets ``e``."""
    r = tiles_rect(tx, tx + 1, ty, ty + 1, cam, settings)
    return rect_meets_ellipse(e, r[0], r[1], r[2], r[3])


@wp.func
def row_tile_span_scan(e: TileEllipse, ty: int, x0: int, x1: int, cam: CameraParams, settings: RasterSettings) -> wp.vec2i:
    """Reference for :func:`row_tile_span` (tests and benchmarks): the same span found by testing tiles from both ends
    of ``[x0, x1)`` with :func:`tile_meets_ellipse` (up to ``x1 − x0`` float64 tests per row)."""
    if e.exact != 1:
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


# Relative widening of the closed-form row span (see :func:`row_tile_span`): ≫ the ~1e-8 relative error of a
# half-chord computed near a tangent point (√ of a float64 cancellation), ≪ a pixel.
SPAN_TOL = wp.constant(1.0e-6)


@wp.func
def row_tile_span(e: TileEllipse, ty: int, x0: int, x1: int, cam: CameraParams, settings: RasterSettings) -> wp.vec2i:
    """Half-open column range ``[lo, hi)`` of the tiles of row ``ty`` within ``[x0, x1)`` that are binned: from the
    first to the last tile that meets the ellipse (the tiles of a row that meet a convex set are contiguous), all of
    ``[x0, x1)`` unless ``e.exact == 1``, empty (``lo == hi``) when none meets it.

    Closed form, O(1) per row. With ``M`` the conic's 2×2 part, ``c`` its centre and ``q_c = q(c) < 0``, the filled
    ellipse is ``(x − c)ᵀM(x − c) ≤ −q_c``: it spans ``b_c ± h_b``, ``h_b = √(−q_c q00 / det M)``, and at
    ``β = b − b_c`` its chord is ``a_c + (−q01 β ± √(−q00 q_c − det M β²)) / q00``. The tile row is the strip
    ``b ∈ [b0, b1]`` of :func:`tiles_rect`; the ellipse's part in it projects onto ``a ∈ [a_lo, a_hi]``, where the
    left end ``a₋(β)`` is convex in β, so ``a_lo`` is its value at the leftmost point's ``β_L = t q01 / det M``
    (``t = √(−q_c det M / q11)``) clamped into the strip (likewise ``a_hi`` at ``β_R = −β_L``). A tile of the row
    meets the ellipse iff its column range meets ``[a_lo, a_hi]``, which gives ``lo`` and ``hi`` by a floor and a
    ceiling. The strip and ``[a_lo, a_hi]`` are widened by ``SPAN_TOL`` of the half-extents (plus 1e-9 px), far
    more than the rounding of these float64 formulas, so the span contains every tile that
    :func:`row_tile_span_scan` keeps (tested) and, but for that widening, no other."""
    if e.exact != 1:
        return wp.vec2i(x0, x1)
    c = e.conic
    zero = wp.float64(0.0)
    det = c[0] * c[3] - c[1] * c[1]
    a_c = (c[1] * c[4] - c[3] * c[2]) / det
    b_c = (c[1] * c[2] - c[0] * c[4]) / det
    q_c = c[5] + c[2] * a_c + c[4] * b_c
    if not (q_c < zero and det > zero):  # cannot happen for exact = 1 but rounding; keep the row
        return wp.vec2i(x0, x1)
    tol = wp.float64(SPAN_TOL)
    h_b = wp.sqrt(-q_c * c[0] / det)
    h_a = wp.sqrt(-q_c * c[3] / det)
    ts = settings.tile_size
    half_pad = wp.float64(0.5) - wp.float64(wp.max(settings.pixel_pad, 0.0))
    fx = wp.float64(cam.fx)
    fy = wp.float64(cam.fy)
    px_b = wp.float64(1.0e-9) / fy
    strip = tiles_rect(x0, x0 + 1, ty, ty + 1, cam, settings)
    b0 = strip[2]
    b1 = strip[3]
    grow_b = tol * h_b + px_b * (wp.float64(1.0) + wp.abs(b_c) * fy)
    lo_b = wp.max(b0, b_c - h_b - grow_b) - b_c
    hi_b = wp.min(b1, b_c + h_b + grow_b) - b_c
    if lo_b > hi_b:
        return wp.vec2i(x1, x1)
    t = wp.sqrt(-q_c * det / c[3])
    beta_l = wp.clamp(t * c[1] / det, lo_b, hi_b)
    beta_r = wp.clamp(-t * c[1] / det, lo_b, hi_b)
    chord_l = wp.sqrt(wp.max(-c[0] * q_c - det * beta_l * beta_l, zero))
    chord_r = wp.sqrt(wp.max(-c[0] * q_c - det * beta_r * beta_r, zero))
    grow_a = tol * h_a
    u_lo = (a_c + (-c[1] * beta_l - chord_l) / c[0] - grow_a) * fx + wp.float64(cam.cx)
    u_hi = (a_c + (-c[1] * beta_r + chord_r) / c[0] + grow_a) * fx + wp.float64(cam.cx)
    grow_u = wp.float64(1.0e-9) * (wp.float64(1.0) + wp.abs(u_lo) + wp.abs(u_hi))
    # tile tx's pixel centres (grown by the pad) span u ∈ [tx ts + half_pad, (tx + 1) ts − half_pad]
    lim = wp.float64(1.0e9)
    tsd = wp.float64(ts)
    lo = int(wp.ceil(wp.clamp((u_lo - grow_u - tsd + half_pad) / tsd, -lim, lim)))
    hi = int(wp.floor(wp.clamp((u_hi + grow_u - half_pad) / tsd, -lim, lim)))
    lo = wp.max(lo, x0)
    if tiles_pixel_rect(lo, lo + 1, ty, ty + 1, cam, settings)[1] < u_lo - grow_u:
        lo += 1  # the image's last tile column is clipped: its pixels end before u_lo
    hi = wp.min(hi + 1, x1)
    if lo >= hi:
        return wp.vec2i(x1, x1)
    return wp.vec2i(lo, hi)


@wp.struct
class ConicTest:
    """The general test's per-Gaussian constants (:func:`conic_test`), so that the many rectangle tests of one
    Gaussian multiply where they would divide."""

    conic: vec6d
    inv: wp.vec3d  # 1/q00, 1/q11, 1/det of the 2×2 part (each 0 unless that quantity is > 0)
    frame: wp.vec4d  # 1/fx, 1/fy, cx, cy: pixel → normalised coordinates


@wp.func
def conic_test(e: TileEllipse, cam: CameraParams) -> ConicTest:
    """:class:`ConicTest` of ``e`` under ``cam``."""
    c = e.conic
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    t = ConicTest()
    t.conic = c
    det = c[0] * c[3] - c[1] * c[1]
    inv = wp.vec3d(zero, zero, zero)
    if c[0] > zero:
        inv[0] = one / c[0]
    if c[3] > zero:
        inv[1] = one / c[3]
    if det > zero:
        inv[2] = one / det
    t.inv = inv
    t.frame = wp.vec4d(one / wp.float64(cam.fx), one / wp.float64(cam.fy), wp.float64(cam.cx), wp.float64(cam.cy))
    return t


@wp.func
def rect_meets_conic(t: ConicTest, a0: wp.float64, a1: wp.float64, b0: wp.float64, b1: wp.float64) -> bool:
    """Whether ``min q ≤ 0`` over the rectangle ``[a0, a1] × [b0, b1]`` for any conic (exact minimum of a 2-D
    quadratic over a rectangle: corners, convex edge vertices, positive definite interior minimum). The candidate
    points are computed with ``t``'s reciprocals and clamped into the rectangle, so each is a point of it (a valid
    witness), and at each the rounding of its position changes ``q`` only to second order (``q`` is stationary
    there along the free directions): far inside the conic's allowance."""
    c = t.conic
    zero = wp.float64(0.0)
    if conic_at(c, a0, b0) <= zero or conic_at(c, a1, b0) <= zero or conic_at(c, a0, b1) <= zero or conic_at(c, a1, b1) <= zero:
        return True
    if c[3] > zero:  # vertical edges a = a0, a1: convex in b, smallest at b = −(q01 a + q12)/q11
        if conic_at(c, a0, wp.clamp(-(c[1] * a0 + c[4]) * t.inv[1], b0, b1)) <= zero:
            return True
        if conic_at(c, a1, wp.clamp(-(c[1] * a1 + c[4]) * t.inv[1], b0, b1)) <= zero:
            return True
    if c[0] > zero:  # horizontal edges b = b0, b1: convex in a, smallest at a = −(q01 b + q02)/q00
        if conic_at(c, wp.clamp(-(c[1] * b0 + c[2]) * t.inv[0], a0, a1), b0) <= zero:
            return True
        if conic_at(c, wp.clamp(-(c[1] * b1 + c[2]) * t.inv[0], a0, a1), b1) <= zero:
            return True
    if c[0] > zero and c[3] > zero and t.inv[2] > zero:  # interior minimum of q (a point of the rectangle once clamped)
        a = wp.clamp((c[1] * c[4] - c[3] * c[2]) * t.inv[2], a0, a1)
        b = wp.clamp((c[1] * c[2] - c[0] * c[4]) * t.inv[2], b0, b1)
        return conic_at(c, a, b) <= zero
    return False


@wp.func
def tiles_rect_normalised(t: ConicTest, tx0: int, tx1: int, ty0: int, ty1: int, cam: CameraParams, settings: RasterSettings) -> wp.vec4d:
    """:func:`tiles_rect` with ``t``'s reciprocal focal lengths (a rounding's difference: covered by the allowance)."""
    u = tiles_pixel_rect(tx0, tx1, ty0, ty1, cam, settings)
    f = t.frame
    return wp.vec4d((u[0] - f[2]) * f[0], (u[1] - f[2]) * f[0], (u[2] - f[3]) * f[1], (u[3] - f[3]) * f[1])


@wp.func
def tiles_meet_conic(t: ConicTest, tx0: int, tx1: int, ty0: int, ty1: int, cam: CameraParams, settings: RasterSettings) -> bool:
    """Whether the hull of tiles ``[tx0, tx1) × [ty0, ty1)`` (from the first tile's first in-image pixel centre to
    the last tile's last, grown by ``pixel_pad``) meets ``{q ≤ 0}``."""
    r = tiles_rect_normalised(t, tx0, tx1, ty0, ty1, cam, settings)
    return rect_meets_conic(t, r[0], r[1], r[2], r[3])


CONIC_BLOCK = wp.constant(8)  # tiles per side of the blocks of the general test (8 × 8 = 64 mask bits)


@wp.func
def tiles_inside_conic(t: ConicTest, tx0: int, tx1: int, ty0: int, ty1: int, cam: CameraParams, settings: RasterSettings) -> bool:
    """A shortcut of :func:`conic_block_mask`: whether ``q ≤ 0`` on the whole hull of tiles ``[tx0, tx1) × [ty0, ty1)``,
    decided only when ``q`` is convex (2×2 part positive semi-definite: its maximum over a rectangle is at a corner,
    so four corners decide); ``False`` otherwise. Every tile of such a hull meets the conic, so its per-tile tests
    can be skipped (a tile they would drop within rounding of the conic's edge is kept: an extra entry, skipped by
    the per-pixel test)."""
    c = t.conic
    zero = wp.float64(0.0)
    if not (c[0] >= zero and c[3] >= zero and c[0] * c[3] - c[1] * c[1] >= zero):
        return False
    r = tiles_rect_normalised(t, tx0, tx1, ty0, ty1, cam, settings)
    return (conic_at(c, r[0], r[2]) <= zero and conic_at(c, r[1], r[2]) <= zero and conic_at(c, r[0], r[3]) <= zero
            and conic_at(c, r[1], r[3]) <= zero)  # fmt: skip


@wp.func
def conic_block_mask(t: ConicTest, bx: int, by: int, x1: int, y1: int, cam: CameraParams, settings: RasterSettings) -> wp.uint64:
    """``exact = 2`` (``t = conic_test(e, cam)``): the tiles of the block ``[bx, min(bx + 8, x1)) × [by, min(by + 8,
    y1))`` that meet the conic, bit ``8 (ty − by) + (tx − bx)``. The block hull, then each row segment, then each
    tile is tested (a hull that misses the conic contains no tile that meets it); a hull, or a row, on which the
    conic is ``≤ 0`` throughout (:func:`tiles_inside_conic`) has all its tiles set without testing them one by one."""
    ex = wp.min(bx + CONIC_BLOCK, x1)
    ey = wp.min(by + CONIC_BLOCK, y1)
    mask = wp.uint64(0)
    if not tiles_meet_conic(t, bx, ex, by, ey, cam, settings):
        return mask
    row_bits = (wp.uint64(1) << wp.uint64(ex - bx)) - wp.uint64(1)  # the block's tiles of one row
    whole = tiles_inside_conic(t, bx, ex, by, ey, cam, settings)
    for ty in range(by, ey):
        shift = wp.uint64(CONIC_BLOCK * (ty - by))
        if whole:
            mask = mask | (row_bits << shift)
        elif ey - by == 1 or tiles_meet_conic(t, bx, ex, ty, ty + 1, cam, settings):
            if ex - bx > 1 and tiles_inside_conic(t, bx, ex, ty, ty + 1, cam, settings):
                mask = mask | (row_bits << shift)
            else:
                for tx in range(bx, ex):
                    if ex - bx == 1 or tiles_meet_conic(t, tx, tx + 1, ty, ty + 1, cam, settings):
                        mask = mask | (wp.uint64(1) << (shift + wp.uint64(tx - bx)))
    return mask
