"""Densification policy, optimizer-state surgery, learning-rate and SH schedules (CPU, no renderer)."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from scipy.stats import chi2

from gof_warp.core.model import quat_to_rotmat
from gof_warp.training.densify import (Densifier, DensifyConfig, _Stats, densify_candidates, prune_mask, quantile,
                              reset_opacity, sample_children, sh_degree_at)
from gof_warp.core.errors import GofError
from gof_warp.core.model import PARAM_NAMES, Gaussians
from gof_warp.training.optim import (OptimConfig, check_optimizer_state, make_optimizer, position_lr, replace_params,
                            update_learning_rate)

EXTENT = 2.0
TOL32 = 1e-6  # float32 values copied or recomputed with one rounding
CHI2_P = 1e-4  # false-alarm probability of each statistical bound (fixed seeds: deterministic anyway)
N_SAMPLES = 20_000
SE_BOUND = 4.5  # standard errors allowed per covariance entry (~7e-6 two-sided per entry for a Gaussian)
TOL_RESET = 1e-5  # float32 logit -> sigmoid round trip of the reset opacity
TOL_LR = 1e-12  # float64 arithmetic (schedule exp/log, rotation orthonormality): rounding only


def _logit(p):
    return math.log(p / (1 - p))


def _gaussians(n=8, seed=0):
    """Small model; sh_dc[:, 0] holds each Gaussian's identity (copied to children, untouched by Adam below)."""
    g = torch.Generator().manual_seed(seed)
    dc = torch.rand(n, 3, generator=g)
    dc[:, 0] = torch.arange(n, dtype=torch.float32)
    return Gaussians(means=torch.randn(n, 3, generator=g), quats=torch.randn(n, 4, generator=g),
                     log_scales=torch.full((n, 3), math.log(0.005 * EXTENT)),
                     opacity_logits=torch.full((n,), _logit(0.5)), sh_dc=dc,
                     sh_rest=torch.rand(n, 3, 3, generator=g), max_sh_degree=1, active_sh_degree=0)


def _stepped_optimizer(gs, steps=2):
    """Adam with non-trivial moments: gradients = row identity + 1 (zero on sh_dc[:, 0] to keep identities)."""
    opt = make_optimizer(gs, OptimConfig(), EXTENT)
    for _ in range(steps):
        for name, p in gs.params.items():
            ident = torch.arange(len(gs), dtype=torch.float32).reshape(-1, *[1] * (p.ndim - 1)) + 1.0
            p.grad = ident.expand_as(p).clone() * (0.1 if name != "means" else 1.0)
            if name == "sh_dc":
                p.grad[:, 0] = 0.0
        opt.step()
    return opt


def _ids(gs):
    return gs.sh_dc[:, 0].detach().round().long().tolist()


def _moments(gs, opt):
    """{name: {identity: (exp_avg row, exp_avg_sq row)}}; duplicates (children) are listed per identity."""
    out = {}
    for name in PARAM_NAMES:
        st = opt.state[gs.params[name]]
        rows = {}
        for i, ident in enumerate(_ids(gs)):
            rows.setdefault(ident, []).append((st["exp_avg"][i].clone(), st["exp_avg_sq"][i].clone()))
        out[name] = rows
    return out


def _stats(n, grad=None, grad_abs=None, radii=None):
    z = torch.zeros(n)
    return SimpleNamespace(grad2d=torch.stack([z if grad is None else grad, z], 1),
                           grad2d_abs=z if grad_abs is None else grad_abs,
                           radii=torch.ones(n, dtype=torch.int32) if radii is None else radii)


# ----------------------------------------------------------------------------- surgery
def test_replace_params_keep_append_reset_moves_moments_with_rows():
    gs = _gaussians()
    opt = _stepped_optimizer(gs)
    before = _moments(gs, opt)
    keep = torch.tensor([6, 1, 3])
    new = {k: v.detach()[[2]].clone() for k, v in gs.params.items()}
    new["sh_dc"][:, 0] = 100.0
    reset_rows = torch.tensor([False, True, False, False])
    replace_params(gs, opt, keep=keep, append=new, reset={"quats": (reset_rows, torch.tensor([1.0, 0, 0, 0]))})
    check_optimizer_state(gs, opt)
    assert _ids(gs) == [6, 1, 3, 100] and len(gs) == 4
    after = _moments(gs, opt)
    for name in PARAM_NAMES:
        for ident in (6, 1, 3):
            if name == "quats" and ident == 1:
                continue
            for a, b in zip(after[name][ident][0], before[name][ident][0]):
                assert torch.equal(a, b), f"{name} moments of Gaussian {ident} did not move with it"
        assert all((m == 0).all() for m in after[name][100][0]), f"appended {name} moments are not zero"
    assert all((m == 0).all() for m in after["quats"][1][0])  # reset row: moments zeroed
    assert torch.equal(gs.quats[1].detach(), torch.tensor([1.0, 0, 0, 0]))
    assert all(p.is_leaf and p.requires_grad and p.grad is None for p in gs.params.values())
    # Adam keeps working on the new tensors
    for p in gs.params.values():
        p.grad = torch.ones_like(p)
    opt.step()
    check_optimizer_state(gs, opt)


