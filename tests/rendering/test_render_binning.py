"""Tile binning of the Warp renderer: the exact screen box of each Gaussian's binning ellipsoid against an
independent float64 numpy computation (the dual conic of the projected quadric), and completeness: every
(pixel, Gaussian) pair that the per-pixel rule can blend, found by float64 brute force over all pairs, is
in that pixel's tile list; the lists are sorted by depth (ties by index).

The tile–ellipse test (``kernels/tile_overlap.py``): against a float64 brute force sampling each padded
tile densely with the ray–ellipsoid condition, it never drops a touched tile and drops nearly all others;
likewise for Gaussians crossing the near plane (general conics: hyperbolic, near-parabolic, elliptic;
camera just outside the ellipsoid; camera inside: whole image kept); renders and gradients with and
without it are bitwise equal (also with many near-plane-crossing Gaussians, and on the benchmark scene);
on the benchmark scene it cuts entries by about half or more."""

from __future__ import annotations

import math

import numpy as np
import pytest
import warp as wp

from gof_warp.core.camera import look_at
from gof_warp.kernels.binning import bin_gaussians
from gof_warp.kernels.project import preprocess_gaussians, screen_bounds
from gof_warp.kernels.render_types import CameraParams, RasterSettings, camera_params_from, make_raster_settings
from gof_warp.kernels.renderer import sh_parts
from gof_warp.kernels.tile_overlap import TileEllipses, empty_tile_ellipses, load_ellipse, row_tile_span, row_tile_span_scan

K_MAX = math.sqrt(2.0 * math.log(255.0))
BOX_TOL_PX = 1e-3  # float32 camera/parameters vs float64: the box edges agree to far below a pixel here
CAMERA = dict(fx=38.0, fy=33.0, cx=21.3, cy=19.1, width=45, height=37)  # 3x3 tiles, partial border tiles


def _world_gaussians(rng, cam, mu_v, scales):
    """World-space test Gaussians from view-space centres ``mu_v [n, 3]`` and ``scales [n, 3]``: random
    rotations and opacities, every value rounded to float32 (what the kernels read)."""
    n = len(mu_v)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    means = (mu_v - cam.t) @ cam.R
    opac = rng.uniform(0.02, 1.0, n)
    f32 = lambda a: a.astype(np.float32).astype(np.float64)  # noqa: E731
    return f32(means), f32(q), f32(scales), f32(opac)


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
    return _world_gaussians(rng, cam, mu_v, scales)


def _run_binning(cam, means, quats, scales, opac, use_ellipse=True, **cfg):
    """Preprocess, bound and bin on the CPU (``use_ellipse=False``: ``bin_gaussians`` without the ellipses,
    i.e. every tile of the box); per-tile lists and the per-Gaussian outputs (numpy)."""
    settings = make_raster_settings(cam.width, cam.height, **cfg)
    camp = camera_params_from(cam)
    n = len(means)
    arr = lambda a, t: wp.array(a.astype(np.float32), dtype=t, device="cpu")  # noqa: E731
    sh_dc, sh_rest = sh_parts(wp.zeros((n, 1), dtype=wp.vec3, device="cpu"))
    mu_v, P, o_g, col = (wp.empty(n, dtype=t, device="cpu") for t in (wp.vec3, wp.mat33, wp.vec3, wp.vec3))
    wp.launch(preprocess_gaussians, n, inputs=[arr(means, wp.vec3), arr(quats, wp.vec4), arr(scales, wp.vec3), sh_dc, sh_rest, 0, camp.R, camp.t, camp.centre],
              outputs=[mu_v, P, o_g, col], device="cpu")  # fmt: skip
    rect, touched, radii, depth = (wp.empty(n, dtype=t, device="cpu") for t in (wp.vec4i, wp.int32, wp.int32, float))
    ellipse = empty_tile_ellipses(n, "cpu")
    wp.launch(screen_bounds, n, inputs=[mu_v, arr(quats, wp.vec4), arr(scales, wp.vec3), arr(opac, float), camp, settings],
              outputs=[rect, touched, radii, depth, ellipse], device="cpu")  # fmt: skip
    extra = (ellipse, camp, settings) if use_ellipse else ()
    values, start, end, count = bin_gaussians(rect, touched, depth, settings.tiles_x, settings.tiles_x * settings.tiles_y, *extra)
    lists = [values.numpy()[s:e] for s, e in zip(start.numpy(), end.numpy())]
    return dict(rect=rect.numpy(), radii=radii.numpy(), depth=depth.numpy(), lists=lists, count=count, settings=settings,
                touched=touched.numpy(), exact=ellipse.exact.numpy())


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


