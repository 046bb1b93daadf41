"""The early reject of the per-pixel kernels and the opacity field (``project.ray_conics``, ``rasterize.ray_outside``):
the silhouette of each Gaussian's ellipsoid at its opacity-aware cutoff (enlarged by 1 %), in normalised image
coordinates, lets a (ray, Gaussian) pair be skipped in a few operations instead of the ray–Gaussian maths.

- golden case: a sphere straight ahead has the circle of its tangent cone as its silhouette;
- against float64 brute force over every pixel of random anisotropic Gaussians (``test_render_binning``'s culling
  scene: discs, needles, some across the near plane): no pair the exact per-pixel test keeps is rejected, and every
  pair whose line of sight passes 2 % beyond the cutoff is (for the Gaussians that get a silhouette: all that lie
  beyond the near plane);
- the warp mask of the CUDA tile kernels (``rasterize_tiled.warp_rows_mask``): golden circle; against float64 brute
  force no warp with a kept pixel is skipped, and every warp 1 % outside the silhouette is;
- renders and gradients with and without the reject are bitwise equal (the rejected pairs never changed a pixel); on
  CUDA the forward is, and the gradients agree within the spread of the float atomics' order.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import warp as wp

from gof_warp.core.camera import Camera, look_at
from gof_warp.kernels import renderer
from gof_warp.kernels.project import PIXEL_CONIC_K_MARGIN, preprocess_gaussians, ray_conics, screen_bounds
from gof_warp.kernels.render_types import CameraParams, RasterSettings, camera_params_from, make_raster_settings
from gof_warp.kernels.rasterize import ray_outside
from gof_warp.kernels.rasterize_tiled import warp_rows_mask
from gof_warp.kernels.renderer import sh_parts
from gof_warp.kernels.tile_overlap import empty_tile_ellipses
from test_render_binning import _cull_scene, _rotations
from test_render_host_glue import CUDA_GRAD_RTOL

ALPHA_MIN = 1.0 / 255.0
# On CUDA the backward's float atomics add in a varying order. In this test's scene (near-plane Gaussians whose
# gradients sum large contributions of both signs) two renders of the same code on an H100 differed by up to 7.3e-4 of
# the gradient's largest element (scales, tile size 8; measured on one H100, repeated renders of this scene):
# the tolerance is 4× that.
CUDA_SPREAD = 3e-3
K_MAX = math.sqrt(2.0 * math.log(255.0))
NEAR = 0.2


def _cutoff(opac):
    return np.minimum(K_MAX, np.sqrt(2.0 * np.log(np.maximum(opac / ALPHA_MIN, 1.0))))


def _silhouettes(cam, means, quats, scales, opac, device="cpu"):
    """``(conic [n, 3], centre [n, 2], radii [n])`` from the renderer's kernels on ``device``."""
    settings = make_raster_settings(cam.width, cam.height)
    camp = camera_params_from(cam)
    n = len(means)
    arr = lambda a, t: wp.array(np.asarray(a, np.float32), dtype=t, device=device)  # noqa: E731
    sh_dc, sh_rest = sh_parts(wp.zeros((n, 1), dtype=wp.vec3, device=device))
    mu_v, P, o_g, col = (wp.empty(n, dtype=t, device=device) for t in (wp.vec3, wp.mat33, wp.vec3, wp.vec3))
    wp.launch(preprocess_gaussians, n, inputs=[arr(means, wp.vec3), arr(quats, wp.vec4), arr(scales, wp.vec3), sh_dc,
                                               sh_rest, 0, camp.R, camp.t, camp.centre],
              outputs=[mu_v, P, o_g, col], device=device)  # fmt: skip
    rect, touched, radii, depth = (wp.empty(n, dtype=t, device=device) for t in (wp.vec4i, wp.int32, wp.int32, float))
    wp.launch(screen_bounds, n, inputs=[mu_v, arr(quats, wp.vec4), arr(scales, wp.vec3), arr(opac, float), camp,
                                        settings],
              outputs=[rect, touched, radii, depth, empty_tile_ellipses(n, device)], device=device)  # fmt: skip
    conic, centre = wp.empty(n, dtype=wp.vec3, device=device), wp.empty(n, dtype=wp.vec2, device=device)
    wp.launch(ray_conics, n, inputs=[mu_v, arr(quats, wp.vec4), arr(scales, wp.vec3), arr(opac, float), radii, camp,
                                       settings], outputs=[conic, centre], device=device)  # fmt: skip
    return conic.numpy().astype(np.float64), centre.numpy().astype(np.float64), radii.numpy()


