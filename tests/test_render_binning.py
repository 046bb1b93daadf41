"""Tile binning of the Warp renderer: the exact screen box of each Gaussian's binning ellipsoid against an
independent float64 numpy computation (the dual conic of the projected quadric), and completeness: every
(pixel, Gaussian) pair that the per-pixel rule can blend, found by float64 brute force over all pairs, is
in that pixel's tile list; the lists are sorted by depth (ties by index)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from gof_warp.camera import look_at
from gof_warp.kernels.binning import bin_gaussians
from gof_warp.kernels.project import preprocess_gaussians, screen_bounds
from gof_warp.kernels.render_types import camera_params_from, make_raster_settings

K_MAX = math.sqrt(2.0 * math.log(255.0))
BOX_TOL_PX = 1e-3  # float32 camera/parameters vs float64: the box edges agree to far below a pixel here
CAMERA = dict(fx=38.0, fy=33.0, cx=21.3, cy=19.1, width=45, height=37)  # 3x3 tiles, partial border tiles


def _rotations(q):
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], 1)  # fmt: skip


def _scene(cam, n, seed, kind):
    """Gaussians (float32-representable float64 arrays) of one of the stress kinds."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(1.0, 4.0, n)
    spread = 1.6 if kind == "border" else 1.0  # "border": centres up to 30 % outside the image
    u = cam.cx + (rng.uniform(size=n) - 0.5) * spread * cam.width
    v = cam.cy + (rng.uniform(size=n) - 0.5) * spread * cam.height
    if kind == "near_plane":  # centres around the near plane: straddling (fallback box) or culled
        z = rng.uniform(0.05, 0.6, n)
    mu_v = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], -1)
    scales = rng.uniform(0.02, 0.15, (n, 3)) * z[:, None]
    if kind == "anisotropic":  # needles and discs, up to 100:1
        scales[:, 0] *= 10.0
        scales[:, 1] *= 0.1
    if kind == "near_plane":
        scales = rng.uniform(0.05, 0.4, (n, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    means = (mu_v - cam.t) @ cam.R
    opac = rng.uniform(0.02, 1.0, n)
    f32 = lambda a: a.astype(np.float32).astype(np.float64)  # noqa: E731
    return f32(means), f32(q), f32(scales), f32(opac)


def _run_binning(cam, means, quats, scales, opac, **cfg):
    settings = make_raster_settings(cam.width, cam.height, **cfg)
    camp = camera_params_from(cam)
    n = len(means)
    arr = lambda a, t: wp.array(a.astype(np.float32), dtype=t, device="cpu")  # noqa: E731
    sh = wp.zeros((n, 1), dtype=wp.vec3, device="cpu")
    mu_v, P, o_g, col = (wp.empty(n, dtype=t, device="cpu") for t in (wp.vec3, wp.mat33, wp.vec3, wp.vec3))
    wp.launch(preprocess_gaussians, n, inputs=[arr(means, wp.vec3), arr(quats, wp.vec4), arr(scales, wp.vec3), sh, 0, camp.R, camp.t, camp.centre],
              outputs=[mu_v, P, o_g, col], device="cpu")  # fmt: skip
    rect, touched, radii, depth = (wp.empty(n, dtype=t, device="cpu") for t in (wp.vec4i, wp.int32, wp.int32, float))
    wp.launch(screen_bounds, n, inputs=[mu_v, arr(quats, wp.vec4), arr(scales, wp.vec3), arr(opac, float), camp, settings],
              outputs=[rect, touched, radii, depth], device="cpu")  # fmt: skip
    values, start, end, count = bin_gaussians(rect, touched, depth, settings.tiles_x, settings.tiles_x * settings.tiles_y)
    lists = [values.numpy()[s:e] for s, e in zip(start.numpy(), end.numpy())]
    return dict(rect=rect.numpy(), radii=radii.numpy(), depth=depth.numpy(), lists=lists, count=count, settings=settings)


def _binning_k(opac, alpha_min, k_max):
    if alpha_min <= 0:
        return np.full_like(opac, k_max)
    return np.minimum(k_max, np.sqrt(2 * np.log(np.maximum(opac / alpha_min, 1.0))))


def _dual_conic_boxes(cam, means, quats, scales, k):
    """Screen boxes from the dual conic ``C* = K (k²Σ − μμᵀ) Kᵀ``: the image lines ``l`` tangent to the
    ellipsoid's outline satisfy ``lᵀ C* l = 0``; for the column ``u``, ``l = (1, 0, −u)``."""
    mu = cam.to_camera(means)
    Rv = cam.R @ _rotations(quats)
    boxes = np.full((len(means), 4), np.nan)
    for g in range(len(means)):
        Sigma = Rv[g] @ np.diag(scales[g] ** 2) @ Rv[g].T
        C = cam.K @ (k[g] ** 2 * Sigma - np.outer(mu[g], mu[g])) @ cam.K.T
        for axis in (0, 1):  # C[a,a] − 2u C[a,2] + u² C[2,2] = 0
            roots = np.roots([C[2, 2], -2 * C[axis, 2], C[axis, axis]])
            boxes[g, 2 * axis : 2 * axis + 2] = np.sort(roots.real)
    return boxes


def test_exact_box_matches_dual_conic():
    cam = look_at((0.3, -2.0, 0.5), (0.0, 0.0, 0.0), **CAMERA)
    means, quats, scales, opac = _scene(cam, 300, seed=1, kind="border")  # rotated, up to 7:1, off-image
    res = _run_binning(cam, means, quats, scales, opac)
    k = _binning_k(opac, 1 / 255, K_MAX)
    mu = cam.to_camera(means)
    Sigma_zz = np.einsum("ni,ni->n", (cam.R @ _rotations(quats))[:, 2, :] ** 2, scales**2)
    exact = (mu[:, 2] - k * np.sqrt(Sigma_zz) > 0.2) & (k > 0)
    assert exact.sum() > 250  # the case exercises the exact box (not the whole-image fallback)
    boxes = _dual_conic_boxes(cam, means, quats, scales, k)
    ts = 16
    checked = 0
    for g in np.nonzero(exact)[0]:
        u0, u1, v0, v1 = boxes[g]
        # pixel ranges whose centres lie in the box, with the box grown/shrunk by the tolerance
        outer = [math.ceil(u0 - 0.5 - BOX_TOL_PX), math.floor(u1 - 0.5 + BOX_TOL_PX), math.ceil(v0 - 0.5 - BOX_TOL_PX), math.floor(v1 - 0.5 + BOX_TOL_PX)]
        inner = [math.ceil(u0 - 0.5 + BOX_TOL_PX), math.floor(u1 - 0.5 - BOX_TOL_PX), math.ceil(v0 - 0.5 + BOX_TOL_PX), math.floor(v1 - 0.5 - BOX_TOL_PX)]

        def tiles(b):
            x0, x1 = max(b[0], 0), min(b[1], cam.width - 1)
            y0, y1 = max(b[2], 0), min(b[3], cam.height - 1)
            if x0 > x1 or y0 > y1:
                return None
            return (x0 // ts, y0 // ts, x1 // ts + 1, y1 // ts + 1)

        got = tuple(res["rect"][g]) if res["rect"][g][2] > res["rect"][g][0] else None
        if tiles(outer) == tiles(inner):  # no tile decision within the tolerance of a pixel centre
            assert got == tiles(outer), (g, got, tiles(outer))
            if got is not None:
                assert abs(res["radii"][g] - max(u1 - u0, v1 - v0) / 2) <= 1.0 + 1e-3
            checked += 1
    assert checked > 250


def _brute_force_pairs(cam, means, quats, scales, opac, near, alpha_min, k_max):
    """All (pixel index, Gaussian) pairs the per-pixel rule keeps, in float64 (spec's formulas)."""
    mu = cam.to_camera(means)
    Rv = cam.R @ _rotations(quats)
    jj, ii = np.meshgrid(np.arange(cam.height), np.arange(cam.width), indexing="ij")
    r = np.stack([(ii + 0.5 - cam.cx) / cam.fx, (jj + 0.5 - cam.cy) / cam.fy, np.ones_like(ii, dtype=float)], -1).reshape(-1, 3)
    P = np.transpose(Rv, (0, 2, 1)) / scales[:, :, None]  # S⁻¹ R_vᵀ
    o_g = -np.einsum("nij,nj->ni", P, mu)
    r_g = np.einsum("nij,pj->pni", P, r)
    A = (r_g**2).sum(-1)
    B = (o_g[None] * r_g).sum(-1)
    C = (o_g**2).sum(-1)[None]
    t = -B / A
    d2 = C - B * B / A
    alpha = np.minimum(0.99, opac[None] * np.exp(-0.5 * np.maximum(d2, 0)))
    keep = (mu[None, :, 2] > near) & (t > near) & (d2 <= k_max**2) & (alpha >= alpha_min)
    return np.argwhere(keep)


BINNING_CASES = {
    "anisotropic": dict(),
    "border": dict(),
    "near_plane": dict(),
    "no_alpha_min": dict(alpha_min=0.0, k_max=2.5),
}


@pytest.mark.parametrize("kind", list(BINNING_CASES))
def test_binning_is_complete_and_sorted(kind):
    cfg = BINNING_CASES[kind]
    cam = look_at((0.3, -2.0, 0.5), (0.0, 0.0, 0.0), **CAMERA)
    means, quats, scales, opac = _scene(cam, 120, seed=hash(kind) % 1000, kind=kind if kind != "no_alpha_min" else "anisotropic")
    res = _run_binning(cam, means, quats, scales, opac, **cfg)
    pairs = _brute_force_pairs(cam, means, quats, scales, opac, near=0.2, alpha_min=cfg.get("alpha_min", 1 / 255), k_max=cfg.get("k_max", K_MAX))
    assert len(pairs) > 200  # the scene really covers pixels
    tx = res["settings"].tiles_x
    members = [set(lst.tolist()) for lst in res["lists"]]
    missing = [(p, g) for p, g in pairs if g not in members[(p // cam.width // 16) * tx + (p % cam.width) // 16]]
    assert not missing, f"{len(missing)} visible (pixel, Gaussian) pairs missing from their tile lists, e.g. {missing[:5]}"
    if kind == "near_plane":  # fallback boxes and culled centres both occur
        z = cam.to_camera(means)[:, 2]
        assert (z <= 0.2).any() and (res["radii"][z > 0.2] > 0).any()
        assert (res["radii"][z <= 0.2] == 0).all()
    depth = res["depth"]
    for lst in res["lists"]:
        key = np.stack([depth[lst], lst], 1)
        assert (np.diff(key[:, 0]) >= 0).all()
        ties = np.diff(key[:, 0]) == 0
        assert (np.diff(lst)[ties] > 0).all()
    # and the lists are not trivially everything: small Gaussians touch few tiles
    assert res["count"] < len(means) * len(res["lists"])