# ---------------------------------------------------------------------------------------------------------
# Exact tile–ellipse culling

TILE_CAMERA = dict(fx=120.0, fy=108.0, cx=71.3, cy=57.9, width=150, height=110)  # 10x7 tiles, partial border


def _cull_scene(cam, n, seed):
    """Flat discs (100:1), needles, large and small Gaussians, randomly rotated (mostly oblique views),
    centres up to 40 % outside the image, a few straddling the near plane."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.8, 5.0, n)
    u = cam.cx + (rng.uniform(size=n) - 0.5) * 1.8 * cam.width
    v = cam.cy + (rng.uniform(size=n) - 0.5) * 1.8 * cam.height
    z[: n // 20] = rng.uniform(0.3, 0.6, n // 20)  # some cross the near plane (rectangle kept)
    mu_v = np.stack([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z], -1)
    size = np.exp(rng.uniform(np.log(0.005), np.log(0.2), n)) * z
    size[: n // 20] = rng.uniform(0.1, 0.3, n // 20)
    kind = rng.integers(0, 4, n)  # 0 disc, 1 needle, 2 anisotropic, 3 round
    ratio = np.where(kind[:, None] == 0, [1.0, rng.uniform(0.3, 1.0), 0.01], 1.0)
    ratio = np.where(kind[:, None] == 1, [1.0, 0.03, 0.03], ratio)
    ratio = np.where(kind[:, None] == 2, rng.uniform(0.1, 1.0, (n, 3)), ratio)
    scales = size[:, None] * ratio
    return _world_gaussians(rng, cam, mu_v, scales)


def _brute_force_tiles(cam, means, quats, scales, k, rect, ts, pad, samples=24):
    """``{(g, tile)}`` for the tiles of ``rect[g]`` with a sample point (a ``samples²`` grid over the tile's
    pixel-centre rectangle grown by ``pad``, edges included) whose ray meets ``{x : ‖P(x − μ)‖ ≤ k}``,
    ``P = S⁻¹R_vᵀ``: the squared distance of the line ``t d`` from the mean is ``‖Pμ × Pd‖² / ‖Pd‖²`` (for
    an ellipsoid crossing the near plane, the line condition: the ray's is stricter). R_v is formed in
    float32 as the kernel does (the flat Gaussians' outlines move with its rounding)."""
    mu = (means @ cam.R.T + cam.t).astype(np.float32).astype(np.float64)
    Rv = (cam.R.astype(np.float32) @ _rotations(quats.astype(np.float32))).astype(np.float64)
    tiles_x = (cam.width + ts - 1) // ts
    grid = np.linspace(0.0, 1.0, samples)
    touched = set()
    for g in range(len(means)):
        x0, y0, x1, y1 = rect[g]
        if x1 <= x0:
            continue
        tx, ty = np.arange(x0, x1), np.arange(y0, y1)
        u = tx[:, None] * ts + 0.5 - pad + grid * (np.minimum(tx * ts + ts, cam.width) - tx * ts - 1 + 2 * pad)[:, None]
        v = ty[:, None] * ts + 0.5 - pad + grid * (np.minimum(ty * ts + ts, cam.height) - ty * ts - 1 + 2 * pad)[:, None]
        uu = np.broadcast_to(u[None, None], (len(ty), samples, len(tx), samples))  # [tile row, v sample, tile column, u sample]
        vv = np.broadcast_to(v[:, :, None, None], uu.shape)
        d = np.stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones(uu.shape)], -1)
        P = Rv[g].T / scales[g][:, None]
        Pd = d @ P.T
        d2 = (np.cross(P @ mu[g], Pd) ** 2).sum(-1) / (Pd**2).sum(-1)
        for j, i in zip(*np.nonzero((d2 <= k[g] ** 2).any(axis=(1, 3)))):
            touched.add((g, int((y0 + j) * tiles_x + x0 + i)))
    return touched


