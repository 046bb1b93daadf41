"""Multi-view photometric term (gof_warp.training.multiview): the plane warp against float64 geometry, the loss on an
analytic textured plane (zero at the true depth, gradients towards it, float64 central differences), the masks,
neighbour selection, config checks and a training run with the term on."""

import math

import numpy as np
import pytest
import torch

from gof_warp.core.camera import look_at
from gof_warp.core.config import merge
from gof_warp.core.errors import GofError
from gof_warp.training.multiview import (MultiViewConfig, MultiViewTerm, _loss, grey, multiview_loss, ncc, neighbour_views,
                                plane_warp, sample_centres)

PLANE_Z = 5.0  # the world plane z = 5, textured by _texture


def _texture(x, y):
    return 0.5 + 0.2 * np.sin(3.1 * x + 0.4) + 0.15 * np.cos(4.3 * y + 1.3 * x) + 0.1 * np.sin(7.7 * (x - y))


def _camera(x, size=48, name=""):
    return look_at((x, 0.3 * x, 0.0), (0.1, -0.05, PLANE_Z), fx=40.0, width=size, height=size, name=name)


def _plane_view(cam):
    """``(grey [H, W], z-depth [H, W], camera-space normal [3] facing the camera)`` of the textured plane, float64."""
    h, w = cam.height, cam.width
    v, u = np.mgrid[0:h, 0:w]
    rays_cam = np.stack([(u + 0.5 - cam.cx) / cam.fx, (v + 0.5 - cam.cy) / cam.fy, np.ones_like(u, float)], -1)
    rays = rays_cam @ np.asarray(cam.R)  # world directions (R^T r)
    s = (PLANE_Z - cam.center[2]) / rays[..., 2]
    hit = cam.center + s[..., None] * rays
    n_cam = np.asarray(cam.R) @ np.array([0.0, 0.0, 1.0])
    if n_cam @ np.array([0.0, 0.0, 1.0]) > 0:
        n_cam = -n_cam
    return _texture(hit[..., 0], hit[..., 1]), s, n_cam  # z-depth = s (rays_cam has z = 1)


def _pair(dtype=torch.float64):
    ref, nbr = _camera(-0.4, name="ref"), _camera(0.5, name="nbr")
    g_ref, d_ref, n_ref = _plane_view(ref)
    g_nbr, d_nbr, _ = _plane_view(nbr)
    t = lambda a: torch.tensor(a, dtype=dtype)  # noqa: E731
    return ref, nbr, t(g_ref), t(g_nbr), t(d_ref), t(d_nbr), t(n_ref)


def _maps(depth, n_cam):
    h, w = depth.shape
    normal = n_cam.expand(h, w, 3).clone()
    return normal, torch.ones(h, w, dtype=depth.dtype)


def test_plane_warp_matches_the_ray_plane_intersection():
    ref, nbr, *_ , d_ref, _, n_ref = _pair()
    centres = torch.tensor([[10, 12], [30, 25], [24, 24]])
    patch = 5
    d = d_ref[centres[:, 1], centres[:, 0]]
    uv, z, ok = plane_warp(centres, d, n_ref.expand(3, 3), ref, nbr, patch)
    assert ok.all()
    # float64 by hand: each patch pixel's ray meets the world plane; project that point into nbr
    for p, (cu, cv) in enumerate(centres.tolist()):
        for s, (du, dv) in enumerate([(a, b) for b in range(-2, 3) for a in range(-2, 3)]):
            r = np.array([(cu + du + 0.5 - ref.cx) / ref.fx, (cv + dv + 0.5 - ref.cy) / ref.fy, 1.0])
            rw = np.asarray(ref.R).T @ r
            x = ref.center + (PLANE_Z - ref.center[2]) / rw[2] * rw
            xc = np.asarray(nbr.R) @ x + np.asarray(nbr.t)
            expect = [nbr.fx * xc[0] / xc[2] + nbr.cx, nbr.fy * xc[1] / xc[2] + nbr.cy]
            assert np.allclose(uv[p, s].numpy(), expect, atol=1e-9), (p, s)
            assert math.isclose(float(z[p, s]), xc[2], rel_tol=1e-12)


