"""Loss terms against float64 numpy references (brute force, written independently of the torch code)."""

import numpy as np
import pytest
import torch
from scipy.signal import convolve2d

from gof_warp.core.camera import Camera
from gof_warp.core.errors import GofError
from gof_warp.training.losses import (LossConfig, depth_normal_consistency, depth_to_normal, distortion_loss, dssim, l1,
                             total_loss)

TOL64 = 1e-10  # float64 torch vs float64 numpy: only summation-order rounding
TOL_PLANE = 1e-9  # central differences of an exact plane lie in the plane: exact up to rounding
DEPTH_GRAD_BOUND = 1.0  # per-pixel terms are O(1/(H W)); a large depth gradient means a normalize of ~0 blew up

H, W = 13, 17


def _camera(cx=7.3, cy=5.1, fx=21.0, fy=19.0):
    """Off-centre principal point on purpose (pixel rays use (i + 0.5 - cx) / fx)."""
    return Camera(R=np.eye(3), t=np.zeros(3), fx=fx, fy=fy, cx=cx, cy=cy, width=W, height=H)


def _np_ssim(x, y, size=11, sigma=1.5):
    """SSIM of [C, H, W] float64 arrays: full 2-D Gaussian window, zero padding, mean over everything."""
    i = np.arange(size) - size // 2
    g = np.exp(-(i**2) / (2 * sigma**2))
    g /= g.sum()
    win = np.outer(g, g)
    f = lambda a: convolve2d(a, win, mode="same", boundary="fill")  # noqa: E731  (symmetric window)
    c1, c2 = 0.01**2, 0.03**2
    out = []
    for a, b in zip(x, y):
        mx, my = f(a), f(b)
        sxx, syy, sxy = f(a * a) - mx**2, f(b * b) - my**2, f(a * b) - mx * my
        out.append(((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx**2 + my**2 + c1) * (sxx + syy + c2)))
    return np.mean(out)


def _np_points(depth, cam):
    h, w = depth.shape
    jj, ii = np.mgrid[0:h, 0:w]
    rays = np.stack([(ii + 0.5 - cam.cx) / cam.fx, (jj + 0.5 - cam.cy) / cam.fy, np.ones((h, w))], -1)
    return depth[..., None] * rays


def _np_depth_normal(depth, cam):
    """Per-pixel loops: N = normalize((P[v+1,u]-P[v-1,u]) x (P[v,u+1]-P[v,u-1])), 0 on the border."""
    p = _np_points(depth, cam)
    h, w = depth.shape
    n = np.zeros((h, w, 3))
    for v in range(1, h - 1):
        for u in range(1, w - 1):
            c = np.cross(p[v + 1, u] - p[v - 1, u], p[v, u + 1] - p[v, u - 1])
            n[v, u] = c / np.linalg.norm(c)
    return n


def _smooth_depth(rng):
    jj, ii = np.mgrid[0:H, 0:W]
    return 2.0 + 0.3 * np.sin(ii / 3.0) + 0.2 * np.cos(jj / 2.5) + 0.01 * rng.random((H, W))


def test_l1_and_distortion_match_numpy():
    rng = np.random.default_rng(0)
    a, b, d = rng.random((H, W, 3)), rng.random((H, W, 3)), rng.random((H, W))
    assert abs(l1(torch.tensor(a), torch.tensor(b)).item() - np.abs(a - b).mean()) < TOL64
    assert abs(distortion_loss(torch.tensor(d)).item() - d.mean()) < TOL64


def test_dssim_matches_numpy_full_window():
    rng = np.random.default_rng(1)
    a = rng.random((H, W, 3))
    b = np.clip(a + 0.2 * rng.standard_normal((H, W, 3)), 0, 1)
    ref = 1.0 - _np_ssim(a.transpose(2, 0, 1), b.transpose(2, 0, 1))
    assert abs(dssim(torch.tensor(a), torch.tensor(b)).item() - ref) < TOL64
    assert abs(dssim(torch.tensor(a), torch.tensor(a)).item()) < TOL64


