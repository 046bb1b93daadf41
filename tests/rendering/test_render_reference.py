"""Self-tests of the float64 reference renderer (``reference_render.py``) against closed forms,
independent evaluations (scipy rotations and spherical harmonics, a numerical search along the ray) and
float64 central differences. The Warp renderer is held to this reference elsewhere, so these tests are
what makes that comparison mean "the renderer follows the spec"."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from scipy.optimize import minimize_scalar
from scipy.spatial.transform import Rotation
from scipy.special import sph_harm_y

from reference_render import (
    GRADCHECK_CONFIG,
    OUTPUT_NAMES,
    RefConfig,
    distortion_depth,
    make_camera,
    quat_to_rotmat,
    random_scene,
    reference_densify_stats,
    reference_render,
    reference_screen_boxes,
    sh_basis,
    weighted_loss,
)

EXACT = 1e-12  # float64 evaluations of the same closed form in a different order
NUMERIC_SEARCH = 1e-6  # scipy's bounded search: the argmin of a flat quadratic is found to ~sqrt(eps) only
WORLD_FORM = 1e-9  # world-space closed form with numpy's inverse of Σ (condition number up to ~1e3)
FD_EPS = 1e-6  # central-difference step in float64 (truncation ~eps², round-off ~1e-16/eps)
FD_RTOL = 1e-6  # central differences vs autograd, relative to the directional derivative's scale


def _scipy_sh_basis(dirs: np.ndarray, degree: int) -> np.ndarray:
    """3DGS basis from scipy's complex SH: index l²+l+m = √2·Im Y_l^|m| (m<0), Y_l^0, √2·Re Y_l^m (m>0)."""
    theta, phi = np.arccos(dirs[:, 2]), np.arctan2(dirs[:, 1], dirs[:, 0])
    out = []
    for l in range(degree + 1):
        for m in range(-l, l + 1):
            Y = sph_harm_y(l, abs(m), theta, phi)
            out.append(math.sqrt(2) * Y.imag if m < 0 else (math.sqrt(2) * Y.real if m > 0 else Y.real))
    return np.stack(out, -1)


def _one(means, scale, opacity, sh, iso=True):
    """Float64 parameter dict of Gaussians given as lists; isotropic with identity rotation."""
    n = len(means)
    return dict(
        means=torch.tensor(means, dtype=torch.float64),
        quats=torch.tensor([[1.0, 0, 0, 0]] * n, dtype=torch.float64),
        scales=torch.tensor(scale, dtype=torch.float64)[:, None].expand(n, 3).clone(),
        opacities=torch.tensor(opacity, dtype=torch.float64),
        sh=torch.tensor(sh, dtype=torch.float64),
    )


def _isotropic_closed_form(camera, mu, sigma, opacity, config):
    """World-space closed form for one isotropic Gaussian: per pixel (t*, α after the skip rules)."""
    o, d = camera.pixel_rays()  # d [H,W,3] world, camera z = 1
    m = mu - o
    t = (d @ m) / (d * d).sum(-1)
    dist2 = ((m - t[..., None] * d) ** 2).sum(-1) / sigma**2
    alpha = np.minimum(config.alpha_max, opacity * np.exp(-0.5 * dist2))
    z = camera.to_camera(mu[None])[0, 2]
    keep = (z > config.near) & (t > config.near) & (dist2 <= config.k_max**2) & (alpha >= config.alpha_min)
    return t, np.where(keep, alpha, 0.0)