def test_replace_params_validates_and_keeps_filter():
    gs = _gaussians(4)
    gs.filter_3d = torch.arange(4, dtype=torch.float32)
    opt = make_optimizer(gs, OptimConfig(), EXTENT)
    new = {k: v.detach()[:1] for k, v in gs.params.items()}
    with pytest.raises(GofError, match="filter_3d"):
        replace_params(gs, opt, append=new)
    with pytest.raises(GofError, match="mask"):
        replace_params(gs, opt, keep=torch.ones(3, dtype=torch.bool))
    keep = torch.tensor([True, False, True, True])
    replace_params(gs, opt, keep=keep, append={**new, "filter_3d": torch.tensor([9.0])})
    assert gs.filter_3d.tolist() == [0.0, 2.0, 3.0, 9.0]
    assert opt.state == {} or all(len(s) == 0 for s in opt.state.values())  # no state before the first step


# ----------------------------------------------------------------------------- clone / split sampling
def test_children_sampled_from_parent_distribution():
    """Many children of one anisotropic rotated parent: mean ≈ μ and covariance ≈ R S² Rᵀ."""
    q = torch.tensor([[0.8, 0.3, -0.4, 0.35]])
    s = torch.tensor([[0.5, 0.1, 0.02]])
    parent = Gaussians(means=torch.tensor([[1.0, -2.0, 0.5]]), quats=q, log_scales=s.log(),
                       opacity_logits=torch.zeros(1), sh_dc=torch.zeros(1, 3))
    kids = sample_children(parent, torch.zeros(1, dtype=torch.long), N_SAMPLES, torch.Generator().manual_seed(0), 1.6)
    x = kids["means"].double().numpy()
    R = quat_to_rotmat(q.double())[0].numpy()
    sigma = R @ np.diag(s[0].double().numpy() ** 2) @ R.T
    mu = np.array([1.0, -2.0, 0.5])
    d = x.mean(0) - mu
    assert N_SAMPLES * d @ np.linalg.solve(sigma, d) < chi2.ppf(1 - CHI2_P, 3)  # Hotelling with known Σ
    white = (x - mu) @ np.linalg.inv(np.linalg.cholesky(sigma)).T  # ~ N(0, I) if drawn from the parent
    cov = white.T @ white / N_SAMPLES
    se = np.sqrt((np.eye(3) + 1.0) / N_SAMPLES)  # standard error of E[w_i w_j]: sqrt(2/n) diag, sqrt(1/n) off
    assert np.all(np.abs(cov - np.eye(3)) < SE_BOUND * se)
    assert np.allclose(kids["log_scales"].exp().numpy(), s.numpy() / 1.6, rtol=TOL32)
    assert torch.equal(kids["quats"], q.expand(N_SAMPLES, 4))
    # a wrong (unrotated) covariance must fail the same bound
    white_bad = (x - mu) / s[0].numpy()
    assert np.any(np.abs(white_bad.T @ white_bad / N_SAMPLES - np.eye(3)) > SE_BOUND * se)


def test_quat_to_rotmat_is_rotation():
    R = quat_to_rotmat(torch.randn(50, 4, dtype=torch.float64))
    assert torch.allclose(R @ R.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(50, 3, 3), atol=TOL_LR)
    assert torch.allclose(torch.linalg.det(R), torch.ones(50, dtype=torch.float64), atol=TOL_LR)