def test_depth_to_normal_of_tilted_plane_is_plane_normal():
    cam = _camera()
    n_true = np.array([0.3, -0.5, -1.0])
    n_true /= np.linalg.norm(n_true)  # faces the camera: n · (point on plane) < 0
    x0 = np.array([0.1, 0.2, 3.0])
    p = _np_points(np.ones((H, W)), cam)  # rays with z = 1
    depth = (n_true @ x0) / (p @ n_true)
    normals, valid = depth_to_normal(torch.tensor(depth), cam, return_valid=True)
    normals = normals.numpy()
    assert valid[1:-1, 1:-1].all() and not valid[0].any() and not valid[:, -1].any()
    np.testing.assert_allclose(normals[1:-1, 1:-1], np.broadcast_to(n_true, (H - 2, W - 2, 3)), atol=TOL_PLANE)
    assert np.all(normals[0] == 0) and np.all(normals[:, 0] == 0)


def test_depth_to_normal_matches_loop_reference_and_faces_camera():
    cam = _camera()
    depth = _smooth_depth(np.random.default_rng(2))
    got = depth_to_normal(torch.tensor(depth), cam).numpy()
    np.testing.assert_allclose(got, _np_depth_normal(depth, cam), atol=TOL64)
    facing = (got[1:-1, 1:-1] * _np_points(depth, cam)[1:-1, 1:-1]).sum(-1)
    assert np.all(facing < 0)


def _per_gaussian_pixels(rng, k=3):
    """Per pixel k blended Gaussians: weights w [H, W, k] (sum < 1) and unit normals n [H, W, k, 3]."""
    w = rng.random((H, W, k)) / k
    w[:2, :3] = 0.0  # a few empty pixels
    n = rng.standard_normal((H, W, k, 3))
    n[..., 2] = -np.abs(n[..., 2]) - 0.5
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return w, n


def test_normal_consistency_paper_form_equals_per_gaussian_sum():
    rng = np.random.default_rng(3)
    cam = _camera()
    depth = _smooth_depth(rng)
    w, n = _per_gaussian_pixels(rng)
    N = _np_depth_normal(depth, cam)
    per_pixel = (w * (1.0 - np.einsum("hwkc,hwc->hwk", n, N))).sum(-1)
    per_pixel[[0, -1], :] = 0.0
    per_pixel[:, [0, -1]] = 0.0  # border: N undefined, no cost
    ref = per_pixel.mean()
    rendered_normal, alpha = (w[..., None] * n).sum(2), w.sum(-1)
    got = depth_normal_consistency(torch.tensor(depth), torch.tensor(rendered_normal), cam, torch.tensor(alpha))
    assert abs(got.item() - ref) < TOL64


def test_normal_consistency_gof_form_matches_code_definition():
    rng = np.random.default_rng(4)
    cam = _camera()
    depth = _smooth_depth(rng)
    w, n = _per_gaussian_pixels(rng)
    rendered = (w[..., None] * n).sum(2)
    norm = np.linalg.norm(rendered, axis=-1, keepdims=True)
    unit = np.where(norm > 0, rendered / np.maximum(norm, 1e-300), 0.0)
    ref = (1.0 - (unit * _np_depth_normal(depth, cam)).sum(-1)).mean()  # border N = 0 -> term 1
    got = depth_normal_consistency(torch.tensor(depth), torch.tensor(rendered), cam, form="gof")
    assert abs(got.item() - ref) < TOL64
    with pytest.raises(GofError):
        depth_normal_consistency(torch.tensor(depth), torch.tensor(rendered), cam)  # paper form needs alpha


def _render_out(rng, dtype=torch.float64):
    depth = _smooth_depth(rng)
    depth[4:7, 5:9] = 0.0  # a hole (no Gaussian): depth edges and a degenerate neighbourhood
    depth[9, [3, 5]] = 0.0  # pixel (9, 4): both horizontal neighbours empty -> zero tangent
    w, n = _per_gaussian_pixels(rng)
    t = lambda a: torch.tensor(a, dtype=dtype, requires_grad=True)  # noqa: E731
    return {"rgb": t(rng.random((H, W, 3))), "alpha": t(w.sum(-1)), "median_depth": t(depth),
            "normal": t((w[..., None] * n).sum(2)), "distortion": t(rng.random((H, W)) * 1e-3)}


