"""Image and mesh metrics against hand-computed cases, a float64 loop SSIM, and the CLI end to end."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import torch
import trimesh

from gof_warp.core.errors import GofError
from gof_warp.cli.evaluate import main as evaluate_main
from gof_warp.eval.geometry_metrics import (_closest_point_on_triangles, load_geometry, mesh_accuracy_completeness,
                                       mesh_statistics, point_mesh_distance, sample_surface)
from gof_warp.eval.image_metrics import (LPIPS_WEIGHTS_ENV, LpipsVgg, image_metrics, lpips,
                              lpips_available, load_lpips, psnr, ssim)

EXACT64 = 1e-10  # float64 closed forms: only rounding separates them
EXACT32 = 1e-5  # float32 image metrics of exact cases
PSNR32 = 1e-4  # float32 MSE of 0.01 (relative rounding ~1e-7) through 10*log10
PLY32 = 1e-6  # PLY files store float32 coordinates
SAMPLING_REL = 0.03  # point-to-point distances on 0.01-spaced samples exceed the true 0.05 by ~0.6%
BINOMIAL = 0.03  # fractions from ~1e4 random samples (5 sigma of a binomial is ~0.025)

SSIM_C1, SSIM_C2 = 0.01**2, 0.03**2  # Wang et al. 2004 / 3DGS / GOF (K1 = 0.01, K2 = 0.03, range 1)


# ----------------------------------------------------------------------------- PSNR / SSIM
def test_psnr_of_known_mse_and_mask():
    gt = torch.rand(2, 3, 8, 10, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    sign = torch.where(torch.arange(8 * 10).reshape(8, 10) % 2 == 0, 1.0, -1.0).to(torch.float64)
    img = gt + 0.1 * sign  # MSE 0.01 -> 20 dB
    assert psnr(img, gt).item() == pytest.approx(20.0, abs=EXACT64)
    assert psnr(img, gt, reduction="none").shape == (2,)
    assert psnr(img[0], gt[0]).item() == pytest.approx(20.0, abs=EXACT64)
    assert psnr(img.float(), gt.float()).item() == pytest.approx(20.0, abs=PSNR32)
    # error 0.2 in the left half only: MSE 0.02 overall, 0.04 inside the left-half mask
    img2, gt2 = torch.zeros(3, 4, 6, dtype=torch.float64), torch.zeros(3, 4, 6, dtype=torch.float64)
    img2[:, :, :3] = 0.2
    mask = torch.zeros(4, 6, dtype=torch.bool)
    mask[:, :3] = True
    assert psnr(img2, gt2).item() == pytest.approx(10 * math.log10(1 / 0.02), abs=EXACT64)
    assert psnr(img2, gt2, mask).item() == pytest.approx(10 * math.log10(1 / 0.04), abs=EXACT64)
    assert psnr(gt2, gt2).item() == math.inf


def _ssim_loops(x: np.ndarray, y: np.ndarray, ws=11, sigma=1.5) -> np.ndarray:
    """float64 SSIM map [C, H, W], one pixel at a time, 2-D window over a zero-padded image."""
    g = np.exp(-((np.arange(ws) - ws // 2) ** 2) / (2 * sigma**2))
    w = np.outer(g, g) / g.sum() ** 2
    r = ws // 2
    xp, yp = (np.pad(a, ((0, 0), (r, r), (r, r))) for a in (x, y))
    out = np.zeros_like(x)
    for c in range(x.shape[0]):
        for i in range(x.shape[1]):
            for j in range(x.shape[2]):
                px, py = xp[c, i : i + ws, j : j + ws], yp[c, i : i + ws, j : j + ws]
                mx, my = (w * px).sum(), (w * py).sum()
                vx, vy, cxy = (w * px * px).sum() - mx**2, (w * py * py).sum() - my**2, (w * px * py).sum() - mx * my
                out[c, i, j] = ((2 * mx * my + SSIM_C1) * (2 * cxy + SSIM_C2)) / (
                    (mx**2 + my**2 + SSIM_C1) * (vx + vy + SSIM_C2))
    return out


def test_ssim_matches_float64_loops_and_identity(device):
    rng = np.random.default_rng(1)
    x, y = rng.random((3, 12, 13)), rng.random((3, 12, 13))
    ref = _ssim_loops(x, y)
    xt, yt = torch.from_numpy(x).to(device), torch.from_numpy(y).to(device)
    np.testing.assert_allclose(ssim(xt, yt, return_map=True).cpu().numpy(), ref, atol=EXACT64)
    assert ssim(xt, yt).item() == pytest.approx(ref.mean(), abs=EXACT64)
    xb = torch.rand(2, 3, 16, 16, device=device)
    assert ssim(xb, xb).item() == pytest.approx(1.0, abs=EXACT32)
    assert ssim(xb, torch.rand(2, 3, 16, 16, device=device)).item() < 0.5


@pytest.mark.slow
def test_compiled_ssim_shifted_sums_match_loops_and_eager_gradients():
    """Inside ``torch.compile`` the window is applied as shifted sums (fusable), eagerly as two depthwise convolutions:
    both against the float64 loops, and the same gradients (``aot_eager`` traces the compiled path without codegen)."""
    rng = np.random.default_rng(2)
    x, y = rng.random((3, 14, 17)), rng.random((3, 14, 17))
    ref = _ssim_loops(x, y)
    compiled = torch.compile(lambda a, b: ssim(a, b, return_map=True), backend="aot_eager", fullgraph=True)
    np.testing.assert_allclose(compiled(torch.from_numpy(x), torch.from_numpy(y)).numpy(), ref, atol=EXACT64)
    grads = []
    for fn in (ssim, torch.compile(ssim, backend="aot_eager", fullgraph=True)):
        xt = torch.from_numpy(x).requires_grad_()
        (1.0 - fn(xt, torch.from_numpy(y))).backward()
        grads.append(xt.grad)
    assert grads[0].abs().max() > 1e-4  # a gradient to compare
    np.testing.assert_allclose(grads[1].numpy(), grads[0].numpy(), atol=EXACT64)


def test_ssim_of_constant_images_interior_and_corner():
    a, b, n = 0.3, 0.5, 20
    smap = ssim(torch.full((3, n, n), a, dtype=torch.float64), torch.full((3, n, n), b, dtype=torch.float64),
                return_map=True)
    interior = (2 * a * b + SSIM_C1) / (a * a + b * b + SSIM_C1)  # no variance: the contrast term is C2/C2
    np.testing.assert_allclose(smap[:, 5:15, 5:15].numpy(), interior, atol=EXACT64)
    # corner: zero padding leaves window mass m = s^2 inside, s = sum of the half 1-D window (offsets 0..5)
    g = np.exp(-(np.arange(-5, 6) ** 2) / (2 * 1.5**2))
    m = (g[5:].sum() / g.sum()) ** 2
    var = m * (1 - m)  # of a 0/1 indicator under the window, times the squared level
    corner = ((2 * a * b * m * m + SSIM_C1) * (2 * a * b * var + SSIM_C2)) / (
        ((a * a + b * b) * m * m + SSIM_C1) * ((a * a + b * b) * var + SSIM_C2))
    assert smap[0, 0, 0].item() == pytest.approx(corner, abs=EXACT64)


@pytest.fixture
def one_torch_thread():
    """gradcheck runs hundreds of tiny ops: on a busy 2-core machine two threads make it ~15x slower."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def test_ssim_gradient_finite_and_gradcheck(device, one_torch_thread):
    img = torch.rand(1, 3, 24, 24, device=device, requires_grad=True)
    (1.0 - ssim(img, torch.rand(1, 3, 24, 24, device=device))).backward()
    assert torch.isfinite(img.grad).all() and img.grad.abs().sum() > 0
    x = torch.rand(1, 2, 8, 9, dtype=torch.float64, device=device, requires_grad=True)
    y = torch.rand(1, 2, 8, 9, dtype=torch.float64, device=device)
    assert torch.autograd.gradcheck(lambda t: ssim(t, y), (x,))