def test_quat_to_rotmat_matches_scipy():
    q = torch.randn(20, 4, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    q = q / q.norm(dim=-1, keepdim=True)
    expected = Rotation.from_quat(q.numpy(), scalar_first=True).as_matrix()
    assert np.abs(quat_to_rotmat(q).numpy() - expected).max() < EXACT


def test_sh_basis_matches_scipy_spherical_harmonics():
    d = np.random.default_rng(2).normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for degree in range(4):
        got = sh_basis(torch.tensor(d), degree).numpy()
        assert got.shape == (50, (degree + 1) ** 2)
        assert np.abs(got - _scipy_sh_basis(d, degree)).max() < EXACT


CLOSED_FORM_CASES = {  # config, camera-space centre, sigma, opacity; each cut bites on part of the image
    "no_thresholds": (GRADCHECK_CONFIG, [0.15, -0.1, 2.4], 0.2, 0.8),
    "defaults_alpha_min_cuts": (RefConfig(background=(0.2, 0.5, 0.9)), [0.15, -0.1, 2.4], 0.1, 0.8),
    "k_max_cuts": (RefConfig(k_max=1.5, alpha_min=0.0), [0.15, -0.1, 2.4], 0.2, 0.8),
    "alpha_max_clamps": (RefConfig(), [0.15, -0.1, 2.4], 1.2, 1.0),
    "near_skips_t_star": (RefConfig(alpha_min=0.0), [-1.0, 0.0, 0.3], 0.9, 0.9),
}


@pytest.mark.parametrize("case", list(CLOSED_FORM_CASES))
def test_single_isotropic_gaussian_closed_form(case):
    config, mu_v, sigma, opacity = CLOSED_FORM_CASES[case]
    cam = make_camera(width=23, height=17)
    mu = (np.asarray(mu_v) - cam.t) @ cam.R
    sh = np.random.default_rng(3).normal(scale=0.3, size=(1, 9, 3))
    p = _one([mu.tolist()], [sigma], [opacity], sh)
    out = reference_render(**p, camera=cam, sh_degree=2, config=config)
    t, alpha = _isotropic_closed_form(cam, mu, sigma, opacity, config)
    dirv = (mu - cam.center) / np.linalg.norm(mu - cam.center)
    colour = np.maximum(0.0, _scipy_sh_basis(dirv[None], 2)[0] @ sh[0] + 0.5)
    bg = np.asarray(config.background)
    r_cam = cam.pixel_rays()[1] @ cam.R.T
    on = alpha > 0
    cut = (alpha == config.alpha_max) if case == "alpha_max_clamps" else on
    assert 0.05 < cut.mean() < 0.95 or case == "no_thresholds"  # the case really exercises its cut
    expected = dict(
        rgb=alpha[..., None] * colour + (1 - alpha[..., None]) * bg,
        alpha=alpha,
        depth=np.where(on, t, 0.0),
        accum_depth=alpha * t,
        median_depth=np.where(on, t, 0.0),
        normal=-alpha[..., None] * r_cam / np.linalg.norm(r_cam, axis=-1, keepdims=True),
        distortion=np.zeros_like(alpha),
    )
    for name in OUTPUT_NAMES:
        assert np.abs(out[name].numpy() - expected[name]).max() < EXACT, name


def test_depth_is_centre_depth_on_the_pixel_through_the_centre():
    cam = make_camera(width=23, height=17)
    i, j, zc = 7, 11, 2.3
    r = np.array([(i + 0.5 - cam.cx) / cam.fx, (j + 0.5 - cam.cy) / cam.fy, 1.0])
    mu = (zc * r - cam.t) @ cam.R  # world point on that pixel's ray at depth zc
    out = reference_render(**_one([mu.tolist()], [0.3], [0.7], np.zeros((1, 1, 3))), camera=cam)
    assert out["depth"][j, i].item() == pytest.approx(zc, abs=EXACT)
    assert out["alpha"][j, i].item() == pytest.approx(0.7, abs=EXACT)
    assert out["median_depth"][j, i].item() == pytest.approx(zc, abs=EXACT)


def test_anisotropic_gaussian_matches_world_space_ray_maximum():
    """t*, α and the normal of a rotated anisotropic Gaussian vs the world-space quadratic along the ray
    (closed-form minimum with numpy's Σ⁻¹, confirmed by a numerical search)."""
    cam = make_camera(width=9, height=7, fx=8.0, fy=6.0)
    scene = random_scene(cam, 1, 0, seed=4, n_behind=0, n_near=0, spread=0.3)
    out = reference_render(**scene, camera=cam, config=GRADCHECK_CONFIG)
    mu = scene["means"][0].numpy()
    Rk = Rotation.from_quat(scene["quats"].numpy(), scalar_first=True).as_matrix()[0]
    Sigma_inv = np.linalg.inv(Rk @ np.diag(scene["scales"][0].numpy() ** 2) @ Rk.T)
    o, d = cam.pixel_rays()
    opacity = scene["opacities"][0].item()
    for j in range(cam.height):
        for i in range(cam.width):

            def q(t):
                x = o + t * d[j, i] - mu
                return x @ Sigma_inv @ x

            dd = d[j, i]
            t_star = dd @ Sigma_inv @ (mu - o) / (dd @ Sigma_inv @ dd)
            res = minimize_scalar(q, bounds=(0.0, 20.0), method="bounded", options=dict(xatol=1e-10))
            assert t_star == pytest.approx(res.x, abs=NUMERIC_SEARCH)
            assert out["t_star"][j, i, 0].item() == pytest.approx(t_star, abs=WORLD_FORM)
            assert out["weights"][j, i, 0].item() == pytest.approx(opacity * math.exp(-0.5 * q(t_star)), abs=WORLD_FORM)
            n = -cam.R @ Sigma_inv @ d[j, i]  # the density's gradient direction, in camera space
            n_ref = out["normal"][j, i].numpy() / out["weights"][j, i, 0].item()  # w = α exactly
            assert np.abs(n_ref - n / np.linalg.norm(n)).max() < WORLD_FORM


@pytest.mark.parametrize("alpha_near", [0.7, 0.3])
def test_two_gaussians_composite_in_depth_order(alpha_near):
    """Index 0 is farther than index 1: index 1 must be blended first; median switches at T = 0.5."""
    cam = make_camera(width=5, height=4)
    i, j = 2, 1
    r = np.array([(i + 0.5 - cam.cx) / cam.fx, (j + 0.5 - cam.cy) / cam.fy, 1.0])
    far, near = 3.0 * r, 1.5 * r
    sh = np.array([[[0.9, -0.3, 0.1]], [[-0.4, 0.6, 0.2]]])
    p = _one([((far - cam.t) @ cam.R).tolist(), ((near - cam.t) @ cam.R).tolist()], [0.4, 0.3], [0.6, alpha_near], sh)
    out = reference_render(**p, camera=cam, config=RefConfig(background=(0.1, 0.2, 0.3), distortion="paper"))
    gof = reference_render(**p, camera=cam, config=RefConfig(background=(0.1, 0.2, 0.3)))
    c = np.maximum(0, sh[:, 0] * 0.28209479177387814 + 0.5)
    w1 = alpha_near
    w0 = 0.6 * (1 - alpha_near)
    T = (1 - alpha_near) * 0.4
    px = {k: v[j, i].numpy() for k, v in out.items()}
    assert np.abs(px["rgb"] - (w1 * c[1] + w0 * c[0] + T * np.array([0.1, 0.2, 0.3]))).max() < EXACT
    assert px["alpha"] == pytest.approx(1 - T, abs=EXACT)
    assert px["accum_depth"] == pytest.approx(w1 * 1.5 + w0 * 3.0, abs=EXACT)
    assert px["median_depth"] == pytest.approx(1.5 if alpha_near >= 0.5 else 3.0, abs=EXACT)
    assert px["distortion"] == pytest.approx(2 * w0 * w1 * (3.0 - 1.5), abs=EXACT)
    m = lambda t: 100.0 * (t - 0.2) / (99.8 * t)  # noqa: E731  GOF's NDC depth (near 0.2, far 100)
    assert gof["distortion"][j, i].item() == pytest.approx(w0 * w1 * (m(3.0) - m(1.5)) ** 2, abs=EXACT)
    assert np.abs(px["weights"] - [w0, w1]).max() < EXACT


def test_equal_depths_blend_in_index_order():
    cam = make_camera(width=5, height=4)
    mu = ((np.array([0.0, 0.0, 2.0]) - cam.t) @ cam.R).tolist()
    sh = np.array([[[1.0, 0, 0]], [[0, 1.0, 0]]])
    out = reference_render(**_one([mu, mu], [0.5, 0.5], [0.5, 0.5], sh), camera=cam, config=GRADCHECK_CONFIG)
    w = out["weights"].reshape(-1, 2)
    assert torch.allclose(w[:, 1], w[:, 0] * (1 - w[:, 0]))  # index 1 sees T = 1 − α_0


def test_transmittance_stop_drops_the_stopping_gaussian_and_all_later():
    cam = make_camera(width=5, height=4)
    r = np.array([(2.5 - cam.cx) / cam.fx, (1.5 - cam.cy) / cam.fy, 1.0])
    mus = [((z * r - cam.t) @ cam.R).tolist() for z in (1.0, 2.0, 3.0)]
    sh = np.array([[[1.0, 0, 0]], [[0, 1.0, 0]], [[0, 0, 1.0]]])
    out = reference_render(**_one(mus, [0.2] * 3, [1.0] * 3, sh), camera=cam, config=RefConfig(transmittance_min=1e-3))
    assert out["alpha"][1, 2].item() == pytest.approx(0.99, abs=EXACT)  # 0.01·0.01 < 1e-3: second stops
    assert out["weights"][1, 2].tolist() == pytest.approx([0.99, 0.0, 0.0], abs=EXACT)
    assert out["margin"][1, 2].item() == pytest.approx(0.9, abs=EXACT)  # |1e-4 − 1e-3| / 1e-3


def test_gaussian_behind_near_plane_is_culled():
    cam = make_camera(width=5, height=4)
    mu = ((np.array([0.0, 0.0, 0.19]) - cam.t) @ cam.R).tolist()
    out = reference_render(**_one([mu], [1.0], [0.9], np.zeros((1, 1, 3))), camera=cam, config=GRADCHECK_CONFIG)
    assert out["alpha"].abs().max() == 0


def _grad_scene():
    cam = make_camera(width=9, height=7, fx=9.0, fy=7.5)
    scene = random_scene(cam, 4, 2, seed=5, n_behind=0, n_near=1, spread=0.8, opacity_range=(0.3, 0.995))
    return cam, scene


def _directional_fd(f, params, name, direction):
    plus = dict(params, **{name: params[name] + FD_EPS * direction})
    minus = dict(params, **{name: params[name] - FD_EPS * direction})
    return (f(plus) - f(minus)) / (2 * FD_EPS)


@pytest.mark.parametrize("output", [n for n in OUTPUT_NAMES if n != "distortion"])
def test_autograd_matches_central_differences(output):
    cam, scene = _grad_scene()
    cfg = GRADCHECK_CONFIG
    out0 = reference_render(**scene, camera=cam, config=cfg)
    assert out0["margin"].min() > 1e-4  # no decision (median crossing, near) within FD reach (~1e-5)
    W = {output: torch.randn(out0[output].shape, generator=torch.Generator().manual_seed(6), dtype=torch.float64)}
    leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items()}
    loss = weighted_loss(reference_render(**leaves, camera=cam, config=cfg), W)
    grads = torch.autograd.grad(loss, list(leaves.values()), allow_unused=True)
    f = lambda p: weighted_loss(reference_render(**p, camera=cam, config=cfg), W).item()  # noqa: E731
    gen = torch.Generator().manual_seed(7)
    for (name, value), g in zip(scene.items(), grads):
        direction = torch.randn(value.shape, generator=gen, dtype=torch.float64)
        if name == "quats":  # stay on the unit sphere to first order
            direction -= (direction * value).sum(-1, keepdim=True) * value
        fd = _directional_fd(f, scene, name, direction)
        if g is None:  # e.g. SH for the geometric outputs: the output must not depend on it at all
            assert fd == 0.0, (output, name, fd)
            continue
        ad = (g * direction).sum().item()
        scale = g.norm().item() * direction.norm().item()
        assert scale > 0, (output, name)
        assert abs(fd - ad) <= FD_RTOL * scale, (output, name, fd, ad)