def _power(conic, centre, a, b):
    """``A (da + β db)² + γ db²`` (= ``A da² + 2B da db + C db²``; float64 of the stored float32 ``(A, β, γ)``) for
    rays ``(a, b, 1)``."""
    da, db = a - centre[0], b - centre[1]
    return conic[0] * (da + conic[1] * db) ** 2 + conic[2] * db * db


def test_sphere_straight_ahead_has_the_circle_of_its_tangent_cone():
    f, z, sigma, opacity = 50.0, 3.0, 0.1, 0.6
    cam = Camera(np.eye(3), np.zeros(3), fx=f, fy=f, cx=32.0, cy=24.0, width=64, height=48)
    conic, centre, radii = _silhouettes(cam, np.array([[0.0, 0.0, z]]), np.array([[1.0, 0.0, 0.0, 0.0]]),
                                        np.full((1, 3), sigma), np.array([opacity]))
    k = float(_cutoff(np.array([opacity]))[0]) * (1.0 + float(PIXEL_CONIC_K_MARGIN))
    radius = k * sigma / math.sqrt(z * z - (k * sigma) ** 2)  # tan of the tangent cone's half-angle
    assert radii[0] > 0
    np.testing.assert_allclose(conic[0], [1.0 / radius**2, 0.0, 1.0 / radius**2], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(centre[0], [0.0, 0.0], atol=1e-7)


def test_reject_never_drops_a_pair_the_exact_test_keeps_and_drops_the_rest():
    cam = look_at((0.3, -2.0, 0.5), (0.0, 0.0, 0.0), fx=120.0, fy=108.0, cx=71.3, cy=57.9, width=150, height=110)
    means, quats, scales, opac = _cull_scene(cam, 400, seed=3)
    conic, centre, radii = _silhouettes(cam, means, quats, scales, opac)
    mu = (means @ cam.R.T + cam.t).astype(np.float32).astype(np.float64)
    Rv = (cam.R.astype(np.float32) @ _rotations(quats.astype(np.float32))).astype(np.float64)
    k = _cutoff(opac)
    px, py = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    d = np.stack([(px + 0.5 - cam.cx) / cam.fx, (py + 0.5 - cam.cy) / cam.fy, np.ones(px.shape)], -1)
    kept_pairs = rejected_far = far_pairs = with_silhouette = 0
    for g in np.nonzero(radii > 0)[0]:
        P = Rv[g].T / scales[g][:, None]
        Pd, Pmu = d @ P.T, P @ mu[g]
        t = (Pd @ Pmu) / (Pd**2).sum(-1)
        d2 = (np.cross(Pmu, Pd) ** 2).sum(-1) / (Pd**2).sum(-1)
        kept = (d2 <= k[g] ** 2) & (t > NEAR)
        power = _power(conic[g], centre[g], d[..., 0], d[..., 1])
        assert not (kept & (power > 1.0)).any(), f"Gaussian {g}: a pair the exact test keeps is rejected"
        kept_pairs += int(kept.sum())
        if conic[g].any():
            with_silhouette += 1
            far = d2 > (1.02 * k[g]) ** 2
            far_pairs += int(far.sum())
            rejected_far += int((far & (power > 1.0)).sum())
            assert (power[far] > 1.0).all(), f"Gaussian {g}: a pair 2 % beyond the cutoff is not rejected"
        else:  # no silhouette only for ellipsoids that reach the near plane
            assert mu[g, 2] - 1.01 * k[g] * np.sqrt((Rv[g] ** 2 @ scales[g] ** 2)[2]) <= NEAR + 1e-6, g
    in_front = int(((mu[:, 2] > 0.6) & (radii > 0)).sum())
    print(f"{kept_pairs} kept pairs, {far_pairs} far pairs, {with_silhouette} of {int((radii > 0).sum())} visible "
          f"Gaussians with a silhouette")
    assert kept_pairs > 2000 and far_pairs > 100_000 and with_silhouette >= in_front > 100


@wp.kernel
def _warp_masks(conic: wp.array(dtype=wp.vec3), centre: wp.array(dtype=wp.vec2), gauss: wp.array(dtype=int),
                tiles: wp.array(dtype=int), cam: CameraParams, settings: RasterSettings, out: wp.array(dtype=int)):
    i = wp.tid()
    out[i] = warp_rows_mask(conic[gauss[i]], centre[gauss[i]], tiles[i], cam, settings)


def _masks(conic, centre, pairs, cam, settings):
    """``warp_rows_mask`` on the CPU for each ``(gaussian, tile)`` row of ``pairs``."""
    pairs = np.asarray(pairs, np.int32).reshape(-1, 2)
    out = wp.empty(len(pairs), dtype=int, device="cpu")
    wp.launch(_warp_masks, len(pairs), inputs=[wp.array(conic.astype(np.float32), dtype=wp.vec3, device="cpu"),
                                               wp.array(centre.astype(np.float32), dtype=wp.vec2, device="cpu"),
                                               wp.array(pairs[:, 0], dtype=int, device="cpu"),
                                               wp.array(pairs[:, 1], dtype=int, device="cpu"), camera_params_from(cam),
                                               settings], outputs=[out], device="cpu")  # fmt: skip
    return out.numpy()


def test_warp_mask_golden_circle():
    """A circle of radius 1.5 px around pixel (7, 5) of tile 0 meets rows 4–6: warps 2 and 3 (rows 4–5, 6–7); tile 1
    (columns 16–31) meets none of it; a zero conic (no silhouette) lets every warp through."""
    cam = Camera(np.eye(3), np.zeros(3), fx=100.0, fy=100.0, cx=0.0, cy=0.0, width=64, height=32)
    rho = 1.5 / 100.0
    conic = np.array([[1 / rho**2, 0.0, 1 / rho**2], [0.0, 0.0, 0.0]])
    centre = np.array([[0.075, 0.055], [0.0, 0.0]])
    masks = _masks(conic, centre, [(0, 0), (0, 1), (1, 0), (0, 4)], cam, make_raster_settings(64, 32))
    assert masks.tolist() == [0b1100, 0, 0xFF, 0]  # tile 4 (rows 16-31) is below the circle


@pytest.mark.slow
def test_warp_mask_never_skips_a_kept_pixel():
    """Against float64 brute force on the scene of discs, needles and near-plane Gaussians: a warp (16 × 2 pixels of
    a 16 × 16 tile) is skipped only if no pixel of it is kept by the exact per-pixel test, and a warp whose rows pass
    1 % beyond the silhouette everywhere along their pixel-centre segments (float64) is skipped."""
    cam = look_at((0.3, -2.0, 0.5), (0.0, 0.0, 0.0), fx=120.0, fy=108.0, cx=71.3, cy=57.9, width=150, height=110)
    means, quats, scales, opac = _cull_scene(cam, 400, seed=3)
    conic, centre, radii = _silhouettes(cam, means, quats, scales, opac)
    settings = make_raster_settings(cam.width, cam.height)
    ts, tiles_x, tiles_y = 16, settings.tiles_x, settings.tiles_y
    mu = (means @ cam.R.T + cam.t).astype(np.float32).astype(np.float64)
    Rv = (cam.R.astype(np.float32) @ _rotations(quats.astype(np.float32))).astype(np.float64)
    k = _cutoff(opac)
    W, H = tiles_x * ts, tiles_y * ts  # whole tiles (pixels past the image are never kept: masked below)
    px, py = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    d = np.stack([(px + 0.5 - cam.cx) / cam.fx, (py + 0.5 - cam.cy) / cam.fy, np.ones(px.shape)], -1)
    inside = (px < cam.width) & (py < cam.height)
    visible = np.nonzero(radii > 0)[0]
    pairs = [(g, t) for g in visible for t in range(tiles_x * tiles_y)]
    masks = _masks(conic, centre, pairs, cam, settings).reshape(len(visible), tiles_x * tiles_y)
    skipped = far_warps = kept_warps = 0
    for gi, g in enumerate(visible):
        P = Rv[g].T / scales[g][:, None]
        Pd, Pmu = d @ P.T, P @ mu[g]
        t = (Pd @ Pmu) / (Pd**2).sum(-1)
        d2 = (np.cross(Pmu, Pd) ** 2).sum(-1) / (Pd**2).sum(-1)
        kept = (d2 <= k[g] ** 2) & (t > NEAR) & inside
        # per warp (tile, w): any kept pixel; the float64 minimum of the conic over its two rows' segments
        kept_w = kept.reshape(tiles_y, 8, 2, tiles_x, ts).any(axis=(2, 4)).transpose(0, 2, 1).reshape(-1, 8)
        bits = (masks[gi][:, None] >> np.arange(8)) & 1
        assert not (kept_w & (bits == 0)).any(), f"Gaussian {g}: a warp with a kept pixel is skipped"
        kept_warps += int(kept_w.sum())
        skipped += int((bits == 0).sum())
        if conic[g].any():
            u0 = (np.arange(tiles_x) * ts + 0.5 - cam.cx) / cam.fx
            u1 = (np.arange(tiles_x) * ts + ts - 0.5 - cam.cx) / cam.fx
            v = (np.arange(H) + 0.5 - cam.cy) / cam.fy
            # the conic's minimum along each row segment, by dense sampling (1,000 points a segment) in float64
            frac = np.linspace(0.0, 1.0, 1000)
            u = u0[:, None] + (u1 - u0)[:, None] * frac[None, :]  # [tiles_x, 1000]
            q = _power(conic[g], centre[g], u[None, :, :], v[:, None, None]).min(axis=2)  # [rows, tiles_x]
            row_min = q.reshape(tiles_y, 8, 2, tiles_x).min(axis=2).transpose(0, 2, 1).reshape(-1, 8)
            far = row_min > 1.01
            far_warps += int(far.sum())
            assert (bits[far] == 0).all(), f"Gaussian {g}: a warp 1 % outside the silhouette is not skipped"
    print(f"{kept_warps} warps with kept pixels, {skipped} of {masks.size * 8} (Gaussian, warp) pairs skipped")
    assert kept_warps > 200 and far_warps > 0.5 * masks.size * 8 and skipped >= far_warps


@wp.kernel
def _outside(conic: wp.array(dtype=wp.vec3), centre: wp.array(dtype=wp.vec2), rays: wp.array(dtype=wp.vec3),
             out: wp.array(dtype=int)):
    i = wp.tid()
    out[i] = wp.where(ray_outside(conic[0], centre[0], rays[i]), 1, 0)


@pytest.mark.parametrize("aspect", [100.0, 1000.0, 3000.0])
def test_reject_is_stable_for_thin_needles(aspect):
    """``ray_outside`` in float32 for needles of aspect up to 3000:1 at 45° (the worst angle for the expanded
    ``A da² + 2B da db + C db²``, whose terms cancel to an error of ~0.7 at 3000:1): no ray well inside the silhouette
    (float64 value ≤ 0.99) is rejected, and every ray well outside (≥ 1.01) is. The silhouette is built through
    ``tile_overlap.ray_conic`` from the conic of a cone of rays, as ``ray_conics`` builds it."""
    rng = np.random.default_rng(int(aspect))
    s_major = 0.3
    s_minor = s_major / aspect
    c45 = math.sqrt(0.5)
    R = np.array([[c45, -c45], [c45, c45]])
    M = R @ np.diag([1 / s_major**2, 1 / s_minor**2]) @ R.T
    A, B, C = M[0, 0], M[0, 1], M[1, 1]
    conic = np.array([[A, B / A, C - B * B / A]], np.float32)
    centre = np.array([[0.137, -0.211]], np.float32)
    # rays near the needle's outline, most of them near its far tips where the expanded form fails
    phi = rng.uniform(0.0, 2.0 * np.pi, 20000)
    phi[:15000] = rng.normal(0.0, 0.05, 15000) + np.pi * rng.integers(0, 2, 15000)
    radius = rng.uniform(0.9, 1.1, 20000)
    local = np.stack([s_major * np.cos(phi), s_minor * np.sin(phi)], -1) * radius[:, None]
    ab = centre.astype(np.float64) + local @ R.T
    rays = np.concatenate([ab, np.ones((len(ab), 1))], 1).astype(np.float32)
    d = rays[:, :2].astype(np.float64) - centre.astype(np.float64)
    q64 = (d @ M * d).sum(1)  # the exact silhouette value of the float32 rays
    out = wp.empty(len(rays), dtype=int, device="cpu")
    wp.launch(_outside, len(rays), inputs=[wp.array(conic, dtype=wp.vec3, device="cpu"),
                                           wp.array(centre, dtype=wp.vec2, device="cpu"),
                                           wp.array(rays, dtype=wp.vec3, device="cpu")], outputs=[out], device="cpu")
    rejected = out.numpy() == 1
    inside, outside = q64 <= 0.99, q64 >= 1.01
    assert inside.sum() > 1000 and outside.sum() > 1000
    assert not rejected[inside].any(), f"{int(rejected[inside].sum())} rays inside the silhouette rejected"
    assert rejected[outside].all(), f"{int((~rejected[outside]).sum())} rays outside the silhouette kept"


@wp.kernel
def _no_reject(mu_v: wp.array(dtype=wp.vec3), quats: wp.array(dtype=wp.vec4), scales: wp.array(dtype=wp.vec3),
               opacities: wp.array(dtype=float), radii: wp.array(dtype=wp.int32), cam: CameraParams,
               settings: RasterSettings, conic: wp.array(dtype=wp.vec3), centre: wp.array(dtype=wp.vec2)):  # fmt: skip
    k = wp.tid()
    conic[k] = wp.vec3(0.0)
    centre[k] = wp.vec2(0.0)


@pytest.mark.parametrize("tile_size", [16, 8])
def test_renders_and_gradients_are_the_same_without_the_reject(tile_size, device, monkeypatch):
    from reference_render import make_camera, random_scene

    from gof_warp.rendering.render import RenderConfig, rasterize

    cam = make_camera(width=97, height=71, fx=90.0, fy=80.0)
    scene = random_scene(cam, 300, 2, seed=11, n_behind=3, n_near=8, spread=1.5)
    flat = torch.rand(300, generator=torch.Generator().manual_seed(0)) < 0.5
    scene["scales"][flat, 2] *= 0.02  # oblique discs
    names = ("means", "quats", "scales", "opacities", "sh")
    cfg = RenderConfig(tile_size=tile_size, background=(0.2, 0.5, 1.0))

    def run():
        leaves = [scene[k].float().to(device).clone().requires_grad_(True) for k in names]
        out = rasterize(*leaves, cam, config=cfg)
        w = torch.Generator().manual_seed(1)
        loss = sum((out[k] * torch.randn(out[k].shape, generator=w).to(device)).sum() for k in sorted(out)
                   if out[k].is_floating_point())
        loss.backward()
        grads = {f"grad_{k}": x.grad.cpu() for k, x in zip(names, leaves)}
        return {**{k: v.detach().cpu() for k, v in out.items()}, **grads}

    with_reject = run()
    monkeypatch.setattr(renderer, "ray_conics", _no_reject)
    without = run()
    for key in with_reject:
        if key.startswith("grad_") and device != "cpu":  # CUDA's float atomics add in a varying order (the forward
            scale = float(without[key].abs().max())  # stays exact); see CUDA_SPREAD
            torch.testing.assert_close(with_reject[key], without[key], rtol=CUDA_GRAD_RTOL, atol=CUDA_SPREAD * scale)
        else:
            assert torch.equal(with_reject[key], without[key]), key
    assert float(with_reject["alpha"].mean()) > 0.3  # the scene covers the image
    quats = scene["quats"].numpy() / np.linalg.norm(scene["quats"].numpy(), axis=1, keepdims=True)
    conic, _, radii = _silhouettes(cam, scene["means"].numpy(), quats, scene["scales"].numpy(),
                                   scene["opacities"].numpy(), device)
    assert (conic.any(axis=1) & (radii > 0)).sum() > 0.8 * (radii > 0).sum()  # the reject is on for most of them


def test_opacity_field_is_bitwise_the_same_without_the_reject(monkeypatch):
    """The field skips the same pairs first (a ray outside the silhouette has ``α(t*) < alpha_min``): bit for bit the
    field without it, on a scene of flat and needle Gaussians seen from seven views at points near and between them."""
    from test_opacity_field import _cameras, _scene

    from gof_warp.core.model import Gaussians
    from gof_warp.rendering.opacity_field import OpacityFieldConfig, opacity_field
    from gof_warp.rendering.render import RenderConfig

    means, quats, scales, opac = _scene(n=60, seed=7)
    scales[::3, 2] *= 0.02  # discs
    scales[1::3, 1:] *= 0.05  # needles
    g = Gaussians.from_activated(means, quats, scales, opac, device="cpu")
    cams = _cameras(n=7)
    rng = np.random.default_rng(8)
    points = np.concatenate([rng.uniform(-0.8, 0.8, (400, 3)), means + 0.1 * rng.normal(size=means.shape)])
    cfg = dict(render_config=RenderConfig(), config=OpacityFieldConfig(cpu_processes=1), return_seen=True)
    with_reject, seen = opacity_field(g, cams, points, **cfg)
    monkeypatch.setattr(renderer, "ray_conics", _no_reject)
    without, seen_without = opacity_field(g, cams, points, **cfg)
    np.testing.assert_array_equal(with_reject.numpy(), without.numpy())
    np.testing.assert_array_equal(seen.numpy(), seen_without.numpy())
    assert ((with_reject.numpy() > 0.05) & (with_reject.numpy() < 0.95)).sum() > 100, "partial opacities exercised"