def test_image_metrics_means_and_lpips_absent(monkeypatch):
    monkeypatch.delenv(LPIPS_WEIGHTS_ENV, raising=False)
    gts = [torch.rand(3, 16, 16), torch.rand(3, 12, 20)]
    preds = [(g + 0.1).clamp(0, 1) for g in gts]
    out = image_metrics(preds, gts)
    want = np.mean([10 * math.log10(1 / float(((p - g) ** 2).mean())) for p, g in zip(preds, gts)])
    assert out["num_images"] == 2 and out["psnr"] == pytest.approx(want, rel=1e-5)
    assert out["ssim"] == pytest.approx(np.mean([ssim(p, g).item() for p, g in zip(preds, gts)]), rel=1e-6)
    assert out["lpips"] is None and "not computed" in out["lpips_note"]
    assert not lpips_available()
    with pytest.raises(GofError, match=LPIPS_WEIGHTS_ENV):
        lpips(preds[0], gts[0])


def _lpips_package_state_dict() -> dict:
    """Random He-initialised weights under the key names of ``lpips.LPIPS(net='vgg').state_dict()``."""
    torch.manual_seed(0)
    slices = [range(0, 4), range(4, 9), range(9, 16), range(16, 23), range(23, 30)]
    out = {}
    for key, t in LpipsVgg().state_dict().items():
        parts = key.split(".")
        w = torch.randn(t.shape) * math.sqrt(2.0 / max(1, t[0].numel())) if t.dim() > 1 else torch.zeros(t.shape)
        if parts[0] == "features":
            k = next(s for s, r in enumerate(slices) if int(parts[1]) in r)
            out[f"net.slice{k + 1}.{parts[1]}.{parts[2]}"] = w
        elif parts[0] == "lins":
            out[f"lin{parts[1]}.model.1.weight"] = w.abs()
    return out