# ----------------------------------------------------------------------------- the densify step
def _scene_for_step():
    """8 Gaussians: 0-1 clone (small, high grad), 2-3 split (large, high grad), 4 low opacity, 5-7 idle."""
    gs = _gaussians(8)
    with torch.no_grad():
        gs.params["log_scales"][2:4] = math.log(0.05 * EXTENT)  # > 0.01 E -> split
        gs.params["opacity_logits"][4] = _logit(0.04)
    opt = _stepped_optimizer(gs)
    grad = torch.tensor([5e-4, 3e-4, 4e-4, 9e-4, 0, 0, 0, 1e-4])
    return gs, opt, grad


def test_step_clones_splits_prunes_and_moves_state():
    gs, opt, grad = _scene_for_step()
    before = _moments(gs, opt)
    parent_means = gs.means.detach().clone()
    parent_scales = gs.raw_scales.detach().clone()
    dens = Densifier(DensifyConfig(metric="standard"))
    dens.after_backward(_stats(8, grad), iteration=599)
    report = dens.step(600, gs, opt, EXTENT)
    check_optimizer_state(gs, opt)
    assert (report.num_candidates, report.num_cloned, report.num_split, report.num_pruned) == (4, 2, 2, 1)
    assert report.num_before == 8 and report.num_after == len(gs) == 8 + 2 + 4 - 2 - 1 == 11
    assert report.num_added == 6 and dens.history == [(600, 11)]
    ids = _ids(gs)
    assert ids[:5] == [0, 1, 5, 6, 7] and sorted(ids[5:]) == [0, 1, 2, 2, 3, 3]  # parents first, then children
    after = _moments(gs, opt)
    for name in PARAM_NAMES:
        for ident in (0, 1, 5, 6, 7):  # surviving parents come first, moments intact
            assert torch.equal(after[name][ident][0][0], before[name][ident][0][0])
        for ident in (0, 1):  # the clone (second occurrence) starts with zero moments
            assert all((m == 0).all() for m in after[name][ident][1])
        for ident in (2, 3):
            assert all((m == 0).all() for pair in after[name][ident] for m in pair)
    scales = gs.raw_scales.detach()
    for i, ident in enumerate(ids):
        expected = parent_scales[ident] / (1.6 if ident in (2, 3) else 1.0)
        assert torch.allclose(scales[i], expected, rtol=TOL32)
    clone_rows = [i for i, ident in enumerate(ids) if ident == 0]
    assert torch.equal(gs.means[clone_rows[0]].detach(), parent_means[0])  # the parent stays put
    assert not torch.equal(gs.means[clone_rows[1]].detach(), parent_means[0])  # the clone is sampled
    assert dens.stats.count.shape == (11,) and dens.stats.count.sum() == 0


def _stats_with_torch_ops(s, stats, scale):
    """What ``Densifier.after_backward`` computed with torch's elementwise operators before session 37: the reference
    its kernel must give bit for bit."""
    radii = stats.radii
    vis = radii > 0
    grad, grad_abs = stats.grad2d.norm(dim=-1), stats.grad2d_abs
    if scale != 1.0:
        grad, grad_abs = grad * scale, grad_abs * scale
    s.grad += torch.where(vis, grad, 0.0).float()
    s.grad_abs += torch.where(vis, grad_abs, 0.0).float()
    s.count += vis.to(torch.int32)
    s.max_radii = torch.maximum(s.max_radii, radii.to(torch.int32))


@pytest.mark.parametrize("scale", [1.0, 3.0])
def test_after_backward_kernel_gives_the_torch_operators_bits(device, scale):
    """Eight views of random statistics (a third of the Gaussians unseen in each, one with NaN gradients where it is
    unseen, radii up to 40 px) accumulated by the densifier's kernel: sums, counts and largest radii equal, bit for
    bit, what torch's elementwise operators give (``_stats_with_torch_ops``)."""
    n = 1001
    gen = torch.Generator().manual_seed(int(scale))
    dens, ref = Densifier(DensifyConfig(metric="standard")), _Stats.zeros(n, device)
    for view in range(8):
        radii = torch.randint(0, 41, (n,), generator=gen, dtype=torch.int32)
        radii[torch.rand(n, generator=gen) < 0.33] = 0
        grad2d = torch.randn(n, 2, generator=gen) * 10.0 ** torch.randint(-9, -2, (n, 1), generator=gen)
        grad_abs = torch.rand(n, generator=gen) * 1e-3
        if view == 5:
            grad2d[radii == 0] = float("nan")
        stats = SimpleNamespace(grad2d=grad2d.to(device), grad2d_abs=grad_abs.to(device), radii=radii.to(device))
        dens.after_backward(stats, 599, scale=scale)
        _stats_with_torch_ops(ref, stats, scale)
    for name in ("grad", "grad_abs", "count", "max_radii"):
        got, want = getattr(dens.stats, name), getattr(ref, name)
        assert got.dtype == want.dtype and torch.equal(got, want), name
    assert 0 < int(ref.count.min()) and int(ref.count.max()) <= 8 and torch.isfinite(ref.grad).all()