@pytest.mark.parametrize("form", ["paper", "gof"])
def test_distortion_gradient_flows_only_through_t_star(form):
    """Autograd of the distortion = d/dθ of the pairwise sum (paper: Σ_{j before k} 2 w_k w_j (t_k − t_j);
    GOF: Σ_{j before k} w_k w_j (m_k − m_j)²) with the weights w frozen at θ₀."""
    cam, scene = _grad_scene()
    cfg = dataclasses.replace(GRADCHECK_CONFIG, distortion=form)
    out0 = reference_render(**scene, camera=cam, config=cfg)
    w0 = out0["weights"]
    z = (scene["means"] @ torch.tensor(cam.R).T + torch.tensor(cam.t))[:, 2]
    rank = torch.argsort(torch.argsort(z, stable=True))
    before = (rank[:, None] < rank[None, :]).double()  # before[j, k]: j is blended before k
    Wd = torch.randn(out0["distortion"].shape, generator=torch.Generator().manual_seed(8), dtype=torch.float64)

    def frozen(p):
        t = reference_render(**p, camera=cam, config=cfg)["t_star"]
        f = distortion_depth(t, cfg)
        diff = f[..., None, :] - f[..., :, None]
        pair = w0[..., :, None] * w0[..., None, :] * (2 * diff if form == "paper" else diff**2) * before
        return (Wd * pair.sum((-1, -2))).sum()

    assert frozen(scene).item() == pytest.approx((Wd * out0["distortion"]).sum().item(), abs=EXACT)
    leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items()}
    loss = (Wd * reference_render(**leaves, camera=cam, config=cfg)["distortion"]).sum()
    grads = torch.autograd.grad(loss, list(leaves.values()), allow_unused=True)
    for (name, value), g in zip(scene.items(), grads):
        if name in ("opacities", "sh"):  # t* does not depend on them: no gradient at all
            assert g is None or g.abs().max() == 0, name
            continue
        direction = torch.randn(value.shape, generator=torch.Generator().manual_seed(9), dtype=torch.float64)
        fd = _directional_fd(lambda p: frozen(p).item(), scene, name, direction)
        assert abs(fd - (g * direction).sum().item()) <= FD_RTOL * g.norm().item() * direction.norm().item(), name