@pytest.mark.slow
def test_lpips_from_local_weights(tmp_path, monkeypatch):
    sd = _lpips_package_state_dict()
    trunk, lins = tmp_path / "vgg.pth", tmp_path / "lins.pth"  # like torchvision's vgg16 + lpips' vgg.pth
    torch.save({k: v for k, v in sd.items() if k.startswith("net.")}, trunk)
    torch.save({k: v for k, v in sd.items() if k.startswith("lin")}, lins)
    with pytest.raises(GofError, match="lack 26 tensors"):
        load_lpips(lins)
    monkeypatch.setenv(LPIPS_WEIGHTS_ENV, f"{trunk}{os.pathsep}{lins}")
    assert lpips_available()
    model = load_lpips()
    x, y = torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32)
    assert lpips(x, x, model).item() == pytest.approx(0.0, abs=EXACT32)
    per = lpips(x, y, model, reduction="none")
    assert per.shape == (2,) and (per > 0).all()
    assert lpips(x[1], y[1], model).item() == pytest.approx(per[1].item(), rel=1e-5)
    assert image_metrics([x[0]], [y[0]])["lpips"] == pytest.approx(per[0].item(), rel=1e-5)
    # biases are zero, so scaling the first conv scales every feature map: unit-normalised taps do not change
    model.features[0].weight.data *= 7.0
    assert lpips(x, y, model, reduction="none").tolist() == pytest.approx(per.tolist(), rel=1e-4)


# ----------------------------------------------------------------------------- mesh metrics
def _square(z=0.0, x0=0.0, x1=1.0) -> trimesh.Trimesh:
    v = np.array([[x0, 0, z], [x1, 0, z], [x1, 1, z], [x0, 1, z]], float)
    return trimesh.Trimesh(v, np.array([[0, 1, 2], [0, 2, 3]]), process=False)


@pytest.mark.parametrize("method", ["points", "triangles"])
def test_parallel_squares_accuracy_completeness_fscore(method):
    d = 0.05
    r = mesh_accuracy_completeness(_square(0.0), _square(d), density=0.01, max_dist=1.0, tau_list=[0.03, 0.07],
                                   method=method)
    tol = EXACT64 if method == "triangles" else SAMPLING_REL * d
    for v in (r.accuracy, r.completeness, r.chamfer, r.accuracy_median):
        assert v == pytest.approx(d, abs=tol)
    if method == "points":
        assert r.accuracy > d  # nearest samples are never closer than the plane
    assert r.precision == [0.0, 1.0] and r.recall == [0.0, 1.0] and r.fscore == [0.0, 1.0]
    assert r.num_pred_samples == r.num_gt_samples == 10_000  # ceil(area / density^2)


def test_truncation_exclude_and_clamp():
    r = mesh_accuracy_completeness(_square(0.0), _square(0.05), density=0.02, max_dist=0.03, tau_list=[0.01],
                                   method="triangles", truncate="clamp")
    assert r.accuracy == pytest.approx(0.03, abs=EXACT64) and r.pred_outlier_fraction == 1.0
    r = mesh_accuracy_completeness(_square(0.0), _square(0.05), density=0.02, max_dist=0.03, tau_list=[0.01],
                                   method="triangles", truncate="exclude")
    assert r.accuracy == math.inf and r.fscore == [0.0]
    # half the prediction lies 1 away from the GT: excluded (DTU) vs counted as max_dist
    pred = trimesh.util.concatenate([_square(0.0), _square(1.0)])
    kw = dict(density=0.01, max_dist=0.5, tau_list=[0.01], method="triangles")
    excl = mesh_accuracy_completeness(pred, _square(0.0), truncate="exclude", **kw)
    clamp = mesh_accuracy_completeness(pred, _square(0.0), truncate="clamp", **kw)
    assert excl.accuracy == pytest.approx(0.0, abs=EXACT64)
    assert excl.pred_outlier_fraction == pytest.approx(0.5, abs=BINOMIAL)
    assert clamp.accuracy == pytest.approx(0.5 * clamp.pred_outlier_fraction, abs=EXACT64)
    assert excl.precision[0] == pytest.approx(0.5, abs=BINOMIAL) and excl.recall == [1.0]


