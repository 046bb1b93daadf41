"""Float64 brute-force reference of the GOF renderer (``/work/briefs/render_spec.md``), for tests only.

Every Gaussian is intersected with every pixel ray (no tiling, no binning), in camera space, with plain
torch ops in float64, so that autograd gives the exact derivative of the spec's formulas with the spec's
gradient conventions:

* the ``alpha_max`` clamp and the exponent clamp use the true derivative (0 where the clamp is active);
* the median depth carries gradient only through the chosen Gaussian's ``t*`` (gathered at a detached
  index);
* the distortion uses detached weights, so its gradient flows only through the ``t*``.

Only the front-to-back compositing loop over the depth-sorted Gaussians runs in Python; everything else is
vectorised over ``[pixels, Gaussians]``. Importable from test files anywhere under ``tests/`` as
``from reference_render import ...`` (``tests/conftest.py`` puts ``tests/`` on ``sys.path``).

Shapes: ``means [N,3]`` world, ``quats [N,4]`` wxyz (used as given: normalise before calling),
``scales [N,3]`` activated, ``opacities [N]`` activated, ``sh [N,K,3]``; outputs ``[H,W,...]`` float64.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)
OUTPUT_NAMES = ("rgb", "alpha", "depth", "accum_depth", "median_depth", "normal", "distortion")


@dataclass(frozen=True)
class RefConfig:
    """The spec's ``RenderConfig`` fields the reference reads (any object with these attributes works)."""

    near: float = 0.2
    alpha_min: float = 1.0 / 255.0
    alpha_max: float = 0.99
    transmittance_min: float = 1e-4
    k_max: float = math.sqrt(2.0 * math.log(255.0))
    background: tuple = (0.0, 0.0, 0.0)
    distortion: str = "gof"  # "gof": Σ_{j<k} w_k w_j (m_k − m_j)² on NDC depth m; "paper": Σ 2 w_k w_j (t_k − t_j)
    far: float = 100.0
    distortion_linear_from: float = 0.0  # > 0: m(t) continued by its tangent beyond this depth ("gof" only)
    ndc_near: float | None = None  # near plane of m(t) when it differs from the clipping depth ``near``


def distortion_depth(t, config):
    """The depth the distortion compares: NDC ``m(t) = far (t − near)/((far − near) t)`` ("gof") or ``t``; with
    ``distortion_linear_from = L > 0``, ``m(L) + m'(L) (t − L)`` beyond ``L``."""
    if getattr(config, "distortion", "gof") == "gof":
        n, fa = getattr(config, "ndc_near", None) or config.near, config.far
        m = fa * (t - n) / ((fa - n) * t)
        L = getattr(config, "distortion_linear_from", 0.0)
        if L > 0:
            tangent = fa * (L - n) / ((fa - n) * L) + fa * n / ((fa - n) * L * L) * (t - L)
            m = torch.where(t > L, tangent, m) if isinstance(t, torch.Tensor) else (tangent if t > L else m)
        return m
    return t


#: Thresholds off, as the spec prescribes for gradient checks.
GRADCHECK_CONFIG = RefConfig(alpha_min=0.0, transmittance_min=0.0, k_max=10.0)