@pytest.mark.slow
@pytest.mark.parametrize("pad, ts", [(0.0, 16), (0.5, 16), (0.5, 4)])
def test_tile_culling_is_conservative_and_tight(pad, ts):
    cam = look_at((0.3, -2.0, 0.5), (0.0, 0.0, 0.0), **TILE_CAMERA)
    means, quats, scales, opac = _cull_scene(cam, 500, seed=7)
    res = _run_binning(cam, means, quats, scales, opac, pixel_pad=pad, tile_size=ts)
    full = _run_binning(cam, means, quats, scales, opac, pixel_pad=pad, tile_size=ts, tile_cull=False)
    legacy = _run_binning(cam, means, quats, scales, opac, use_ellipse=False, pixel_pad=pad, tile_size=ts)
    assert all(np.array_equal(a, b) for a, b in zip(full["lists"], legacy["lists"]))
    assert np.array_equal(res["rect"], full["rect"]) and np.array_equal(res["radii"], full["radii"])
    kept = {(int(g), t) for t, lst in enumerate(res["lists"]) for g in lst}
    rect_tiles = {(int(g), t) for t, lst in enumerate(full["lists"]) for g in lst}
    assert kept <= rect_tiles and res["count"] == len(kept) == res["touched"].sum()
    k = _binning_k(opac, 1 / 255, K_MAX)  # the spec's k (the kernel adds its 1e-4 float32 margin)
    touched = _brute_force_tiles(cam, means, quats, scales, k, res["rect"], ts, pad)
    missed = touched - kept
    assert not missed, f"{len(missed)} touched (Gaussian, tile) pairs culled, e.g. {sorted(missed)[:5]}"
    # Gaussians crossing the near plane (whole-image rectangle) are culled by their general conic too
    mu = cam.to_camera(means)
    Sigma_zz = np.einsum("ni,ni->n", (cam.R @ _rotations(quats))[:, 2, :] ** 2, scales**2)
    front = mu[:, 2] - k * np.sqrt(Sigma_zz) - 0.2
    crossing = set(np.nonzero((mu[:, 2] > 0.2) & (front < -1e-3))[0].tolist())
    assert len(crossing) >= 5
    # the fraction of the rectangle's untouched tiles that is culled
    exact = set(np.nonzero(front > 1e-3)[0].tolist())
    for name, group in (("in front of the near plane", exact), ("crossing it", crossing)):
        untouched = {(g, t) for g, t in rect_tiles - touched if g in group}
        culled = len(untouched - kept) / len(untouched)
        print(f"pad {pad}, tile {ts}: rectangle {len(rect_tiles)} entries, kept {len(kept)}, brute-force touched {len(touched)}; "
              f"culled {culled:.2%} of the {len(untouched)} untouched (of Gaussians {name})")
        assert len(untouched) > 0.1 * len({(g, t) for g, t in rect_tiles if g in group})  # something to cull
        assert culled > 0.97  # the rest are slivers between the 24² samples (and the float64 allowance)


NEAR_KINDS = ("beside", "behind", "parabolic", "outside", "inside", "flat", "front")