@pytest.mark.parametrize("form", ["paper", "gof"])
def test_total_loss_composition_schedule_and_switches(form):
    rng = np.random.default_rng(5)
    cam = _camera()
    out = _render_out(rng)
    gt = torch.tensor(rng.random((H, W, 3)))
    cfg = LossConfig(normal_form=form)
    rgb, g = out["rgb"].detach().numpy(), gt.numpy()
    lc = 0.8 * np.abs(rgb - g).mean() + 0.2 * (1 - _np_ssim(rgb.transpose(2, 0, 1), g.transpose(2, 0, 1)))
    loss, terms = total_loss(out, gt, cam, cfg, iteration=14_999)
    assert abs(loss.item() - lc) < TOL64 and set(terms) == {"l1", "dssim", "total"}
    loss, terms = total_loss(out, gt, cam, cfg, iteration=15_000)
    n_ref = depth_normal_consistency(out["median_depth"], out["normal"], cam, out["alpha"], form=form).item()
    expected = lc + 1000.0 * out["distortion"].detach().numpy().mean() + 0.05 * n_ref
    assert abs(loss.item() - expected) < TOL64 and abs(terms["normal"].item() - n_ref) < TOL64
    loss.backward()
    for k, v in out.items():
        if form == "gof" and k == "alpha":
            assert v.grad is None  # the code's form ignores alpha
            continue
        assert torch.isfinite(v.grad).all(), f"non-finite gradient into {k}"
    assert out["median_depth"].grad.abs().sum() > 0 and out["normal"].grad.abs().sum() > 0
    off = LossConfig(lambda_dssim=0.0, lambda_distortion=0.0, lambda_normal=0.0)
    loss, terms = total_loss(out, gt, cam, off, iteration=20_000)
    assert set(terms) == {"l1", "total"} and abs(loss.item() - np.abs(rgb - g).mean()) < TOL64


def test_float32_gradients_finite_with_holes():
    rng = np.random.default_rng(6)
    out = _render_out(rng, torch.float32)
    loss, _ = total_loss(out, torch.rand(H, W, 3), _camera(), LossConfig(), iteration=30_000)
    loss.backward()
    assert all(torch.isfinite(v.grad).all() for v in out.values())
    assert out["median_depth"].grad.abs().max() < DEPTH_GRAD_BOUND


def test_bad_inputs_raise():
    with pytest.raises(GofError):
        LossConfig(normal_form="other")
    with pytest.raises(GofError):
        total_loss(_render_out(np.random.default_rng(7)), torch.rand(3, H, W), _camera(), LossConfig(), 1)


def _loss_and_grads(loss_fn, out, gt, *args, **kw):
    for v in out.values():
        v.grad = None
    loss, terms = loss_fn(out, gt, *args, **kw)
    loss.backward()
    return loss.detach(), terms, {k: v.grad.clone() for k, v in out.items() if v.grad is not None}


