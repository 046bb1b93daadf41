"""Gaussians hidden behind the rendered surface (gof_warp.training.hidden) and the densifier's hidden prune (CPU)."""

import json
import math

import numpy as np
import pytest
import torch

from gof_warp.core.camera import look_at
from gof_warp.training.densify import Densifier, DensifyConfig
from gof_warp.core.errors import GofError
from gof_warp.training.hidden import (behind_by, behind_surface, blend_weights, hidden_gaussians, surface_depth_ratio,
                             surface_measures, unoccluded_weight, visible_fraction)
from gof_warp.core.model import Gaussians
from gof_warp.training.optim import OptimConfig, check_optimizer_state, make_optimizer

W, H, F = 32, 24, 30.0


def _cameras():
    """Two views of the wall at z = 0 from z = 2, and one above x = 2.5, beyond the wall's edge (x <= 1.5)."""
    kw = dict(up=(0.0, 1.0, 0.0), fx=F, width=W, height=H)
    return [look_at((0.3, 0.0, 2.0), (0.0, 0.0, 0.0), name="a", **kw),
            look_at((-0.3, 0.1, 2.0), (0.0, 0.0, 0.0), name="b", **kw),
            look_at((2.5, 0.0, 2.0), (2.5, 0.0, 0.0), name="c", **kw)]


def _wall_and_probes():
    """An opaque wall of flat Gaussians on z = 0 (|x|, |y| <= 1.5), then the probes, by name."""
    g = np.arange(-1.5, 1.5001, 0.05)
    wall = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    means = [np.c_[wall, np.zeros(len(wall))]]
    scales = [np.tile([0.04, 0.04, 0.002], (len(wall), 1))]
    probes = {  # name: (centre, scale, hidden?)
        "blob behind the wall": ((0.0, 0.0, -0.3), 0.1, True),
        "small, in front of the wall": ((0.1, 0.1, 0.5), 0.02, False),
        "just behind, within the margin": ((0.05, -0.05, -0.01), 0.005, False),
        "behind the wall's plane, beyond its edge, seen by c": ((2.5, 0.0, -0.3), 0.02, False),
        "behind the wall, in no image": ((0.0, 9.0, -0.3), 0.02, False),
    }
    for c, s, _ in probes.values():
        means.append(np.array([c]))
        scales.append(np.full((1, 3), s))
    means, scales = np.concatenate(means), np.concatenate(scales)
    n = len(means)
    gs = Gaussians(means=torch.tensor(means, dtype=torch.float32), quats=torch.tensor([[1.0, 0, 0, 0]] * n),
                   log_scales=torch.tensor(np.log(scales), dtype=torch.float32),
                   opacity_logits=torch.full((n,), math.log(0.99 / 0.01)), sh_dc=torch.zeros(n, 3), max_sh_degree=0)
    first = len(means) - len(probes)
    return gs, {name: (first + k, hid) for k, (name, (_, _, hid)) in enumerate(probes.items())}, first


def test_behind_surface_golden_wall():
    gs, probes, n_wall = _wall_and_probes()
    hidden = behind_surface(gs, _cameras(), margin=0.01)
    assert hidden.dtype == torch.bool and hidden.shape == (len(gs),)
    for name, (i, expected) in probes.items():
        assert bool(hidden[i]) == expected, name
    assert not hidden[:n_wall].any()  # the wall is the surface
    # a margin wider than the blob's 15 % keeps it; the probe 0.5 % behind goes once the margin is below that
    assert not behind_surface(gs, _cameras(), margin=0.2)[probes["blob behind the wall"][0]]
    assert behind_surface(gs, _cameras(), margin=0.001)[probes["just behind, within the margin"][0]]
    ratio = surface_depth_ratio(gs, _cameras())  # the margins above from one set of renders
    assert math.isinf(ratio[probes["behind the wall, in no image"][0]])
    for m in (0.001, 0.01, 0.2):
        assert torch.equal(behind_by(ratio, m), behind_surface(gs, _cameras(), margin=m))
    # one view that finds the blob in front of its rendered surface (here: no wall in the way) keeps it
    no_wall = gs.subset(torch.arange(n_wall, len(gs)))
    assert not behind_surface(no_wall, _cameras(), margin=0.01).any()