def _near_scene(cam, n, seed, near=0.2, kinds=NEAR_KINDS, opacity=(0.05, 1.0)):
    """``n`` Gaussians whose k-ellipsoid crosses the near plane with the centre beyond it (float32-
    representable; k from the opacity as the kernel's), kinds cycled: large ones beside the camera (mean
    up to 3 half-fields of view off-axis), needles reaching behind the camera, ellipsoids nearly touching
    the camera plane (near-parabolic conics), the camera just outside (Mahalanobis radius (1 + 10⁻³…10⁻¹)
    the kernel's k) or inside the ellipsoid, flat discs, wide ones in front. Returns
    ``means, quats, scales, opac, kind``. Hyperbolic, parabolic and elliptic conics all occur."""
    rng = np.random.default_rng(seed)
    f32 = lambda a: np.asarray(a, dtype=np.float32).astype(np.float64)  # noqa: E731
    out = []
    while len(out) < n:
        kind = kinds[len(out) % len(kinds)]
        q = rng.normal(size=4)
        q = f32(q / np.linalg.norm(q))
        Rv = cam.R.astype(np.float32).astype(np.float64) @ _rotations(q[None])[0]
        op = f32(rng.uniform(*opacity))
        k = min(K_MAX, math.sqrt(2 * math.log(op * 255.0)))
        a = rng.uniform(-1.5, 1.5) * cam.width / cam.fx  # view direction (a, b, 1), in and far outside the image
        b = rng.uniform(-1.5, 1.5) * cam.height / cam.fy
        if kind == "beside":
            z, s = rng.uniform(near + 0.01, 0.6), rng.uniform(0.03, 0.5, 3)
        elif kind == "behind":
            z, s = rng.uniform(near + 0.02, 1.0), np.array([rng.uniform(0.02, 0.15), rng.uniform(0.02, 0.15), rng.uniform(0.3, 2.0)])
        elif kind == "flat":
            z, s = rng.uniform(near + 0.01, 1.0), np.array([rng.uniform(0.1, 1.0), rng.uniform(0.1, 1.0), rng.uniform(0.002, 0.02)])
        else:
            z, s = rng.uniform(near + 0.05, 1.5), rng.uniform(0.05, 0.5, 3)
            if rng.uniform() < 0.3:
                s[rng.integers(3)] *= 0.02
            if kind == "front":
                a, b = rng.uniform(-0.5, 0.5) * cam.width / cam.fx, rng.uniform(-0.5, 0.5) * cam.height / cam.fy
        mu = np.array([a * z, b * z, z])
        Sigma = Rv @ np.diag(s**2) @ Rv.T
        if kind == "parabolic":  # μz ≈ k √Σzz: the ellipsoid nearly touches the plane z = 0
            s = s * mu[2] / (k * math.sqrt(Sigma[2, 2])) * (1.0 + rng.uniform(-0.03, 0.03))
        elif kind == "outside":
            s = s * math.sqrt(mu @ np.linalg.solve(Sigma, mu) / ((1.0 + 10.0 ** rng.uniform(-3, -1)) * (k * 1.0001) ** 2))
        elif kind == "inside":
            s = s * math.sqrt(mu @ np.linalg.solve(Sigma, mu) / (rng.uniform(0.1, 0.9) * k**2))
        s = f32(s)
        Sigma = Rv @ np.diag(s**2) @ Rv.T
        means = f32((mu - cam.t) @ cam.R)
        m = (means @ cam.R.T + cam.t).astype(np.float32).astype(np.float64)  # μ_v as the kernel has it (about)
        m2 = m @ np.linalg.solve(Sigma, m)
        if not (m[2] > near + 1e-3 and m[2] - 1.0001 * k * math.sqrt(Sigma[2, 2]) < near - 1e-3):
            continue
        if (kind == "inside" and not m2 < 0.95 * k**2) or (kind == "outside" and not m2 > 1.0005 * (1.0001 * k) ** 2):
            continue
        out.append((means, q, s, op, kinds.index(kind)))
    return tuple(np.array(x) for x in zip(*out))


def _conic_types(cam, means, quats, scales, k):
    """Per Gaussian, from an independent float64 formula (the dual of the projected quadric ``k²Σ − μμᵀ``):
    ``inside`` (camera inside the ellipsoid) or the type of the image conic of lines meeting it."""
    mu = cam.to_camera(means)
    Rv = cam.R @ _rotations(quats)
    out = []
    for g in range(len(means)):
        S = Rv[g] @ np.diag(scales[g] ** 2) @ Rv[g].T
        C = np.linalg.inv(k[g] ** 2 * S - np.outer(mu[g], mu[g]))  # the cone of lines: dᵀ C d ≥ 0 (up to sign)
        if mu[g] @ np.linalg.solve(S, mu[g]) <= k[g] ** 2:
            out.append("inside")
            continue
        A = C[:2, :2] / np.abs(C[:2, :2]).max()
        det = np.linalg.det(A)
        out.append("parabola" if abs(det) < 1e-2 else "ellipse" if det > 0 else "hyperbola")
    return np.array(out)