def test_partial_mesh_precision_one_recall_half_and_crop():
    tau = 0.01
    r = mesh_accuracy_completeness(_square(0.0, 0.0, 0.5), _square(0.0), density=0.01, max_dist=1.0,
                                   tau_list=[tau], method="triangles")
    assert r.precision == [1.0]
    assert r.recall[0] == pytest.approx(0.5 + tau, abs=BINOMIAL)  # GT within tau of x <= 0.5
    box = ([-1, -1, -1], [0.5, 2, 1])
    cropped = mesh_accuracy_completeness(_square(0.0, 0.0, 0.5), _square(0.0), density=0.01, max_dist=1.0,
                                         tau_list=[tau], method="triangles", crop=box)
    assert cropped.recall == [1.0] and cropped.precision == [1.0]
    assert cropped.num_gt_samples == pytest.approx(5000, rel=BINOMIAL)
    as_function = mesh_accuracy_completeness(_square(0.0, 0.0, 0.5), _square(0.0), density=0.01, max_dist=1.0,
                                             tau_list=[tau], method="triangles", crop=lambda p: p[:, 0] <= 0.5)
    assert as_function.num_gt_samples == cropped.num_gt_samples


def test_empty_prediction_gives_inf_and_zero_fscore():
    for pred, gt in ((trimesh.Trimesh(), _square()), (_square(), np.zeros((0, 3)))):
        r = mesh_accuracy_completeness(pred, gt, density=0.05, max_dist=1.0, tau_list=[0.1], truncate="clamp")
        assert r.accuracy == r.completeness == r.chamfer == math.inf
        assert r.precision == r.recall == r.fscore == [0.0]
        assert r.to_dict()["chamfer"] is None


def test_sample_surface_uniform_deterministic_on_surface():
    box = trimesh.creation.box()
    a, b = sample_surface(box, density=0.05, seed=3), sample_surface(box, density=0.05, seed=3)
    assert a.shape == (math.ceil(6 / 0.05**2), 3) and np.array_equal(a, b)
    assert not np.array_equal(a, sample_surface(box, density=0.05, seed=4))
    np.testing.assert_allclose(np.abs(a).max(axis=1), 0.5, atol=EXACT64)  # every sample on a face
    # two triangles of areas 1 and 3: a quarter of the samples land on the first
    v = np.array([[0, 0, 0], [2, 0, 0], [0, 1, 0], [0, 0, 5], [6, 0, 5], [0, 1, 5]], float)
    pts = sample_surface((v, np.array([[0, 1, 2], [3, 4, 5]])), count=10_000, seed=0)
    assert np.mean(pts[:, 2] == 0) == pytest.approx(0.25, abs=BINOMIAL)
    cloud = np.random.default_rng(0).random((7, 3))
    np.testing.assert_array_equal(sample_surface(trimesh.PointCloud(cloud), density=0.1), cloud)


def test_point_mesh_distance_square_and_triangle():
    rng = np.random.default_rng(2)
    p = rng.uniform(-1, 2, (500, 3))
    sq = _square()
    outside = np.stack([np.maximum(0, np.maximum(-p[:, k], p[:, k] - 1)) for k in (0, 1)], 1)
    want = np.sqrt(p[:, 2] ** 2 + (outside**2).sum(1))
    np.testing.assert_allclose(point_mesh_distance(p, sq.vertices, sq.faces, chunk=64), want, atol=EXACT64)
    # one obtuse triangle against a dense barycentric grid (spacing h): true <= grid <= true + h
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.2, 0.1], [-0.3, 0.6, -0.2]])
    n = 150
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
    keep = i + j <= n
    bary = np.stack([1 - (i + j)[keep] / n, i[keep] / n, j[keep] / n], 1)
    grid = bary @ tri
    q = rng.normal(0.3, 0.8, (200, 3))
    got = point_mesh_distance(q, tri, [[0, 1, 2]])
    brute = np.linalg.norm(q[:, None] - grid[None], axis=2).min(1)
    h = np.linalg.norm(tri[1] - tri[2]) / n
    assert np.all(got <= brute + EXACT64) and np.all(brute - got <= h)