def test_behind_surface_rejects_bad_arguments():
    gs, _, _ = _wall_and_probes()
    with pytest.raises(ValueError, match="margin"):
        behind_surface(gs, _cameras(), margin=0.0)
    with pytest.raises(ValueError, match="margin"):
        behind_by(torch.ones(3), -0.1)
    with pytest.raises(ValueError, match="no cameras"):
        behind_surface(gs, [], margin=0.01)


def _gaussians(items):
    """A model from ``(centre, scales, opacity)`` triples (axis-aligned, DC colour 0)."""
    n = len(items)
    return Gaussians(means=torch.tensor([c for c, _, _ in items], dtype=torch.float32),
                     quats=torch.tensor([[1.0, 0, 0, 0]] * n),
                     log_scales=torch.tensor(np.log([s for _, s, _ in items]), dtype=torch.float32),
                     opacity_logits=torch.tensor([math.log(o / (1 - o)) for _, _, o in items], dtype=torch.float32),
                     sh_dc=torch.zeros(n, 3), max_sh_degree=0)


def test_visible_fraction_golden_layers():
    """One camera at z = 2; three round probes (σ = 0.05, 3 px) at z = 0: one in the open, one behind a flat layer of
    opacity 0.5, one behind an opaque one (each layer a σ = 0.15 Gaussian at z = 0.5 on the probe's ray, 5σ or more
    from the other rays). The fraction is about the transmittance in front: 1, 0.5, ~0."""
    items = [((0.5, 0.0, 0.0), (0.05,) * 3, 0.9),  # 0: in the open
             ((-0.375, 0.0, 0.5), (0.15, 0.15, 0.001), 0.5), ((-0.5, 0.0, 0.0), (0.05,) * 3, 0.9),  # 1, 2: half
             ((0.0, 0.375, 0.5), (0.15, 0.15, 0.001), 0.99), ((0.0, 0.5, 0.0), (0.05,) * 3, 0.9),  # 3, 4: opaque
             ((0.0, 0.0, 3.0), (0.05,) * 3, 0.9)]  # 5: behind the camera
    g = _gaussians(items)
    cam = look_at((0.0, 0.0, 2.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fx=120.0, width=128, height=128, name="a")
    full = unoccluded_weight(g, cam)
    sigma_px = 0.05 * 120.0 / 2.0  # a round Gaussian's projected σ at depth 2, on the axis
    off_axis = math.sqrt(1 + (0.5 / 2.0) ** 2)  # the pinhole stretches it along x by this, 0.5 off the axis
    assert full[0] == pytest.approx(0.9 * 2 * math.pi * sigma_px**2 * off_axis, rel=1e-4)
    assert full[5] == 0.0
    w = blend_weights(g, cam)
    assert w[0] == pytest.approx(float(full[0]), rel=0.02)  # nothing in front: all of it shows
    assert w[5] == 0.0
    vf = visible_fraction(g, [cam])
    assert vf[0] > 0.95 and 0.4 < vf[2] < 0.6 and vf[4] < 0.1 and vf[5] == 0.0
    assert vf[1] > 0.95 and vf[3] > 0.95  # the layers themselves are in the open
    with pytest.raises(ValueError, match="no cameras"):
        visible_fraction(g, [])


def test_hidden_gaussians_keeps_what_shows_through_a_half_transparent_wall():
    gs, probes, n_wall = _wall_and_probes()
    blob = probes["blob behind the wall"][0]
    opaque = hidden_gaussians(gs, _cameras(), margin=0.01, max_visible=0.2)
    assert opaque[blob] and torch.equal(opaque, behind_surface(gs, _cameras(), margin=0.01))
    gs.params["opacity_logits"][:n_wall] = math.log(0.3 / 0.7)  # a wall that still renders a surface, and lets light by
    assert behind_surface(gs, _cameras(), margin=0.01)[blob]
    assert visible_fraction(gs, _cameras())[blob] > 0.2
    assert not hidden_gaussians(gs, _cameras(), margin=0.01, max_visible=0.2)[blob]
    assert hidden_gaussians(gs, _cameras(), margin=0.01, max_visible=None)[blob]  # the depth test alone
    with pytest.raises(ValueError, match="max_visible"):
        hidden_gaussians(gs, _cameras(), margin=0.01, max_visible=0.0)


def test_surface_tail_golden_wall():
    """Behind the opaque wall at z = 0: a large round blob (σ = 0.2, 0.3 behind) reaches through it, a small one
    (σ = 0.02, 0.1 behind) does not. Tail = o · exp(−½ (Δ/σ)²), Δ the distance along the ray from the wall to the
    centre, the largest over the views a and b (c does not hold them)."""
    gs, _, n_wall = _wall_and_probes()
    wall = gs.subset(torch.arange(n_wall))
    blobs = _gaussians([((0.0, 0.0, -0.3), (0.2,) * 3, 0.99), ((0.1, 0.0, -0.1), (0.02,) * 3, 0.99)])
    both = Gaussians(*(torch.cat([getattr(wall, k), getattr(blobs, k)]) for k in
                       ("means", "quats", "log_scales", "opacity_logits", "sh_dc")), max_sh_degree=0)
    cams = _cameras()
    ratio, tail = surface_measures(both, cams)
    assert torch.equal(ratio, surface_depth_ratio(both, cams))
    for k, (centre, sigma) in enumerate((((0.0, 0.0, -0.3), 0.2), ((0.1, 0.0, -0.1), 0.02))):
        expected = 0.0
        for cam in cams[:2]:
            c, b = np.asarray(cam.center), np.asarray(centre)
            delta = np.linalg.norm(b - c) * (1 - c[2] / (c[2] - b[2]))  # beyond the plane z = 0 along the ray
            expected = max(expected, 0.99 * math.exp(-0.5 * (delta / sigma) ** 2))
        assert float(tail[n_wall + k]) == pytest.approx(expected, rel=0.1, abs=1e-5)  # the small one: ~4e-6
    assert tail[n_wall] > 0.2 and tail[n_wall + 1] < 1e-4
    assert tail[:n_wall].max() <= 0.99 + 1e-6  # what shows is the surface: in front, its own opacity
    kept = hidden_gaussians(both, cams, margin=0.01, max_visible=None, min_tail=0.05)
    assert kept[n_wall] and not kept[n_wall + 1]  # both behind; only the one reaching through goes
    assert hidden_gaussians(both, cams, margin=0.01, max_visible=None)[n_wall + 1]
    with pytest.raises(ValueError, match="min_tail"):
        hidden_gaussians(both, cams, margin=0.01, max_visible=None, min_tail=1.0)


def _model(n=6):
    dc = torch.zeros(n, 3)
    dc[:, 0] = torch.arange(n, dtype=torch.float32)  # identities
    return Gaussians(means=torch.randn(n, 3), quats=torch.tensor([[1.0, 0, 0, 0]] * n),
                     log_scales=torch.full((n, 3), -4.0), opacity_logits=torch.zeros(n), sh_dc=dc, max_sh_degree=0)


def test_densifier_prunes_hidden_gaussians_at_its_iterations_only():
    cfg = DensifyConfig(stop_iter=100, interval=10, hidden_prune_iters=[150, 170])
    d = Densifier(cfg)
    gs = _model()
    opt = make_optimizer(gs, OptimConfig(), 1.0)
    calls = []

    def hidden():
        calls.append(len(gs))
        mask = torch.zeros(len(gs), dtype=torch.bool)
        mask[[0, len(gs) - 1]] = True  # the first and the last
        return mask

    for it in (120, 149, 151):
        assert d.step(it, gs, opt, 1.0, hidden=hidden).num_hidden == 0
    assert not calls and len(gs) == 6
    r = d.step(150, gs, opt, 1.0, hidden=hidden)
    assert r.num_hidden == 2 and r.num_after == 4 and calls == [6]
    assert gs.sh_dc[:, 0].round().long().tolist() == [1, 2, 3, 4]
    check_optimizer_state(gs, opt)
    d.step(170, gs, opt, 1.0, hidden=hidden)
    assert d.hidden_pruned == 4 and len(gs) == 2
    again = Densifier(cfg)
    again.load_state_dict(json.loads(json.dumps(d.state_dict(), default=lambda o: None)))
    assert again.hidden_pruned == 4
    with pytest.raises(GofError, match="would remove all 2"):
        d.step(170, gs, opt, 1.0, hidden=lambda: torch.ones(len(gs), dtype=torch.bool))
    assert len(gs) == 2
    for bad in ({"hidden_prune_iters": [0]}, {"hidden_prune_iters": [1.5]}, {"hidden_margin": 0.0},
                {"hidden_max_visible": 0.0}, {"hidden_max_visible": 1.5}, {"hidden_min_tail": -0.1},
                {"hidden_min_tail": 1.0}):
        with pytest.raises(GofError):
            DensifyConfig(**bad)


@pytest.mark.slow
def test_training_with_a_hidden_prune_reports_it(tiny_train_scene, tiny_train_overrides, tmp_path):
    from gof_warp.data import load_scene
    from gof_warp.training.presets import resolve_config
    from gof_warp.training.trainer import Trainer

    # every Gaussian behind shows less than all of itself: with 1.0 the count is the depth test's, through the same path
    over = [*tiny_train_overrides, "iterations=6", "densify.hidden_prune_iters=[4]", "densify.hidden_margin=0.01",
            "densify.hidden_max_visible=1.0"]
    cfg = resolve_config("quick", over, None)
    scene = load_scene(tiny_train_scene)
    trainer = Trainer(scene, cfg, tmp_path / "run", "cpu")
    expected = int(hidden_gaussians(trainer.gaussians, trainer.cameras, margin=0.01,
                                    max_visible=cfg.densify.hidden_max_visible, config=trainer.render_config).sum())
    metrics = trainer.run()
    assert isinstance(metrics["hidden_pruned"], int) and metrics["hidden_pruned"] > 0
    assert expected > 0  # 300 random points in a box: some lie inside the objects' renders' surfaces
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["hidden_pruned"] == metrics["hidden_pruned"]
    assert np.isfinite(metrics["test"]["psnr"])


def test_prune_iterations_beyond_the_run_are_said(tiny_train_scene, tiny_train_overrides, tmp_path, caplog):
    """The unbounded preset prunes at 15k-29k: a shorter run says that its prunes do not run, naming them."""
    import logging

    from gof_warp.data import load_scene
    from gof_warp.training.presets import resolve_config
    from gof_warp.training.trainer import Trainer

    scene = load_scene(tiny_train_scene)
    for prunes, said in (("[4,40]", "densify.hidden_prune_iters [40] lie beyond this run's 6 iterations: those"),
                         ("[40,50]", "[40, 50] lie beyond this run's 6 iterations: no hidden prune in it"),
                         ("[4]", None)):
        caplog.clear()
        cfg = resolve_config("quick", [*tiny_train_overrides, "iterations=6", f"densify.hidden_prune_iters={prunes}"],
                             None)
        with caplog.at_level(logging.INFO, logger="gof_warp.training.trainer"):
            Trainer(scene, cfg, tmp_path / prunes.strip("[]").replace(",", "_"), "cpu")
        lines = [r.getMessage() for r in caplog.records if "hidden_prune_iters" in r.getMessage()]
        assert (lines == []) if said is None else (len(lines) == 1 and said in lines[0]), lines