def test_loss_is_zero_at_the_true_plane_and_grows_off_it():
    ref, nbr, g_ref, g_nbr, d_ref, d_nbr, n_ref = _pair()
    normal, alpha = _maps(d_ref, n_ref)
    cfg = MultiViewConfig(weight=1.0, patch=7, min_std=1e-3)
    centres = sample_centres(48, 48, 256, 7, torch.Generator().manual_seed(0))
    at, used = multiview_loss(d_ref, normal, alpha, g_ref, g_nbr, ref, nbr, centres, cfg, nbr_depth=d_nbr)
    assert int(used) > 100
    assert float(at) < 5e-3  # bilinear sampling of point-sampled photos: not exactly 0
    losses = [float(multiview_loss(d_ref * k, normal, alpha, g_ref, g_nbr, ref, nbr, centres, cfg)[0])
              for k in (0.9, 0.95, 0.98, 1.02, 1.05, 1.12)]
    assert losses[0] > losses[1] > losses[2] > float(at) < losses[3] < losses[4] < losses[5]
    assert min(losses[0], losses[5]) > 10 * float(at)


def test_gradient_points_back_to_the_true_depth():
    """Gradient descent on a depth scale factor, started 6 % in front of the plane, walks back to it."""
    ref, nbr, g_ref, g_nbr, d_ref, _, n_ref = _pair()
    normal, alpha = _maps(d_ref, n_ref)
    cfg = MultiViewConfig(weight=1.0, patch=7, min_std=1e-3)
    centres = sample_centres(48, 48, 256, 7, torch.Generator().manual_seed(1))
    k = torch.tensor(0.94, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([k], lr=0.01)
    for _ in range(60):
        opt.zero_grad()
        loss, _ = multiview_loss(d_ref * k, normal, alpha, g_ref, g_nbr, ref, nbr, centres, cfg)
        loss.backward()
        opt.step()
    assert abs(float(k.detach()) - 1.0) < 0.01, float(k.detach())


def test_gradient_matches_float64_central_differences():
    """Through the depth and the (un-normalised) normal at the patch centres, the only pixels the term reads."""
    ref, nbr, g_ref, g_nbr, d_ref, _, n_ref = _pair()
    cfg = MultiViewConfig(weight=1.0, patch=5, min_std=1e-3)
    centres = torch.tensor([[12, 14], [30, 20], [22, 33], [35, 35]])
    u, v = centres[:, 0], centres[:, 1]
    gen = torch.Generator().manual_seed(3)
    d0 = (d_ref[v, u] * (1 + 0.03 * torch.rand(4, generator=gen, dtype=torch.float64))).requires_grad_()
    n0 = (1.7 * (n_ref + 0.1 * torch.randn(4, 3, generator=gen, dtype=torch.float64))).requires_grad_()
    alpha = torch.ones(48, 48, dtype=torch.float64)

    def f(dc, nc):
        depth = d_ref.index_put((v, u), dc)
        normal = n_ref.expand(48, 48, 3).index_put((v, u), nc)
        return multiview_loss(depth, normal, alpha, g_ref, g_nbr, ref, nbr, centres, cfg)

    assert int(f(d0, n0)[1]) == 4
    assert torch.autograd.gradcheck(lambda dc, nc: f(dc, nc)[0], (d0, n0), eps=1e-6, atol=1e-7, rtol=1e-4)


def test_masks_leave_out_what_cannot_be_compared():
    ref, nbr, g_ref, g_nbr, d_ref, d_nbr, n_ref = _pair()
    normal, alpha = _maps(d_ref, n_ref)
    cfg = MultiViewConfig(weight=1.0, patch=7, min_std=1e-3)
    centres = sample_centres(48, 48, 128, 7, torch.Generator().manual_seed(2))
    full = int(multiview_loss(d_ref, normal, alpha, g_ref, g_nbr, ref, nbr, centres, cfg, nbr_depth=d_nbr)[1])
    assert full > 0
    # the neighbour saw something 20 % nearer everywhere: every patch is occluded there
    loss, used = multiview_loss(d_ref, normal, alpha, g_ref, g_nbr, ref, nbr, centres, cfg, nbr_depth=0.8 * d_nbr)
    assert int(used) == 0 and float(loss) == 0.0
    # transparent reference pixels, and a flat grey reference photo (no texture), count for nothing
    assert int(multiview_loss(d_ref, normal, 0.3 * alpha, g_ref, g_nbr, ref, nbr, centres, cfg)[1]) == 0
    depth = d_ref.clone().requires_grad_()
    loss, used = multiview_loss(depth, normal, alpha, torch.full_like(g_ref, 0.5), g_nbr, ref, nbr, centres, cfg)
    loss.backward()
    assert int(used) == 0 and torch.equal(depth.grad, torch.zeros_like(depth))
    # a neighbour looking away sees none of the patches
    away = look_at((0.0, 0.0, 0.0), (0.0, 0.0, -5.0), fx=40.0, width=48, height=48)
    assert int(multiview_loss(d_ref, normal, alpha, g_ref, g_nbr, ref, away, centres, cfg)[1]) == 0


def test_occlusion_test_is_one_sided():
    """With the neighbour's true depth: a surface rendered in front of the truth, or behind it within the tolerance,
    keeps its patches and is pulled back; one rendered further behind looks hidden and gets nothing (documented)."""
    ref, nbr, g_ref, g_nbr, d_ref, d_nbr, n_ref = _pair()
    normal, alpha = _maps(d_ref, n_ref)
    cfg = MultiViewConfig(weight=1.0, patch=7, min_std=1e-3, occlusion_tolerance=0.05)
    centres = sample_centres(48, 48, 256, 7, torch.Generator().manual_seed(4))
    full = int(multiview_loss(d_ref, normal, alpha, g_ref, g_nbr, ref, nbr, centres, cfg, nbr_depth=d_nbr)[1])
    for k, kept in ((0.94, True), (1.03, True), (1.08, False)):
        depth = (d_ref * k).requires_grad_()
        loss, used = multiview_loss(depth, normal, alpha, g_ref, g_nbr, ref, nbr, centres, cfg, nbr_depth=d_nbr)
        if kept:
            assert int(used) > 0.8 * full, k
            loss.backward()
            toward = (depth.grad * (d_ref - depth.detach())).sum()  # descent moves the depth towards the truth
            assert float(toward) < 0, k
        else:
            assert int(used) == 0, k


def test_nearest_reads_the_pixel_holding_the_point():
    from gof_warp.training.multiview import _nearest

    image = torch.arange(12.0).reshape(3, 4)  # pixel (i, j) spans [i, i + 1] x [j, j + 1]
    uv = torch.tensor([[2.99, 1.0], [3.0, 1.0], [0.0, 2.5], [-0.5, 9.0], [7.0, 0.2]])
    assert _nearest(image, uv).tolist() == [6.0, 7.0, 8.0, 8.0, 3.0]


def test_ncc_ignores_gain_and_offset():
    a = torch.rand(5, 49, dtype=torch.float64)
    assert torch.allclose(ncc(a, 0.3 * a + 0.2), torch.ones(5, dtype=torch.float64), atol=1e-4)
    assert torch.allclose(ncc(a, -a), -torch.ones(5, dtype=torch.float64), atol=1e-4)


def test_neighbours_are_the_nearest_cameras_looking_the_same_way():
    ring = [look_at((4 * math.cos(a), 4 * math.sin(a), 0.0), (0, 0, 0), width=8, height=8)
            for a in np.deg2rad(np.arange(0, 360, 30))]
    twin = look_at((4.0, 0.0, 0.0), (0, 0, 0), width=8, height=8)  # at camera 0's centre: no baseline
    nb = neighbour_views(ring + [twin], k=2, max_angle_deg=45)
    assert sorted(nb[0]) == [1, 11] and sorted(nb[6]) == [5, 7]
    assert 12 not in nb[0] and 0 not in nb[12]
    assert neighbour_views(ring, k=3, max_angle_deg=20) == [[] for _ in ring]  # 30 degrees apart: none qualifies


@pytest.mark.parametrize("bad", [{"weight": -1.0}, {"weight": float("nan")}, {"patch": 4}, {"patch": 1},
                                 {"pixels": 0}, {"max_angle_deg": 0.0}, {"alpha_min": 1.0},
                                 {"neighbours_per_step": 0}, {"neighbours": 2, "neighbours_per_step": 3}])
def test_config_is_validated(bad):
    with pytest.raises(GofError):
        MultiViewConfig(**bad)


def test_grey_and_patches_that_do_not_fit():
    img = torch.rand(4, 5, 3)
    assert torch.allclose(grey(img), 0.299 * img[..., 0] + 0.587 * img[..., 1] + 0.114 * img[..., 2])
    with pytest.raises(GofError):
        grey(torch.rand(4, 5))
    with pytest.raises(GofError, match="do not fit"):
        sample_centres(6, 40, 8, 7)


@pytest.mark.slow
def test_term_draws_the_same_pair_for_the_same_iteration():
    cams = [_camera(x, name=f"c{i}") for i, x in enumerate((-0.5, -0.2, 0.1, 0.4))]
    views = [_plane_view(c) for c in cams]
    images = [torch.tensor(g, dtype=torch.float32)[..., None].expand(48, 48, 3).contiguous() for g, _, _ in views]
    term = MultiViewTerm(MultiViewConfig(weight=0.5, from_iter=3, neighbours=2), cams, images, seed=7)
    assert not term.active(2) and term.active(3)
    _, d0, n0 = views[0]
    out = {"median_depth": torch.tensor(d0, dtype=torch.float32), "alpha": torch.ones(48, 48),
           "normal": torch.tensor(n0, dtype=torch.float32).expand(48, 48, 3)}
    assert term(out, 0, 5) is None  # no neighbour rendered yet
    for i, (_, d, _) in enumerate(views):
        term.remember(i, torch.tensor(d, dtype=torch.float32))
    a, b = term(out, 0, 5), term(out, 0, 5)
    assert torch.equal(a[0], b[0]) and int(a[1]) > 0 and float(a[0]) < 0.01
    fresh = MultiViewTerm(MultiViewConfig(weight=0.5, from_iter=3, neighbours=2), cams, images, seed=7)  # a resume
    for i, (_, d, _) in enumerate(views):
        fresh.remember(i, torch.tensor(d, dtype=torch.float32))
    assert torch.equal(fresh(out, 0, 5)[0], a[0])
    depth = out["median_depth"] * 1.03  # off the plane: the loss depends on which patches are drawn
    draws = {float(term({**out, "median_depth": depth}, 0, it)[0]) for it in range(5, 12)}
    assert len(draws) > 1, "every iteration drew the same neighbour and patches"
    term.forget()
    assert term(out, 0, 5) is None
    late = MultiViewTerm(MultiViewConfig(weight=0.5, from_iter=100), cams, images, seed=7, views_per_step=2)
    assert late.remember_from == 100 - 2 - 1  # one epoch (4 views, 2 a step) before the term acts
    late.remember(1, out["median_depth"], 96)
    assert late.depth[1] is None
    late.remember(1, out["median_depth"], 97)
    assert torch.equal(late.depth[1], out["median_depth"])


def test_several_neighbours_average_over_those_that_see_a_patch():
    """A patch's loss is the mean over the neighbours it counts for: a neighbour looking away adds nothing (the
    patches keep the one that sees them), and two that see it give the mean of the two single-neighbour losses."""
    ref, nbr, g_ref, g_nbr, d_ref, d_nbr, n_ref = _pair()
    other = _camera(0.15, name="other")
    g_oth, d_oth, _ = (torch.tensor(a, dtype=torch.float64) if isinstance(a, np.ndarray) else a
                       for a in _plane_view(other))
    away = look_at((0.0, 0.0, 0.0), (0.0, 0.0, -5.0), fx=40.0, width=48, height=48)
    normal, alpha = _maps(d_ref, n_ref)
    cfg = MultiViewConfig(weight=1.0, patch=7, min_std=1e-3)
    centres = sample_centres(48, 48, 256, 7, torch.Generator().manual_seed(5))
    depth = d_ref * 1.04  # off the plane, so that the losses differ from neighbour to neighbour

    def multi(cams, greys, depths):
        from gof_warp.training.multiview import _relative_pose
        poses = [_relative_pose(ref, c, torch.float64, None) for c in cams]
        return _loss(depth, normal, alpha, g_ref, greys, ref.pinhole, [c.pinhole for c in cams],
                     [p[0] for p in poses], [p[1] for p in poses], centres, cfg, depths)

    one = multiview_loss(depth, normal, alpha, g_ref, g_nbr, ref, nbr, centres, cfg, nbr_depth=d_nbr)
    with_away = multi([nbr, away], [g_nbr, g_nbr], [d_nbr, None])
    assert int(with_away[1]) == int(one[1]) > 100
    assert torch.allclose(with_away[0], one[0], rtol=1e-12)
    # per patch: the mean of 1 - NCC over the neighbours that see it, each from the single-neighbour loss
    both = multi([nbr, other], [g_nbr, g_oth], [d_nbr, d_oth])
    losses, counts = [], []
    for cam, g, d in ((nbr, g_nbr, d_nbr), (other, g_oth, d_oth)):
        rows = [multiview_loss(depth, normal, alpha, g_ref, g, ref, cam, centres[i:i + 1], cfg, nbr_depth=d)
                for i in range(len(centres))]
        losses.append(torch.stack([r[0] for r in rows]))
        counts.append(torch.stack([r[1] for r in rows]).to(torch.float64))
    count = counts[0] + counts[1]
    assert int((counts[0] != counts[1]).sum()) > 0 and int((count == 2).sum()) > 100  # some patches one, most both
    expect = ((losses[0] + losses[1])[count > 0] / count[count > 0]).mean()
    assert int(both[1]) == int((count > 0).sum())
    assert torch.allclose(both[0], expect, rtol=1e-10)


def test_term_draws_several_neighbours_without_replacement():
    cams = [_camera(x, name=f"c{i}") for i, x in enumerate((-0.5, -0.2, 0.1, 0.4))]
    views = [_plane_view(c) for c in cams]
    images = [torch.tensor(g, dtype=torch.float32)[..., None].expand(48, 48, 3).contiguous() for g, _, _ in views]
    cfg = MultiViewConfig(weight=0.5, from_iter=1, neighbours=3, neighbours_per_step=3, pixels=64, patch=5)
    term = MultiViewTerm(cfg, cams, images, seed=2)
    seen = []
    term._core = lambda *args: seen.append(len(args[4])) or _loss(*args)  # count the neighbours each call gets
    _, d0, n0 = views[0]
    out = {"median_depth": torch.tensor(d0, dtype=torch.float32) * 1.03, "alpha": torch.ones(48, 48),
           "normal": torch.tensor(n0, dtype=torch.float32).expand(48, 48, 3)}
    term.remember(1, torch.tensor(views[1][1], dtype=torch.float32))
    assert term(out, 0, 4) is not None and seen[-1] == 1  # only one of the three has a depth yet
    for i, (_, d, _) in enumerate(views):
        term.remember(i, torch.tensor(d, dtype=torch.float32))
    loss, used = term(out, 0, 4)
    assert seen[-1] == 3 and int(used) > 0 and float(loss) > 0
    with pytest.raises(GofError, match="at most"):
        MultiViewConfig(weight=0.5, neighbours=2, neighbours_per_step=3)


@pytest.mark.slow
@pytest.mark.parametrize("per_step", [1, 2])
def test_compiled_term_matches_the_eager_one(per_step):
    """What the trainer compiles (traced here by aot_eager: the same graph, no code generated) gives the eager value
    and gradient, for two views in a row (one graph serves every view), against one or two neighbours a step."""
    cams = [_camera(x, name=f"c{i}") for i, x in enumerate((-0.5, -0.2, 0.1))]
    views = [_plane_view(c) for c in cams]
    images = [torch.tensor(g, dtype=torch.float32)[..., None].expand(48, 48, 3).contiguous() for g, _, _ in views]
    cfg = MultiViewConfig(weight=0.5, from_iter=1, neighbours=2, neighbours_per_step=per_step, pixels=128, patch=5)
    eager = MultiViewTerm(cfg, cams, images, seed=3)
    compiled = MultiViewTerm(cfg, cams, images, seed=3, compile_backend="aot_eager")
    for term in (eager, compiled):
        for i, (_, d, _) in enumerate(views):
            term.remember(i, torch.tensor(d, dtype=torch.float32) * 1.02)
    for view in (0, 1):
        _, d, n = views[view]
        results = []
        for term in (eager, compiled):
            depth = (torch.tensor(d, dtype=torch.float32) * 1.03).requires_grad_()
            normal = torch.tensor(n, dtype=torch.float32).expand(48, 48, 3).clone().requires_grad_()
            loss, used = term({"median_depth": depth, "normal": normal, "alpha": torch.ones(48, 48)}, view, 5)
            loss.backward()
            results.append((loss.detach(), used, depth.grad, normal.grad))
        (a, ua, ga, na), (b, ub, gb, nb) = results
        assert int(ua) == int(ub) > 0 and float(a) > 0
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-7)
        assert torch.allclose(ga, gb, rtol=1e-4, atol=1e-8) and torch.allclose(na, nb, rtol=1e-4, atol=1e-8)
    assert compiled._core is not _loss  # it stayed compiled: no fallback to the eager function