@pytest.mark.slow
@pytest.mark.parametrize("pad, ts, samples", [(0.0, 16, 24), (0.5, 16, 24), (0.5, 4, 8)])
def test_near_plane_tile_culling_is_conservative(pad, ts, samples):
    """Gaussians crossing the near plane (whole-image rectangle): against the float64 brute force of the
    line–ellipsoid condition on every tile of the image, no touched tile is culled, nearly all untouched
    ones are, and a camera inside the ellipsoid keeps the whole image."""
    cam = look_at((0.3, -2.0, 0.5), (0.0, 0.0, 0.0), **TILE_CAMERA)
    means, quats, scales, opac, kind = _near_scene(cam, 210, seed=3)
    k = _binning_k(opac, 1 / 255, K_MAX)
    types = _conic_types(cam, means, quats, scales, k)
    counts = {t: int((types == t).sum()) for t in ("inside", "ellipse", "parabola", "hyperbola")}
    assert min(counts.values()) >= 10, counts
    res = _run_binning(cam, means, quats, scales, opac, pixel_pad=pad, tile_size=ts)
    full = _run_binning(cam, means, quats, scales, opac, pixel_pad=pad, tile_size=ts, tile_cull=False)
    num_tiles = len(res["lists"])
    assert (res["touched"] <= num_tiles).all() and (full["touched"] == num_tiles).all()  # whole-image rectangles
    assert np.array_equal(res["rect"], full["rect"]) and np.array_equal(res["radii"], full["radii"])
    assert (res["radii"] == max(cam.width, cam.height)).all()  # radii (densification statistics) unchanged
    kept = {(int(g), t) for t, lst in enumerate(res["lists"]) for g in lst}
    rect_tiles = {(int(g), t) for t, lst in enumerate(full["lists"]) for g in lst}
    assert kept <= rect_tiles and res["count"] == len(kept) == res["touched"].sum()
    touched = _brute_force_tiles(cam, means, quats, scales, k, res["rect"], ts, pad, samples)
    missed = touched - kept
    assert not missed, f"{len(missed)} touched (Gaussian, tile) pairs culled, e.g. {sorted(missed)[:5]}"
    inside = np.nonzero(types == "inside")[0]
    assert (res["exact"][inside] == 0).all() and (res["touched"][inside] == num_tiles).all()
    assert (res["exact"][types != "inside"] == 2).all()
    untouched = rect_tiles - touched
    culled = len(untouched - kept) / len(untouched)
    per_type = {t: (sum(res["touched"][types == t]), sum(full["touched"][types == t])) for t in counts}
    print(f"pad {pad}, tile {ts}: {counts}; entries kept/rectangle per type {per_type}; "
          f"culled {culled:.2%} of the {len(untouched)} untouched of {len(rect_tiles)}")
    assert len(untouched) > 0.2 * len(rect_tiles)
    assert culled > 0.97
    for t in ("ellipse", "parabola", "hyperbola"):  # every conic type is culled
        assert per_type[t][0] < 0.8 * per_type[t][1], (t, per_type[t])


def _assert_renders_identically(cam, scene):
    """Outputs and gradients (two configurations, gradients accumulated) with and without the tile test:
    bitwise equal."""
    import torch

    from gof_warp.rendering.render import RenderConfig, rasterize

    names = ("means", "quats", "scales", "opacities", "sh")
    results = []
    for cull in (True, False):
        leaves = [scene[k].float().clone().requires_grad_(True) for k in names]
        for cfg in (RenderConfig(tile_cull=cull), RenderConfig(tile_cull=cull, tile_size=8, background=(0.2, 0.5, 1.0))):
            out = rasterize(*leaves, cam, config=cfg)
            w = torch.Generator().manual_seed(1)
            loss = sum((out[k] * torch.randn(out[k].shape, generator=w)).sum() for k in sorted(out) if out[k].is_floating_point())
            loss.backward()
            results.append({k: v.detach().clone() for k, v in out.items()})
        results.append({k: l.grad.clone() for k, l in zip(names, leaves)})
    half = len(results) // 2
    for a, b in zip(results[:half], results[half:]):
        for key in a:
            assert torch.equal(a[key], b[key]), key
    return results[0]


def test_tile_culling_renders_identically():
    """Outputs and gradients with and without the tile test: bitwise equal (each tile's list keeps its
    order; the dropped entries never passed the per-pixel test)."""
    import torch

    from reference_render import make_camera, random_scene

    cam = make_camera(width=97, height=71, fx=90.0, fy=80.0)
    scene = random_scene(cam, 300, 2, seed=11, n_behind=3, n_near=8, spread=1.5)
    g = torch.Generator().manual_seed(0)
    flat = torch.rand(300, generator=g) < 0.5  # half of them flat (oblique discs)
    scene["scales"][flat, 2] *= 0.02
    out = _assert_renders_identically(cam, scene)
    assert float(out["alpha"].mean()) > 0.3  # the scene covers the image