def test_densify_stats_match_per_pixel_finite_differences():
    """g_p for every pixel from four shifted renders per Gaussian (screen shift at fixed depth)."""
    cam, scene = _grad_scene()
    cfg = GRADCHECK_CONFIG
    gen = torch.Generator().manual_seed(10)
    out0 = reference_render(**scene, camera=cam, config=cfg)
    W = {k: torch.randn(out0[k].shape, generator=gen, dtype=torch.float64) for k in OUTPUT_NAMES if k != "distortion"}
    grad2d, grad2d_abs = reference_densify_stats(**scene, camera=cam, weights=W, config=cfg)
    R, tc = torch.tensor(cam.R), torch.tensor(cam.t)
    mu_v = scene["means"] @ R.T + tc
    n = mu_v.shape[0]
    g_fd = torch.zeros(cam.height, cam.width, n, 2, dtype=torch.float64)
    for k in range(n):
        for axis, f in ((0, cam.fx), (1, cam.fy)):
            maps = []
            for sign in (1.0, -1.0):
                shifted = mu_v.clone()
                shifted[k, axis] += sign * FD_EPS * mu_v[k, 2] / f
                out = reference_render(**dict(scene, means=(shifted - tc) @ R), camera=cam, config=cfg)
                maps.append(sum((out[name] * W[name]).reshape(cam.height, cam.width, -1).sum(-1) for name in W))
            g_fd[..., k, axis] = (maps[0] - maps[1]) / (2 * FD_EPS) * (cam.width if axis == 0 else cam.height) / 2
    scale = g_fd.norm(dim=-1).sum((0, 1))
    assert torch.all(scale > 0)
    assert torch.all((grad2d - g_fd.sum((0, 1))).norm(dim=-1) <= FD_RTOL * scale)
    assert torch.all((grad2d_abs - g_fd.norm(dim=-1).sum((0, 1))).abs() <= FD_RTOL * scale)
    assert torch.all(grad2d.norm(dim=-1) < grad2d_abs)  # cancellation: signed sum is strictly shorter