def test_after_backward_golden_case():
    """Four Gaussians by hand: seen twice, once, never (with a NaN gradient) and once with a larger radius later."""
    dens = Densifier(DensifyConfig(metric="standard"))
    views = [([3.0, 4.0], [0.5, 0.0], [1.0, 1.0], [0.0, 0.0], [2, 3, 0, 1]),
             ([0.0, 1.0], [float("nan"), 1.0], [0.25, 0.0], [1.0, 0.0], [4, 0, 0, 7])]
    for g0, g1, g2, g3, radii in views:
        grad2d = torch.tensor([g0, g1, g2, g3])
        dens.after_backward(SimpleNamespace(grad2d=grad2d, grad2d_abs=torch.tensor([1.0, 2.0, 3.0, 4.0]),
                                            radii=torch.tensor(radii, dtype=torch.int32)), 599)
    s = dens.stats
    assert s.grad.tolist() == [5.0 + 1.0, 0.5, 0.0, 1.0] and s.grad_abs.tolist() == [2.0, 2.0, 0.0, 8.0]
    assert s.count.tolist() == [2, 1, 0, 2] and s.max_radii.tolist() == [4, 3, 0, 7]


def test_step_is_reproducible_with_seed():
    means = []
    for _ in range(2):
        gs, opt, grad = _scene_for_step()
        dens = Densifier(DensifyConfig(metric="standard", seed=7))
        dens.after_backward(_stats(8, grad), 599)
        dens.step(600, gs, opt, EXTENT)
        means.append(gs.means.detach())
    assert torch.equal(means[0], means[1])


def test_schedule_of_step():
    cfg = DensifyConfig(metric="standard")
    for it, densifies in [(500, False), (550, False), (600, True), (14_900, True), (15_000, False)]:
        gs, opt, grad = _scene_for_step()
        dens = Densifier(cfg)
        dens.after_backward(_stats(8, grad), it - 1)
        rep = dens.step(it, gs, opt, EXTENT)
        assert rep.densified == densifies, it
        assert rep.filter_3d_due == densifies
    dens = Densifier(cfg)
    gs, opt, _ = _scene_for_step()
    assert dens.step(3000, gs, opt, EXTENT).opacity_reset and not dens.step(15_000, gs, opt, EXTENT).opacity_reset
    assert dens.step(15_100, gs, opt, EXTENT).filter_3d_due and not dens.step(29_900, gs, opt, EXTENT).filter_3d_due
    dens.after_backward(_stats(len(gs), torch.ones(len(gs))), 15_000)  # no statistics from stop_iter on
    assert dens.stats.count.sum() == 0


def test_budget_caps_count_and_keeps_highest_metric():
    n = 20
    gs = _gaussians(n)
    opt = make_optimizer(gs, OptimConfig(), EXTENT)
    grad = torch.linspace(3e-4, 1e-3, n)[torch.randperm(n, generator=torch.Generator().manual_seed(1))]
    dens = Densifier(DensifyConfig(metric="standard", max_gaussians=n + 5))
    dens.after_backward(_stats(n, grad), 599)
    rep = dens.step(600, gs, opt, EXTENT)
    assert len(gs) == n + 5 and rep.num_candidates == n and rep.num_over_budget == n - 5
    top5 = set(torch.argsort(grad, descending=True)[:5].tolist())
    ids = _ids(gs)
    assert {i for i in set(ids) if ids.count(i) == 2} == top5
    dens.after_backward(_stats(len(gs), torch.full((len(gs),), 1e-3)), 699)
    assert dens.step(700, gs, opt, EXTENT).num_added == 0 and len(gs) == n + 5  # full: no growth