def test_near_plane_tile_culling_renders_identically():
    """As above with many Gaussians crossing the near plane (beside and behind the camera, near-parabolic,
    camera just outside or inside), culled by their general conic."""
    import torch

    from reference_render import make_camera, random_scene

    cam = make_camera(width=97, height=71, fx=90.0, fy=80.0)
    base = random_scene(cam, 100, 2, seed=12, n_behind=2, n_near=4)
    means, quats, scales, opac, kind = _near_scene(cam, 140, seed=5, opacity=(0.006, 0.08))  # faint: not saturated
    near = dict(means=means, quats=quats, scales=scales, opacities=opac)
    g = torch.Generator().manual_seed(2)
    near = {k: torch.from_numpy(v) for k, v in near.items()}
    near["sh"] = 0.4 * torch.randn(len(means), 9, 3, generator=g, dtype=torch.float64)
    scene = {k: torch.cat([base[k], near[k]]) for k in base}
    out = _assert_renders_identically(cam, scene)
    alpha = out["alpha"]
    print(f"alpha mean {float(alpha.mean()):.3f}, min {float(alpha.min()):.3f}")
    assert float(alpha.mean()) > 0.3 and float(alpha.min()) < 0.99  # covered, not saturated everywhere
    np_scene = [scene[k].float().double().numpy() for k in ("means", "quats", "scales", "opacities")]
    np_scene[1] = np_scene[1] / np.linalg.norm(np_scene[1], axis=1, keepdims=True)  # render() normalises
    culled = _run_binning(cam, *np_scene)
    full = _run_binning(cam, *np_scene, tile_cull=False)
    crossing = culled["exact"][100:] == 2
    kept, rect = culled["touched"][100:][crossing].sum(), full["touched"][100:][crossing].sum()
    print(f"near-plane scene: {culled['count']} entries ({full['count']} without culling); the {crossing.sum()} "
          f"crossing Gaussians outside their ellipsoid keep {kept} of {rect}")
    assert crossing.sum() > 100 and kept < 0.8 * rect


@pytest.mark.slow
def test_tile_culling_renders_benchmark_scene_identically():
    """The benchmark scene (20k Gaussians, 320x240, SH degree 2; its ~100 near-plane-crossing Gaussians lose
    all their entries): outputs and gradients bitwise equal with and without culling."""
    from gof_warp.benchmarking.render_scene import make_camera, make_scene

    means, quats, scales, opac, sh = make_scene(20_000, device="cpu")
    scene = dict(means=means.double(), quats=quats.double(), scales=scales.double(), opacities=opac.double(), sh=sh[:, :9].double())
    out = _assert_renders_identically(make_camera(320, 240), scene)
    assert float(out["alpha"].mean()) > 0.5


@pytest.mark.slow
@pytest.mark.parametrize("n, W, H, bound", [(20_000, 320, 240, 0.65), (50_000, 640, 360, 0.5)])
def test_tile_culling_reduces_benchmark_entries(n, W, H, bound):
    """The renderer benchmark's scene: the few Gaussians crossing the near plane (ground splats beside the
    camera, background splats behind it) held most entries as whole-image rectangles; culled, they keep
    only the tiles their lines reach (none here), and the total drops below ``bound`` × the rectangles'."""
    from gof_warp.benchmarking.render_scene import make_camera, make_scene

    from gof_warp.kernels.renderer import prepare_view

    params = [p.numpy() for p in make_scene(n, device="cpu")]
    cam = camera_params_from(make_camera(W, H))
    types = (wp.vec3, wp.vec4, wp.vec3, float, wp.vec3)
    arrays = [wp.array(p, dtype=t, device="cpu") for p, t in zip(params, types)]
    counts, radii = {}, {}
    for cull in (False, True):
        settings = make_raster_settings(W, H, tile_cull=cull)
        splats, _, counts[cull] = prepare_view(*arrays, 3, cam, settings)
        radii[cull] = splats.radius.numpy()
    crossing = int((radii[True] == max(W, H)).sum())
    print(f"bench scene {n} Gaussians {W}x{H}: {counts[False]} tile entries (rectangle), {counts[True]} (culled); "
          f"{crossing} Gaussians crossing the near plane")
    assert np.array_equal(radii[True], radii[False]) and crossing > 0
    assert counts[True] < bound * counts[False]