@pytest.mark.slow
@pytest.mark.parametrize("form", ["paper", "gof"])
def test_compiled_training_loss_equals_the_eager_loss(form):
    """``TrainingLoss`` through ``torch.compile`` (backend ``aot_eager``: Dynamo's capture of the whole loss as one
    graph, ``fullgraph=True``, and AOTAutograd's backward, without code generation) gives the eager loss, its terms
    and its gradients, with and without the regularisers, for two cameras of different intrinsics (passed as device
    tensors, not baked in) and with an L1 pair."""
    from gof_warp.training.losses import TrainingLoss

    rng = np.random.default_rng(11)
    cams = [_camera(), _camera(cx=8.9, cy=4.2, fx=25.0, fy=23.5)]
    cfg = LossConfig(normal_form=form)
    compiled = TrainingLoss(cfg, cams, "cpu", mode="on", backend="aot_eager")
    assert compiled.compiled is not None
    out = _render_out(rng)
    gt = torch.tensor(rng.random((H, W, 3)))
    for view, it in ((0, 14_999), (1, 15_000), (0, 20_000)):
        pair = (lambda: (out["rgb"][1:-1, 1:-1] * 0.9, gt[1:-1, 1:-1])) if view == 1 else (lambda: None)  # noqa: E731
        ref = _loss_and_grads(total_loss, out, gt, cams[view], cfg, it, l1_pair=pair())
        got = _loss_and_grads(compiled, out, gt, cams[view], view, it, l1_pair=pair())
        assert abs(got[0].item() - ref[0].item()) <= 1e-12 * max(1.0, abs(ref[0].item()))
        assert set(got[1]) == set(ref[1]) and all(abs(got[1][k].item() - ref[1][k].item()) <= 1e-12 for k in ref[1])
        assert set(got[2]) == set(ref[2])
        for k in ref[2]:
            assert torch.allclose(got[2][k], ref[2][k], rtol=1e-10, atol=1e-14), k
    assert compiled.compiled is not None and compiled.fallback_reason is None