def test_gof_metric_quantile_selects_as_many_by_abs():
    g = torch.Generator().manual_seed(2)
    grad = torch.rand(1000, generator=g) * 4e-4  # about half above 2e-4
    grad_abs = torch.rand(1000, generator=g)
    mask, score, q = densify_candidates(grad, grad_abs, DensifyConfig(metric="gof"))
    k = int((grad >= 2e-4).sum())
    assert int((grad_abs >= q).sum()) == k and abs(q - torch.quantile(grad_abs, 1 - k / 1000).item()) < TOL32
    assert torch.equal(mask, (grad >= 2e-4) | (grad_abs >= q)) and torch.equal(mask, score >= 1.0)
    mask0, _, _ = densify_candidates(torch.zeros(10), torch.rand(10), DensifyConfig(metric="gof"))
    assert not mask0.any()  # nothing above τ: no quantile candidates either (GOF would pick max M)
    assert torch.equal(densify_candidates(grad, grad_abs, DensifyConfig(metric="paper", abs_grad_threshold=0.9))[0],
                       (grad >= 2e-4) | (grad_abs >= 0.9))


def test_quantile_matches_torch():
    x = torch.randn(1001)
    for q in (0.0, 0.13, 0.5, 0.999, 1.0):
        assert abs(quantile(x, q).item() - torch.quantile(x, q).item()) < TOL32


# ----------------------------------------------------------------------------- prune, reset, schedules
def test_prune_thresholds():
    cfg = DensifyConfig(prune_screen_size=True)  # the papers' screen-size test
    opac = torch.tensor([0.049, 0.051, 0.5, 0.5, 0.5])
    scales = torch.tensor([[0.01] * 3, [0.01] * 3, [0.21, 0.01, 0.01], [0.01] * 3, [0.01] * 3])
    radii = torch.tensor([0, 0, 0, 21, 20])
    assert prune_mask(opac, scales, radii, EXTENT, 3000, cfg).tolist() == [True, False, False, False, False]
    assert prune_mask(opac, scales, radii, EXTENT, 3100, cfg).tolist() == [True, False, True, True, False]
    code = DensifyConfig()  # the default is GOF's code: the screen test is dead
    assert not code.prune_screen_size
    assert prune_mask(opac, scales, radii, EXTENT, 3100, code).tolist() == [True, False, True, False, False]


def test_opacity_reset_value_and_moments():
    gs = _gaussians(4)
    with torch.no_grad():
        gs.params["opacity_logits"].copy_(torch.tensor([_logit(0.9), _logit(0.005), _logit(0.3), _logit(0.02)]))
        gs.params["log_scales"][0] = torch.tensor([0.1, 0.2, 0.05]).log()
    gs.filter_3d = torch.tensor([0.05, 0.0, 0.1, 0.01])
    opt = _stepped_optimizer(gs)
    o_f_before = gs.opacities.detach().clone()
    other = opt.state[gs.params["means"]]["exp_avg"].clone()
    reset_opacity(gs, opt, 0.01)
    expected = torch.minimum(o_f_before, torch.tensor(0.01))
    assert torch.allclose(gs.opacities.detach(), expected, rtol=TOL_RESET, atol=0)
    st = opt.state[gs.params["opacity_logits"]]
    assert (st["exp_avg"] == 0).all() and (st["exp_avg_sq"] == 0).all()
    assert torch.equal(opt.state[gs.params["means"]]["exp_avg"], other)


def test_sh_degree_schedule():
    assert [sh_degree_at(it, 1000, 3) for it in (1, 999, 1000, 2500, 3000, 9000)] == [0, 0, 1, 2, 3, 3]
    gs = _gaussians(2)
    assert Densifier().update_sh_degree(5000, gs) == 1 == gs.active_sh_degree  # model's max degree is 1


def test_position_lr_schedule_and_optimizer_groups():
    cfg = OptimConfig()
    assert position_lr(0, cfg, EXTENT) == pytest.approx(1.6e-4 * EXTENT, rel=TOL_LR)
    assert position_lr(30_000, cfg, EXTENT) == pytest.approx(1.6e-6 * EXTENT, rel=TOL_LR)
    assert position_lr(60_000, cfg, EXTENT) == pytest.approx(1.6e-6 * EXTENT, rel=TOL_LR)  # held after the end
    assert position_lr(15_000, cfg, EXTENT) == pytest.approx(math.sqrt(1.6e-4 * 1.6e-6) * EXTENT, rel=TOL_LR)
    gs = _gaussians(3)
    opt = make_optimizer(gs, cfg, EXTENT)
    lrs = {g["name"]: g["lr"] for g in opt.param_groups}
    assert lrs == pytest.approx({"means": 1.6e-4 * EXTENT, "quats": 1e-3, "log_scales": 5e-3, "opacity_logits": 0.05,
                                 "sh_dc": 2.5e-3, "sh_rest": 1.25e-4}, rel=TOL_LR)
    assert opt.defaults["eps"] == 1e-15
    lr_end = position_lr(30_000, cfg, EXTENT)
    assert update_learning_rate(opt, 30_000, cfg, EXTENT) == opt.param_groups[0]["lr"] == lr_end