@wp.kernel
def _spans_both(rect: wp.array(dtype=wp.vec4i), ellipse: TileEllipses, cam: CameraParams, settings: RasterSettings,
                row: int, closed: wp.array(dtype=wp.vec2i), scan: wp.array(dtype=wp.vec2i)):  # fmt: skip
    k = wp.tid()
    r = rect[k]
    ty = r[1] + row
    closed[k] = wp.vec2i(0, 0)
    scan[k] = wp.vec2i(0, 0)
    if ty < r[3]:
        closed[k] = row_tile_span(load_ellipse(ellipse, k), ty, r[0], r[2], cam, settings)
        scan[k] = row_tile_span_scan(load_ellipse(ellipse, k), ty, r[0], r[2], cam, settings)


@pytest.mark.slow
@pytest.mark.parametrize("pad, ts", [(0.0, 16), (0.5, 16), (0.5, 4), (0.0, 1)])
def test_closed_form_row_span_equals_the_tile_scan(pad, ts):
    """The binning's O(1) row span (``row_tile_span``) against its reference that tests tiles one by one from both
    ends of the row (``row_tile_span_scan``), on every row of 1,500 Gaussians of all stress kinds: it contains the
    scan's span, and equals it on all but a vanishing fraction of rows (its float64 allowance may add a tile whose
    edge lies within ~1e-6 of the ellipse's half-extent)."""
    cam = look_at((0.3, -2.0, 0.5), (0.0, 0.0, 0.0), **TILE_CAMERA)
    parts = [_cull_scene(cam, 500, seed=7)] + [_scene(cam, 500, seed, kind) for seed, kind in ((3, "anisotropic"), (4, "border"))]
    means, quats, scales, opac = (np.concatenate(x) for x in zip(*parts))
    settings = make_raster_settings(cam.width, cam.height, pixel_pad=pad, tile_size=ts)
    camp = camera_params_from(cam)
    n = len(means)
    arr = lambda a, t: wp.array(a.astype(np.float32), dtype=t, device="cpu")  # noqa: E731
    mu_v, P, o_g, col = (wp.empty(n, dtype=t, device="cpu") for t in (wp.vec3, wp.mat33, wp.vec3, wp.vec3))
    wp.launch(preprocess_gaussians, n, inputs=[arr(means, wp.vec3), arr(quats, wp.vec4), arr(scales, wp.vec3),
              *sh_parts(wp.zeros((n, 1), dtype=wp.vec3, device="cpu")), 0, camp.R, camp.t, camp.centre], outputs=[mu_v, P, o_g, col], device="cpu")  # fmt: skip
    rect, touched, radii, depth = (wp.empty(n, dtype=t, device="cpu") for t in (wp.vec4i, wp.int32, wp.int32, float))
    ellipse = empty_tile_ellipses(n, "cpu")
    wp.launch(screen_bounds, n, inputs=[mu_v, arr(quats, wp.vec4), arr(scales, wp.vec3), arr(opac, float), camp, settings],
              outputs=[rect, touched, radii, depth, ellipse], device="cpu")  # fmt: skip
    r = rect.numpy()
    exact = ellipse.exact.numpy()
    rows = equal = narrower = 0
    for row in range(int((r[:, 3] - r[:, 1]).max())):
        closed, scan = wp.empty(n, dtype=wp.vec2i, device="cpu"), wp.empty(n, dtype=wp.vec2i, device="cpu")
        wp.launch(_spans_both, n, inputs=[rect, ellipse, camp, settings, row], outputs=[closed, scan], device="cpu")
        c, s = closed.numpy(), scan.numpy()
        live = (r[:, 1] + row < r[:, 3]) & (exact == 1)
        c, s = c[live], s[live]
        c_len, s_len = c[:, 1] - c[:, 0], s[:, 1] - s[:, 0]
        rows += int(live.sum())
        equal += int(((c == s).all(1) | ((c_len == 0) & (s_len == 0))).sum())
        narrower += int(((s_len > 0) & ((c[:, 0] > s[:, 0]) | (c[:, 1] < s[:, 1]))).sum())
    print(f"pad {pad}, tile {ts}: {rows} rows of exact ellipses, {equal} equal, {narrower} narrower than the scan")
    assert rows > 1500 and narrower == 0
    assert equal >= rows - max(2, rows // 1000)