def test_screen_boxes_bound_the_projected_ellipsoid():
    cam = make_camera()
    scene = random_scene(cam, 12, 0, seed=11)
    box, status = reference_screen_boxes(scene["means"], scene["quats"], scene["scales"], scene["opacities"], cam)
    assert status[0] == 0 and status[1] == 2 and (status[2:] == 1).all()  # behind, near-straddling, rest
    sphere = np.random.default_rng(12).normal(size=(20000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    cfg = RefConfig()
    for k in np.flatnonzero(status.numpy() == 1):
        kk = min(cfg.k_max, math.sqrt(2 * math.log(scene["opacities"][k].item() / cfg.alpha_min)))
        Rk = quat_to_rotmat(scene["quats"][k : k + 1])[0].numpy()
        pts = scene["means"][k].numpy() + kk * (sphere * scene["scales"][k].numpy()) @ Rk.T
        uv, _ = cam.project(pts)
        lo, hi = uv.min(0), uv.max(0)
        b = box[k].numpy()
        assert b[0] <= lo[0] + 1e-9 and b[1] >= hi[0] - 1e-9 and b[2] <= lo[1] + 1e-9 and b[3] >= hi[1] - 1e-9
        assert np.abs(b - [lo[0], hi[0], lo[1], hi[1]]).max() < 0.02 * max(hi - lo)  # tight (sampling gap)