def f64(x) -> torch.Tensor:
    """A detached float64 CPU copy of ``x`` (tensor or array-like)."""
    if isinstance(x, torch.Tensor):
        return x.detach().to(device="cpu", dtype=torch.float64).clone()
    return torch.as_tensor(x, dtype=torch.float64).clone()


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """``[N,4]`` wxyz unit quaternions → ``[N,3,3]`` rotations (columns = local axes in world)."""
    w, x, y, z = q.unbind(-1)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return torch.stack([torch.stack(r, -1) for r in rows], -2)


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """3DGS real SH basis at unit ``dirs [...,3]`` → ``[..., (degree+1)^2]``."""
    x, y, z = dirs.unbind(-1)
    b = [torch.full_like(x, SH_C0)]
    if degree > 0:
        b += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree > 1:
        xx, yy, zz = x * x, y * y, z * z
        b += [
            SH_C2[0] * x * y,
            SH_C2[1] * y * z,
            SH_C2[2] * (2 * zz - xx - yy),
            SH_C2[3] * x * z,
            SH_C2[4] * (xx - yy),
        ]
    if degree > 2:
        b += [
            SH_C3[0] * y * (3 * xx - yy),
            SH_C3[1] * x * y * z,
            SH_C3[2] * y * (4 * zz - xx - yy),
            SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            SH_C3[4] * x * (4 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(b, -1)


def sh_to_color(sh: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Colour ``max(0, SH(dir) + 0.5)``; ``sh [N,K,3]``, ``dirs [...,N,3]`` (unit) → ``[...,N,3]``."""
    basis = sh_basis(dirs, degree)  # [..., N, k]
    k = basis.shape[-1]
    return torch.clamp((basis.unsqueeze(-1) * sh[:, :k, :]).sum(-2) + 0.5, min=0.0)


class RefCamera:
    """Float64 torch view of a ``gof_warp.core.camera.Camera`` (or any object with its attributes)."""

    def __init__(self, camera):
        self.R = f64(camera.R)
        self.t = f64(camera.t)
        self.fx, self.fy = float(camera.fx), float(camera.fy)
        self.cx, self.cy = float(camera.cx), float(camera.cy)
        self.W, self.H = int(camera.width), int(camera.height)
        self.center = -self.R.T @ self.t

    def rays(self) -> torch.Tensor:
        """``[H*W, 3]`` camera-space pixel rays (z = 1), row-major (pixel (i, j) at ``j*W + i``)."""
        i = (torch.arange(self.W, dtype=torch.float64) + 0.5 - self.cx) / self.fx
        j = (torch.arange(self.H, dtype=torch.float64) + 0.5 - self.cy) / self.fy
        jj, ii = torch.meshgrid(j, i, indexing="ij")
        return torch.stack([ii, jj, torch.ones_like(ii)], -1).reshape(-1, 3)

    def to_camera(self, x: torch.Tensor) -> torch.Tensor:
        return x @ self.R.T + self.t

    def to_world(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.t) @ self.R


def _ray_gaussian(mu_v, R_v, scales, rays):
    """Ray–Gaussian quantities in camera space (ray origin 0).

    ``mu_v [P|1,N,3]``, ``R_v [N,3,3]``, ``scales [N,3]``, ``rays [P,3]`` → ``t* , d² [P,N]``,
    ``n̂ [P,N,3]`` (unit normal facing the camera).
    """
    inv_s = 1.0 / scales
    o_g = -torch.einsum("nji,pnj->pni", R_v, mu_v) * inv_s  # S⁻¹ R_vᵀ (0 − μ_v)
    r_g = torch.einsum("nji,pj->pni", R_v, rays) * inv_s  # S⁻¹ R_vᵀ r
    A = (r_g * r_g).sum(-1)
    B = (o_g * r_g).sum(-1)
    C = (o_g * o_g).sum(-1)
    n = -torch.einsum("nij,pnj->pni", R_v, r_g * inv_s)  # −(R_v S⁻¹) r_g
    return -B / A, C - B * B / A, n / n.norm(dim=-1, keepdim=True)


def _composite(order, alpha, valid, t, colors, normals, background, transmittance_min, config):
    """Front-to-back compositing of the sorted Gaussians; returns per-pixel sums and the margins."""
    P = alpha.shape[0]
    T = torch.ones(P, dtype=torch.float64)
    done = torch.zeros(P, dtype=torch.bool)
    found = torch.zeros(P, dtype=torch.bool)
    med_idx = torch.full((P,), -1, dtype=torch.long)
    rgb = torch.zeros(P, 3, dtype=torch.float64)
    normal = torch.zeros(P, 3, dtype=torch.float64)
    accum = torch.zeros(P, dtype=torch.float64)
    dist = torch.zeros(P, dtype=torch.float64)
    A_prev = torch.zeros(P, dtype=torch.float64)  # Σ_{j<k} w_j (detached)
    B_prev = torch.zeros(P, dtype=torch.float64)  # Σ_{j<k} w_j f_j (w detached, f = distortion depth)
    C_prev = torch.zeros(P, dtype=torch.float64)  # Σ_{j<k} w_j f_j²
    squared = getattr(config, "distortion", "gof") == "gof"
    margin = torch.full((P,), math.inf, dtype=torch.float64)
    weights = [None] * alpha.shape[1]
    for k in order.tolist():
        a, tk = alpha[:, k], t[:, k]
        ok = valid[:, k] & ~done
        T_next_if = T * (1.0 - a)
        if transmittance_min > 0:
            rel = ((T_next_if.detach() - transmittance_min).abs() / transmittance_min)
            margin = torch.where(ok, torch.minimum(margin, rel), margin)
        stop = ok & (T_next_if.detach() < transmittance_min)
        done = done | stop
        blend = ok & ~stop
        w = torch.where(blend, a * T, torch.zeros_like(T))
        weights[k] = w
        c = colors[:, k] if colors.shape[0] == P else colors[0, k].expand(P, 3)
        rgb = rgb + w[:, None] * c
        normal = normal + w[:, None] * normals[:, k]
        accum = accum + w * tk
        wd = w.detach()
        fk = distortion_depth(tk, config)
        if squared:
            dist = dist + wd * (fk * fk * A_prev - 2.0 * fk * B_prev + C_prev)
        else:
            dist = dist + 2.0 * wd * (fk * A_prev - B_prev)
        A_prev = A_prev + wd
        B_prev = B_prev + wd * fk
        C_prev = C_prev + wd * fk * fk
        T = torch.where(blend, T_next_if, T)
        margin = torch.where(blend, torch.minimum(margin, (T.detach() - 0.5).abs() / 0.5), margin)
        med_idx = torch.where(blend & ~found, torch.full_like(med_idx, k), med_idx)
        found = found | (blend & (T.detach() <= 0.5))
    has = med_idx >= 0
    median = torch.gather(t, 1, med_idx.clamp(min=0)[:, None])[:, 0] * has
    rgb = rgb + T[:, None] * background
    w_all = torch.stack(weights, -1) if weights else torch.zeros(P, 0, dtype=torch.float64)
    return dict(rgb=rgb, T=T, accum=accum, median=median, normal=normal, dist=dist, margin=margin, w=w_all)


def _threshold_margin(z, t, d2, a, config):
    """Per-pixel minimum relative distance of any per-(pixel, Gaussian) decision from its threshold."""
    near, k2 = config.near, config.k_max**2
    m = torch.minimum((t - near).abs() / near, (d2 - k2).abs() / k2)
    if config.alpha_min > 0:
        m = torch.minimum(m, (a - config.alpha_min).abs() / config.alpha_min)
    m = torch.where((z > near)[None, :], m, torch.full_like(m, math.inf))
    return m.min(dim=1).values if m.shape[1] else torch.full((m.shape[0],), math.inf, dtype=torch.float64)


def reference_render(means, quats, scales, opacities, sh, camera, sh_degree=None, config=None, screen_offsets=None,
                     offsets_move_colour=True):
    """Render with the spec's math in float64.

    Args:
        means, quats, scales, opacities, sh: see module docstring (any dtype; used in float64 — pass
            float64 leaf tensors with ``requires_grad`` to get gradients).
        camera: ``gof_warp.core.camera.Camera``.
        sh_degree: active SH degree (default: the maximum the coefficients hold).
        config: an object with ``near, alpha_min, alpha_max, transmittance_min, k_max, background``
            (default :class:`RefConfig`).
        screen_offsets: optional ``[H*W, N, 2]`` per-pixel screen-space (pixel units) offsets of the
            projected means with depth held fixed (used by :func:`reference_densify_stats`).
        offsets_move_colour: whether those offsets also move the SH viewing direction (the literal
            spec) or only the ray–Gaussian geometry (3DGS's ``means2D`` convention).

    Returns:
        dict of ``[H,W,...]`` float64 outputs (``OUTPUT_NAMES``) plus ``margin [H,W]``: the smallest
        relative distance of any discrete decision (near test, k_max test, alpha_min skip, transmittance
        stop, the median's T = 0.5 crossing) from its threshold in that pixel (inf if none);
        ``weights [H,W,N]`` (blending weights w_k by Gaussian index, 0 where not blended) and
        ``t_star [H,W,N]`` (every ray–Gaussian intersection depth) for tests.
    """
    config = RefConfig() if config is None else config
    cam = RefCamera(camera)
    means, quats, scales, opacities, sh = (x if x.dtype == torch.float64 else x.double() for x in (means, quats, scales, opacities, sh))
    degree = int(round(math.sqrt(sh.shape[1]))) - 1 if sh_degree is None else int(sh_degree)
    rays = cam.rays()
    mu_v = cam.to_camera(means)[None]  # [1,N,3]
    z = mu_v[0, :, 2].detach()
    mu_colour = mu_v
    if screen_offsets is not None:
        step = torch.tensor([cam.fx, cam.fy], dtype=torch.float64)
        shift = screen_offsets * (z[None, :, None] / step)  # ∂μ_v/∂(u,v) = (z/fx, z/fy) at fixed z
        mu_v = mu_v + torch.cat([shift, torch.zeros_like(shift[..., :1])], -1)
        mu_colour = mu_v if offsets_move_colour else mu_colour
    dirs = cam.to_world(mu_colour) - cam.center
    colors = sh_to_color(sh, dirs / dirs.norm(dim=-1, keepdim=True), degree)  # [P|1,N,3]
    R_v = cam.R @ quat_to_rotmat(quats)
    t, d2, normals = _ray_gaussian(mu_v, R_v, scales, rays)
    alpha = torch.clamp(opacities[None] * torch.exp(-0.5 * torch.clamp(d2, min=0.0)), max=config.alpha_max)
    valid = (z > config.near)[None] & (t > config.near) & (d2 <= config.k_max**2) & (alpha >= config.alpha_min)
    order = torch.argsort(z, stable=True)
    bg = f64(config.background)
    comp = _composite(order, alpha, valid, t, colors, normals, bg, config.transmittance_min, config)
    a_out = 1.0 - comp["T"]
    safe = torch.where(a_out > 0, a_out, torch.ones_like(a_out))
    depth = torch.where(a_out > 0, comp["accum"] / safe, torch.zeros_like(a_out))
    margin = torch.minimum(comp["margin"], _threshold_margin(z, t.detach(), d2.detach(), alpha.detach(), config))
    H, W = cam.H, cam.W
    out = dict(
        rgb=comp["rgb"].reshape(H, W, 3),
        alpha=a_out.reshape(H, W),
        depth=depth.reshape(H, W),
        accum_depth=comp["accum"].reshape(H, W),
        median_depth=comp["median"].reshape(H, W),
        normal=comp["normal"].reshape(H, W, 3),
        distortion=comp["dist"].reshape(H, W),
        margin=margin.reshape(H, W),
        weights=comp["w"].reshape(H, W, -1),
        t_star=t.reshape(H, W, -1),
    )
    return out


def weighted_loss(out: dict, weights: dict) -> torch.Tensor:
    """``Σ_name Σ W_name ⊙ out[name]`` over the names in ``weights`` (a scalar)."""
    return sum((out[k] * weights[k].to(out[k].dtype)).sum() for k in weights)


def reference_densify_stats(means, quats, scales, opacities, sh, camera, weights, sh_degree=None, config=None,
                            through_colour=True):
    """The spec's densification statistics for the loss ``weighted_loss(out, weights)``.

    Each pixel gets its own copy of every projected mean (``screen_offsets`` at 0), so one backward
    pass yields every per-pixel gradient ``∂L_p/∂(u_k, v_k)`` at once. ``through_colour=False`` leaves
    the SH viewing direction fixed (only the ray–Gaussian geometry moves, as 3DGS's ``means2D``);
    with SH degree 0 both agree.

    Returns:
        ``grad2d [N,2]`` = Σ_p g_p and ``grad2d_abs [N]`` = Σ_p ‖g_p‖₂ with g_p in NDC units (×W/2, ×H/2).
    """
    cam = RefCamera(camera)
    args = [f64(x) for x in (means, quats, scales, opacities, sh)]
    offsets = torch.zeros(cam.H * cam.W, args[0].shape[0], 2, dtype=torch.float64, requires_grad=True)
    out = reference_render(*args, camera, sh_degree=sh_degree, config=config, screen_offsets=offsets,
                           offsets_move_colour=through_colour)
    (g,) = torch.autograd.grad(weighted_loss(out, weights), offsets)
    g = g * torch.tensor([cam.W / 2.0, cam.H / 2.0], dtype=torch.float64)
    return g.sum(0), g.norm(dim=-1).sum(0)


def reference_screen_boxes(means, quats, scales, opacities, camera, config=None):
    """Exact screen bounding boxes of the binning ellipsoids (spec, "Tile binning").

    The ellipsoid ``‖S⁻¹Rᵀ(x−μ)‖ ≤ k`` with ``k = min(k_max, sqrt(2 ln(opacity/alpha_min)))``; its image-x
    extent is bounded by the planes ``x = u' z`` through the camera tangent to it:
    ``(μx − u'μz)² = k² (Σxx − 2u'Σxz + u'²Σzz)``, a quadratic in ``u'`` (same for y).

    Returns:
        ``box [N,4]`` (u_min, u_max, v_min, v_max) in pixels, unclipped (NaN where not applicable);
        ``status [N]`` int: 0 = culled/invisible, 1 = exact box, 2 = whole-image fallback (ellipsoid
        reaches the plane z = near).
    """
    config = RefConfig() if config is None else config
    cam = RefCamera(camera)
    means, quats, scales, opacities = (f64(x) for x in (means, quats, scales, opacities))
    mu = cam.to_camera(means)
    R_v = cam.R @ quat_to_rotmat(quats)
    Sigma = R_v @ torch.diag_embed(scales**2) @ R_v.transpose(1, 2)
    if config.alpha_min > 0:
        ratio = torch.clamp(opacities / config.alpha_min, min=1.0)
        k = torch.clamp(torch.sqrt(2.0 * torch.log(ratio)), max=config.k_max)
    else:
        k = torch.full_like(opacities, config.k_max)
    k2 = k * k
    box = torch.full((means.shape[0], 4), math.nan, dtype=torch.float64)
    for axis, (f, c) in enumerate(((cam.fx, cam.cx), (cam.fy, cam.cy))):
        a = mu[:, 2] ** 2 - k2 * Sigma[:, 2, 2]
        b = -2.0 * (mu[:, axis] * mu[:, 2] - k2 * Sigma[:, axis, 2])
        cc = mu[:, axis] ** 2 - k2 * Sigma[:, axis, axis]
        disc = torch.sqrt(torch.clamp(b * b - 4 * a * cc, min=0.0))
        lo, hi = (-b - disc) / (2 * a), (-b + disc) / (2 * a)
        box[:, 2 * axis] = f * lo + c
        box[:, 2 * axis + 1] = f * hi + c
    reaches_near = mu[:, 2] - k * torch.sqrt(Sigma[:, 2, 2]) <= config.near
    visible = (mu[:, 2] > config.near) & (k > 0)
    status = torch.where(visible, torch.where(reaches_near, 2, 1), 0)
    box[status != 1] = math.nan
    return box, status


def make_camera(width=37, height=29, fx=41.0, fy=35.0, cx=None, cy=None, eye=(0.4, -2.6, 0.9), target=(0.1, 0.2, 0.3)):
    """A test camera with an off-centre principal point and non-square pixels by default."""
    from gof_warp.core.camera import look_at

    cx = 0.43 * width if cx is None else cx
    cy = 0.58 * height if cy is None else cy
    return look_at(eye, target, up=(0.0, 0.0, 1.0), fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height)


def random_scene(camera, n, sh_degree, seed, n_behind=1, n_near=1, spread=1.3, opacity_range=(0.05, 0.95), scale_factor=1.0):
    """Random Gaussians (float64 leaf tensors) for ``camera``.

    Most lie in front (depth 1.5–5) over a screen area ``spread`` times the image (so some straddle or
    leave the border); ``n_behind`` lie behind the camera; ``n_near`` straddle the near plane (centre depth
    0.35–0.6, scales large enough for the ellipsoid to cross z = 0.2). Scales are anisotropic, quaternions
    random (normalised) and multiplied by ``scale_factor``, SH coefficients of degree ``sh_degree`` random with a DC term giving mid colours.
    """
    g = torch.Generator().manual_seed(seed)
    cam = RefCamera(camera)

    def rand(*shape):
        return torch.rand(*shape, generator=g, dtype=torch.float64)

    z = 1.5 + 3.5 * rand(n)
    z[:n_behind] = -0.5 - 2.0 * rand(n_behind)
    z[n_behind : n_behind + n_near] = 0.35 + 0.25 * rand(n_near)
    u = cam.cx + (rand(n) - 0.5) * spread * cam.W
    v = cam.cy + (rand(n) - 0.5) * spread * cam.H
    mu_v = torch.stack([(u - cam.cx) / cam.fx * z.abs(), (v - cam.cy) / cam.fy * z.abs(), z], -1)
    scales = (0.04 + 0.3 * rand(n, 3)) * (0.3 + 0.2 * z.abs())[:, None] * scale_factor
    scales[n_behind : n_behind + n_near] = 0.2 + 0.2 * rand(n_near, 3)
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    quats = quats / quats.norm(dim=-1, keepdim=True)
    lo, hi = opacity_range
    opacities = lo + (hi - lo) * rand(n)
    sh = 0.4 * torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g, dtype=torch.float64)
    sh[:, 0] = (rand(n, 3) - 0.5) / SH_C0 * 0.8
    return dict(means=cam.to_world(mu_v), quats=quats, scales=scales, opacities=opacities, sh=sh)