@pytest.mark.slow
def test_training_loss_with_appearance_compiled_equals_the_eager_correction():
    """With an appearance model, ``TrainingLoss`` puts GOF's corrected pair ``(gain ⊙ crop(rgb), crop(gt))`` in the L1
    term, the gain from camera i's embedding row: eager and through ``torch.compile`` (one graph for every view: the
    row is picked by a device index) it gives the loss, terms and gradients (renders, embedding, network) of
    ``total_loss`` with the pair built by ``AppearanceModel.apply`` as the trainer built it before; a camera smaller
    than the 32-pixel crop gets the plain L1."""
    from gof_warp.training.appearance import AppearanceModel
    from gof_warp.training.losses import TrainingLoss

    h, w = 40, 70  # crop 32 x 64
    rng = np.random.default_rng(3)
    torch.manual_seed(0)
    model = AppearanceModel(3).double()
    torch.nn.init.normal_(model.embedding.weight, 0.0, 0.5)  # rows that differ enough to tell them apart
    big = Camera(R=np.eye(3), t=np.zeros(3), fx=60.0, fy=58.0, cx=35.2, cy=19.7, width=w, height=h)
    cams = [big, Camera(R=np.eye(3), t=np.zeros(3), fx=61.0, fy=57.0, cx=34.0, cy=20.5, width=w, height=h), _camera()]

    def maps(hh, ww):
        t = lambda a: torch.tensor(a, requires_grad=True)  # noqa: E731
        return {"rgb": t(rng.random((hh, ww, 3))), "alpha": t(rng.random((hh, ww))),
                "median_depth": t(2.0 + rng.random((hh, ww))), "normal": t(rng.random((hh, ww, 3)) - 0.5),
                "distortion": t(rng.random((hh, ww)) * 1e-3)}

    def run(loss_fn, out, gt, view, it, **kw):
        model.zero_grad(set_to_none=True)
        loss, terms, grads = _loss_and_grads(loss_fn, out, gt, *kw.pop("args"), **kw)
        return loss, terms, grads, {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}

    def reference(out, gt, cam, view, it):
        corrected = model.apply(out["rgb"].permute(2, 0, 1), view)
        pair = None if not corrected.numel() else (
            corrected.permute(1, 2, 0), AppearanceModel.crop(gt.permute(2, 0, 1)).permute(1, 2, 0))
        return total_loss(out, gt, cam, LossConfig(), it, l1_pair=pair)

    eager = TrainingLoss(LossConfig(), cams, "cpu", mode="off", appearance=model)
    compiled = TrainingLoss(LossConfig(), cams, "cpu", mode="on", backend="aot_eager", appearance=model)
    for view, it in ((0, 100), (1, 15_000), (2, 15_000), (1, 20_000)):
        cam = cams[view]
        out = maps(cam.height, cam.width)
        gt = torch.tensor(rng.random((cam.height, cam.width, 3)))
        ref = run(lambda o, g, *a: reference(o, g, cam, view, it), out, gt, view, it, args=())
        for loss_fn in (eager, compiled):
            got = run(loss_fn, out, gt, view, it, args=(cam, view, it))
            assert abs(got[0].item() - ref[0].item()) <= 1e-12 * max(1.0, abs(ref[0].item()))
            assert set(got[1]) == set(ref[1]) and all(abs(got[1][k].item() - ref[1][k].item()) <= 1e-12 for k in ref[1])
            for a, b in ((got[2], ref[2]), (got[3], ref[3])):
                assert set(a) == set(b)
                for k in b:
                    assert torch.allclose(a[k], b[k], rtol=1e-9, atol=1e-14), k
        if view < 2:  # the corrected pair is in use: the embedding's row got a gradient, the other rows none
            rows = ref[3]["embedding.weight"].abs().sum(1)
            assert rows[view] > 0 and rows.sum() == rows[view]
        else:
            assert "embedding.weight" not in ref[3]
    assert compiled.compiled_appearance is not None and compiled.fallback_reason is None


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a GPU")
def test_training_loss_as_cuda_graphs_equals_the_eager_loss():
    """``cuda_graphs=True`` (inductor, ``mode="reduce-overhead"``): over a sequence of views and both graphs (with and
    without the regularisers), each call's loss, terms and gradients (renders and appearance network) equal the
    eager loss's, and the terms stay valid after later replays (they are copied out of the graph's memory)."""
    from gof_warp.training.appearance import AppearanceModel
    from gof_warp.training.losses import TrainingLoss

    dev = torch.device("cuda")
    h, w = 40, 70
    rng = np.random.default_rng(4)
    torch.manual_seed(0)
    model = AppearanceModel(2).to(dev)
    cams = [Camera(R=np.eye(3), t=np.zeros(3), fx=60.0 + i, fy=58.0, cx=35.2, cy=19.7, width=w, height=h)
            for i in range(2)]
    eager = TrainingLoss(LossConfig(), cams, dev, mode="off", appearance=model)
    graphs = TrainingLoss(LossConfig(), cams, dev, mode="on", cuda_graphs=True, appearance=model)
    kept = []
    for view, it in ((0, 100), (1, 15_000), (0, 15_000), (1, 200), (0, 20_000), (1, 20_000)):
        t = lambda a: torch.tensor(a, dtype=torch.float32, device=dev, requires_grad=True)  # noqa: E731
        out = {"rgb": t(rng.random((h, w, 3))), "alpha": t(rng.random((h, w))),
               "median_depth": t(2 + rng.random((h, w))), "normal": t(rng.random((h, w, 3)) - 0.5), "distortion": t(rng.random((h, w)) * 1e-3)}
        gt = torch.tensor(rng.random((h, w, 3)), dtype=torch.float32, device=dev)
        results = []
        for loss_fn in (eager, graphs):
            for v in out.values():
                v.grad = None
            model.zero_grad(set_to_none=True)
            loss, terms = loss_fn(out, gt, cams[view], view, it)
            loss.backward()
            results.append((loss.item(), {k: v.item() for k, v in terms.items()},
                            {k: v.grad.clone() for k, v in out.items() if v.grad is not None},
                            {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}))
        kept.append((terms, results[1][1]))
        (l_ref, t_ref, g_ref, a_ref), (l_got, t_got, g_got, a_got) = results
        assert abs(l_got - l_ref) <= 1e-5 * max(1.0, abs(l_ref)) and set(t_got) == set(t_ref)
        assert all(abs(t_got[k] - t_ref[k]) <= 1e-5 * max(1.0, abs(t_ref[k])) for k in t_ref)
        for got, ref in ((g_got, g_ref), (a_got, a_ref)):
            assert set(got) == set(ref)
            for k in ref:
                assert torch.allclose(got[k], ref[k], rtol=1e-3, atol=1e-6), k
    for terms, values in kept:  # still readable, and unchanged, after every later replay
        assert {k: v.item() for k, v in terms.items()} == values
    assert graphs.cuda_graphs and graphs.fallback_reason is None