@pytest.mark.slow
@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a GPU"))])
def test_training_with_the_term_on(tmp_path, device):
    from gof_warp.data import load_scene
    from gof_warp.synthetic import make_scene
    from gof_warp.training.trainer import TrainConfig, Trainer

    scene = load_scene(make_scene("default", tmp_path / "s", views=6, resolution=(32, 32), device=device))
    cfg = merge(TrainConfig(), {"iterations": 16, "checkpoint_every": 0, "log_every": 1,
                                "model": {"sh_degree": 0, "init": "random", "random_init_points": 300},
                                "densify": {"start_iter": 100},
                                "loss": {"regularization_from_iter": 100},
                                "experimental": {"multiview": {"weight": 0.2, "from_iter": 8, "pixels": 64, "patch": 5,
                                                       "neighbours": 2, "neighbours_per_step": 2,
                                                       "max_angle_deg": 90.0}}})
    trainer = Trainer(scene, cfg, tmp_path / "run", device)
    trainer.run()
    with_term = [h for h in trainer.history if "multiview" in h]
    assert with_term and all(h["iteration"] >= 8 for h in with_term)
    assert all(math.isfinite(h["multiview"]) and 0 <= h["multiview"] <= 2 for h in with_term)
    assert any(h["multiview"] > 0 for h in with_term), "no patch was ever compared"
    for h in with_term:  # the logged total is the loss the step minimised: colour terms + weight x multiview
        expect = 0.8 * h["l1"] + 0.2 * h["dssim"] + 0.2 * h["multiview"]
        assert math.isclose(h["total"], expect, rel_tol=1e-5, abs_tol=1e-7), h
    assert all(math.isfinite(h["total"]) for h in trainer.history)