def test_state_dict_roundtrip():
    gs, opt, grad = _scene_for_step()
    dens = Densifier(DensifyConfig(metric="standard"))
    dens.after_backward(_stats(8, grad), 599)
    dens.step(600, gs, opt, EXTENT)
    dens.after_backward(_stats(len(gs), torch.full((len(gs),), 1e-4)), 601)
    other = Densifier(dens.config)
    other.load_state_dict(dens.state_dict())
    assert other.history == dens.history and torch.equal(other.stats.grad, dens.stats.grad)
    assert torch.equal(torch.randn(3, generator=other.generator), torch.randn(3, generator=dens.generator))


def test_late_prune_runs_after_densification_only_on_its_interval_and_with_the_near_camera_mask():
    cfg = DensifyConfig(stop_iter=100, interval=10, late_prune_interval=50, filter_3d_until_iter=300)
    d = Densifier(cfg)
    gs = _gaussians(8)
    opt = _stepped_optimizer(gs)
    with torch.no_grad():
        gs.params["opacity_logits"][[1, 5]] = _logit(0.01)  # transparent: below min_opacity 0.05
        gs.params["log_scales"][3, 0] = math.log(0.11 * EXTENT)  # grown past max_world_scale·E = 0.1·E
        gs.params["log_scales"][4, 0] = math.log(0.09 * EXTENT)  # large, within it
    near = torch.zeros(8, dtype=torch.bool)
    near[[5, 6]] = True  # 5 is transparent as well: counted once, as transparent
    calls = []
    def in_front():
        calls.append(1)
        return near[:len(gs)]
    for it in (120, 149, 301):  # off the interval, and past filter_3d_until_iter
        r = d.step(it, gs, opt, EXTENT, near_camera=in_front)
        assert not r.late_pruned and len(gs) == 8
    assert not calls
    r = d.step(150, gs, opt, EXTENT, near_camera=in_front)
    assert r.late_pruned and r.num_pruned == 4 and r.num_near_camera == 1 and r.num_after == 4
    assert _ids(gs) == [0, 2, 4, 7]
    assert d.late_pruned == {"transparent": 2, "too_large": 1, "near_camera": 1}
    again = Densifier(cfg)
    again.load_state_dict(d.state_dict())
    assert again.late_pruned == d.late_pruned
    check_optimizer_state(gs, opt)
    assert not Densifier(DensifyConfig(stop_iter=100)).late_prune_due(150)  # off by default: GOF never prunes late
    with torch.no_grad():  # a late prune that would leave nothing says so (and leaves the model as it was)
        gs.params["opacity_logits"][:] = _logit(0.01)
    with pytest.raises(GofError, match="would remove all 4 Gaussians"):
        d.step(200, gs, opt, EXTENT)
    assert len(gs) == 4
    for bad in ({"late_prune_interval": -1}, {"near_camera_fraction": 1.5},
                {"near_camera_fraction": 0.25}):  # the last: no late prunes to act at
        with pytest.raises(GofError):
            DensifyConfig(**bad)


def test_count_may_change_follows_the_schedule():
    """count_may_change (the trainer frees its render scratch on it) says yes exactly at the iterations whose step can
    change the count: densification, a late prune, a hidden prune given a hidden test."""
    d = Densifier(DensifyConfig(start_iter=100, stop_iter=1000, interval=100, late_prune_interval=50,
                                filter_3d_until_iter=2000, hidden_prune_iters=[1225]))
    assert d.count_may_change(500, hidden=False) and d.densify_due(500)
    assert not d.count_may_change(550, hidden=False) and not d.count_may_change(100, hidden=True)
    assert d.count_may_change(1050, hidden=False) and d.late_prune_due(1050)
    assert not d.count_may_change(1225, hidden=False) and d.count_may_change(1225, hidden=True)
    assert d.hidden_prune_due(1225) and not d.hidden_prune_due(1200)
    assert not d.count_may_change(2050, hidden=True)  # past filter_3d_until_iter: no late prune