def test_training_loss_modes_and_fallback():
    from gof_warp.training.losses import TrainingLoss

    cams = [_camera()]
    assert TrainingLoss(LossConfig(), cams, "cpu").compiled is None  # "auto" compiles on CUDA only
    assert TrainingLoss(LossConfig(), cams, "cpu", mode="off").compiled is None
    with pytest.raises(GofError):
        TrainingLoss(LossConfig(), cams, "cpu", mode="sometimes")
    from gof_warp.training.appearance import AppearanceModel

    with pytest.raises(GofError, match="1 embeddings for 2 cameras"):
        TrainingLoss(LossConfig(), cams * 2, "cpu", appearance=AppearanceModel(1))
    assert not TrainingLoss(LossConfig(), cams, "cpu", mode="on", cuda_graphs=True).cuda_graphs  # CUDA only

    def broken_backend(gm, example_inputs):
        raise RuntimeError("no compiler here")

    rng = np.random.default_rng(12)
    out, gt = _render_out(rng), torch.tensor(rng.random((H, W, 3)))
    ref = _loss_and_grads(total_loss, out, gt, cams[0], LossConfig(), 20_000)
    auto = TrainingLoss(LossConfig(), cams, "cpu", mode="on", backend=broken_backend)
    auto.mode = "auto"  # as on a GPU machine whose compiler fails: the eager loss, and the reason kept
    got = _loss_and_grads(auto, out, gt, cams[0], 0, 20_000)
    assert auto.compiled is None and "no compiler here" in auto.fallback_reason
    assert got[0].item() == ref[0].item()
    strict = TrainingLoss(LossConfig(), cams, "cpu", mode="on", backend=broken_backend)
    with pytest.raises(Exception, match="no compiler here"):
        strict(out, gt, cams[0], 0, 20_000)


def test_compile_loss_config_values():
    """``performance.compile_loss``: auto / on / off; a bare YAML on/off (read as true/false) means on/off; nonsense is
    an error naming the key."""
    from gof_warp.core.config import ConfigError, merge, parse_override
    from gof_warp.training.trainer import TrainConfig

    assert TrainConfig().performance.compile_loss == "auto"
    for value in ("off", "on", "auto"):
        cfg = merge(TrainConfig(), parse_override(f"performance.compile_loss={value}"))
        assert cfg.performance.compile_loss == value
    with pytest.raises(ConfigError, match="compile_loss"):
        merge(TrainConfig(), parse_override("performance.compile_loss=sometimes"))


def test_auto_compiles_only_long_runs_on_cuda():
    """``performance.compile_loss="auto"`` (the default) compiles runs of at least AUTO_COMPILE_MIN_ITERATIONS iterations on CUDA
    only: a short run resolves to "off", a long one stays "auto" (which TrainingLoss keeps eager off CUDA), and an
    explicit "on" / "off" is kept whatever the length."""
    from gof_warp.training.losses import TrainingLoss
    from gof_warp.training.settings import PerformanceConfig
    from gof_warp.training.trainer import AUTO_COMPILE_MIN_ITERATIONS, TrainConfig, compile_mode

    long_run, short_run = AUTO_COMPILE_MIN_ITERATIONS, AUTO_COMPILE_MIN_ITERATIONS - 1
    assert compile_mode(TrainConfig(iterations=long_run)) == "auto"
    assert compile_mode(TrainConfig(iterations=short_run)) == "off"
    assert compile_mode(TrainConfig(iterations=short_run, performance=PerformanceConfig(compile_loss="on"))) == "on"
    assert compile_mode(TrainConfig(iterations=long_run, performance=PerformanceConfig(compile_loss="off"))) == "off"
    # "auto" on the CPU: eager, nothing compiled
    assert TrainingLoss(LossConfig(), [_camera()], "cpu", mode=compile_mode(TrainConfig(iterations=long_run))).compiled is None