def test_mesh_statistics_boxes():
    box = trimesh.creation.box()
    s = mesh_statistics(box)
    assert (s["connected_components"], s["watertight"], s["boundary_edges"], s["euler_characteristic"]) == (1, True, 0, 2)
    assert s["area"] == pytest.approx(6.0, abs=EXACT64) and s["winding_consistent"]
    two = trimesh.util.concatenate([box, box.copy().apply_translation([3, 0, 0])])
    assert mesh_statistics(two)["connected_components"] == 2 and mesh_statistics(two)["watertight"]
    open_box = trimesh.Trimesh(box.vertices, box.faces[2:], process=False)  # one square side removed
    s = mesh_statistics(open_box)
    assert (s["watertight"], s["boundary_edges"], s["faces"]) == (False, 4, 10)
    fan = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [5, 5, 5]],
                          [[0, 1, 2], [1, 0, 3], [0, 1, 4], [0, 0, 1]], process=False)
    s = mesh_statistics(fan)  # three triangles on edge (0, 1) + a degenerate one
    assert (s["non_manifold_edges"], s["degenerate_faces"], s["unreferenced_vertices"]) == (1, 1, 1)
    empty = mesh_statistics(trimesh.Trimesh())
    assert (empty["vertices"], empty["connected_components"], empty["watertight"]) == (0, 0, False)


def test_bad_mesh_file_names_the_file(tmp_path):
    bad = tmp_path / "broken.ply"
    bad.write_text("this is not a ply\n")
    with pytest.raises(GofError, match="broken.ply"):
        load_geometry(bad)


# ----------------------------------------------------------------------------- CLI
@pytest.mark.slow
def test_cli_end_to_end_json(tmp_path):
    _square(0.0).export(tmp_path / "pred.ply")
    _square(0.05).export(tmp_path / "gt.ply")
    out = tmp_path / "out" / "eval.json"
    cmd = [sys.executable, "-m", "gof_warp.evaluate", "--mesh", str(tmp_path / "pred.ply"), "--gt",
           str(tmp_path / "gt.ply"), "--tau", "0.03", "0.07", "--density", "0.02", "--max-dist", "1",
           "--method", "triangles", "--json", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "chamfer" in proc.stdout and "F-score" in proc.stdout
    rep = json.loads(out.read_text())
    m = rep["metrics"]
    assert m["chamfer"] == pytest.approx(0.05, abs=PLY32) and m["fscore"] == [0.0, 1.0]
    assert rep["gt_stats"]["faces"] == 2 and rep["mesh_stats"]["boundary_edges"] == 4


def test_cli_bad_file_exit_2(tmp_path, capsys):
    bad = tmp_path / "garbage.ply"
    bad.write_bytes(b"\x00\x01 not a mesh")
    _square().export(tmp_path / "gt.ply")
    assert evaluate_main(["--mesh", str(bad), "--gt", str(tmp_path / "gt.ply")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "garbage.ply" in err
    assert evaluate_main(["--mesh", str(tmp_path / "gt.ply"), "--gt", str(tmp_path / "missing.ply")]) == 2
    assert "missing.ply" in capsys.readouterr().err


def test_point_mesh_distance_mixed_triangle_sizes_against_brute_force():
    """Small and very large triangles together (pruned in separate radius classes): every distance is the brute
    force minimum over all triangles, each computed exactly."""
    rng = np.random.default_rng(5)
    small = rng.uniform(-1, 1, (300, 1, 3)) + rng.normal(0, 0.01, (300, 3, 3))
    large = rng.uniform(-1, 1, (3, 1, 3)) + rng.normal(0, 3.0, (3, 3, 3))
    tri = np.concatenate([small, large])
    v, f = tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3)
    q = rng.uniform(-3, 3, (400, 3))
    got = point_mesh_distance(q, v, f, chunk=128)
    brute = np.stack([np.linalg.norm(q - _closest_point_on_triangles(q, *[np.broadcast_to(t[k], q.shape)
                                                                        for k in range(3)]), axis=1) for t in tri], 1)
    np.testing.assert_allclose(got, brute.min(1), atol=EXACT64)
    assert (brute.argmin(1) >= 300).any() and (brute.argmin(1) < 300).any()  # both classes decide some points
