"""Gaussians right in front of a training camera: the census a loss spike records."""

import json

import numpy as np
import pytest
import torch

from gof_warp.core.camera import Camera
from gof_warp.core.config import merge
from gof_warp.data import load_scene
from gof_warp.training.loss_monitor import LossSpikeMonitor
from gof_warp.training.near_camera import centre_depths, near_camera_census
from gof_warp.training.step_scalars import IterationScalars
from gof_warp.synthetic import make_scene
from gof_warp.training.trainer import TrainConfig, Trainer
from test_trainer import TINY


def _camera(centre, name="c") -> Camera:
    """A 40×30 camera at ``centre`` looking along world +y (OpenCV axes: x right, y down, z forward)."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])  # columns: cam x, y, z in world
    c2w[:3, 3] = centre
    return Camera.from_c2w(c2w, fx=40.0, fy=40.0, cx=20.0, cy=15.0, width=40, height=30, name=name)


def test_centre_depths_match_the_camera_projection_in_float64():
    cam = _camera((0.5, -1.0, 0.2))
    pts = np.random.default_rng(0).uniform(-3, 3, (500, 3))
    z, inside = centre_depths(torch.tensor(pts, dtype=torch.float64), cam)
    _, z_ref, inside_ref = cam.in_image(pts, near=0.0)
    assert np.allclose(z.numpy(), z_ref, atol=1e-12)
    assert np.array_equal(inside.numpy(), inside_ref)
    assert 0 < inside_ref.sum() < len(pts)  # both kinds present: the test can fail


def test_census_lists_the_nearest_centres_in_the_image_only():
    cam = _camera((0.0, 0.0, 0.0))
    means = torch.tensor([[0.0, 0.3, 0.0],   # 0.3 in front, image centre
                          [0.1, 0.8, 0.0],   # 0.8 in front, in the image
                          [0.0, 2.5, 0.0],   # beyond `within`
                          [0.0, -0.3, 0.0],  # behind the camera
                          [5.0, 0.5, 0.0]])  # in front but far outside the image
    opac = torch.tensor([0.9, 0.5, 0.7, 0.8, 0.6])
    scales = torch.tensor([[0.1, 0.2, 0.05], [0.01, 0.01, 0.02], [0.3, 0.3, 0.3], [1, 1, 1], [1, 1, 1.0]])
    c = near_camera_census(means, opac, scales, cam, within=1.0)
    assert c["count"] == c["visible"] == 2
    assert [n["depth"] for n in c["nearest"]] == [pytest.approx(0.3), pytest.approx(0.8)]
    assert c["nearest"][0]["opacity"] == pytest.approx(0.9) and c["nearest"][0]["max_scale"] == pytest.approx(0.2)
    assert near_camera_census(means, opac, scales, cam, within=1.0, top=1)["nearest"][0]["depth"] == pytest.approx(0.3)
    faint = near_camera_census(means, opac, scales, cam, within=1.0, min_opacity=0.6)  # the 0.8-deep one renders nothing
    assert (faint["count"], faint["visible"]) == (2, 1) and [n["depth"] for n in faint["nearest"]] == [pytest.approx(0.3)]


def test_monitor_lists_view_spikes_with_their_terms_and_keeps_them_in_its_state():
    m = LossSpikeMonitor(warmup=0, max_events=2)
    it = 0
    for _ in range(5):
        for v in ("a", "b"):
            it += 1
            m.update(it, 1.0, v, {"l1": 1.0})
            assert m.last_view_spike is None
    m.update(it + 1, 50.0, "a", {"l1": 2.0, "distortion": 0.5})
    assert m.last_view_spike == {"iteration": it + 1, "view": "a", "ratio": 50.0, "loss": 50.0, "view_median": 1.0,
                                 "terms": {"l1": 2.0, "distortion": 0.5}}
    m.last_view_spike["near_camera"] = {"count": 3}  # what the trainer attaches
    m.update(it + 2, 1.0, "b")
    assert m.last_view_spike is None
    m.update(it + 3, 80.0, "b")
    m.update(it + 4, 90.0, "a")  # over max_events: counted, not listed
    report = m.report()
    assert [e["view"] for e in report["view_spikes"]] == ["a", "b"]
    assert report["view_spikes"][0]["near_camera"] == {"count": 3}
    assert report["view_count_over_threshold"] == 3
    with pytest.raises(ValueError, match="max_events"):
        LossSpikeMonitor(max_events=-1)
    again = LossSpikeMonitor(warmup=0, max_events=2)
    again.load_state_dict(m.state_dict())
    assert again.report()["view_spikes"] == report["view_spikes"]


@pytest.mark.slow
def test_a_view_spike_in_training_records_what_sits_in_front_of_that_camera(tmp_path):
    scene = load_scene(make_scene("default", tmp_path / "s", views=6, resolution=(32, 32), device="cpu"))
    t = Trainer(scene, merge(TrainConfig(), TINY), tmp_path / "run", "cpu")
    cam = t.cameras[2]
    planted = torch.tensor(cam.center + 0.3 * cam.R[2], dtype=torch.float32)  # 0.3 in front, on the optical axis
    with torch.no_grad():
        t.gaussians.params["means"][0] = planted
    t.spikes = LossSpikeMonitor(warmup=0)
    for it in range(1, 6):  # a steady loss, then one visit of that view 40x higher
        loss = 40.0 if it == 5 else 1.0
        t._pending.add(IterationScalars(it, cam.name, len(t.gaussians), False, 0.0, {}),
                       {"total": torch.tensor(loss), "l1": torch.tensor(loss)})
    t._drain()
    (event,) = t.spikes.report()["view_spikes"]
    assert event["iteration"] == 5 and event["view"] == cam.name and event["ratio"] == pytest.approx(40.0)
    near = event["near_camera"]
    assert near["nearest"][0]["depth"] == pytest.approx(0.3, abs=1e-5) and near["count"] >= 1
    assert near["within"] == pytest.approx(0.25 * scene.extent) and near["spike_iteration"] == 5
    assert t._near_census("no such view", spike_iteration=0) is None


def test_distortion_colours_run_from_dark_to_bright_and_an_empty_map_is_dark():
    from gof_warp.viz.panels import colorize_distortion

    d = np.array([[0.0, 0.01, 0.25, 1.0]])
    c = colorize_distortion(d).astype(int)
    brightness = c.sum(axis=-1)[0]
    assert np.all(np.diff(brightness) > 0)  # viridis brightens with the value
    assert tuple(c[0, -1]) == tuple(np.round(np.array([0.993, 0.906, 0.144]) * 255).astype(int))  # the maximum
    assert np.array_equal(colorize_distortion(np.zeros((2, 3))), np.broadcast_to(c[0, 0], (2, 3, 3)))


@pytest.mark.slow
def test_training_draws_a_picture_of_each_listed_spike(tmp_path):
    from gof_warp.viz.pictures import spike_picture_name, spike_picture_or_warning

    scene = load_scene(make_scene("default", tmp_path / "s", views=6, resolution=(32, 32), device="cpu"))
    t = Trainer(scene, merge(TrainConfig(), TINY), tmp_path / "run", "cpu")
    class Listing(LossSpikeMonitor):  # lists iterations 5, 11 and 19 as spikes (a 24-iteration run has none)
        def update(self, iteration, loss, view="", terms=None):
            ratio = super().update(iteration, loss, view, terms)
            if iteration in (5, 11, 19):
                self.last_view_spike = {"iteration": iteration, "view": view, "ratio": 12.0, "terms": dict(terms)}
                self.events.append(self.last_view_spike)
            return ratio

    t.spikes = Listing()
    seen = []

    def on_spike(trainer, event):
        seen.append(event["iteration"])
        spike_picture_or_warning(trainer, event)

    metrics = t.run(on_spike=on_spike)
    listed = metrics["loss_spikes"]["view_spikes"]
    assert seen == [e["iteration"] for e in listed] == [5, 11, 19]  # each listed spike once, in order
    for e in listed:
        assert e["near_camera"]["spike_iteration"] == e["iteration"]
        assert e["picture"] == "pictures/" + spike_picture_name(e["iteration"], e["view"])
        assert (tmp_path / "run" / e["picture"]).is_file()
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())["loss_spikes"]["view_spikes"]
    assert [e.get("picture") for e in saved] == [e["picture"] for e in listed]
    # an event naming no training view: a warning, no picture, no exception
    assert spike_picture_or_warning(t, {"view": "nope", "iteration": 3, "ratio": 2.0}) == []
    assert spike_picture_name(7, "a/b c") == "spike_it7_a_b_c.png"


def _ray_census_f64(means, quats, scales, opac, cam, within, near, alpha_min, alpha_max, nx):
    """Brute force with the float64 reference renderer's ray–Gaussian quantities (tests/reference_render)."""
    from reference_render import RefCamera, _ray_gaussian, f64
    from gof_warp.core.model import quat_to_rotmat

    rc = RefCamera(cam)
    ny = max(1, round(nx * cam.height / cam.width))
    px = (torch.arange(nx, dtype=torch.float64) + 0.5) * cam.width / nx
    py = (torch.arange(ny, dtype=torch.float64) + 0.5) * cam.height / ny
    yy, xx = torch.meshgrid(py, px, indexing="ij")
    rays = torch.stack([(xx - cam.cx) / cam.fx, (yy - cam.cy) / cam.fy, torch.ones_like(xx)], -1).reshape(-1, 3)
    mu_v = rc.to_camera(f64(means))
    R_v = rc.R @ quat_to_rotmat(torch.nn.functional.normalize(f64(quats), dim=1))
    t, d2, _ = _ray_gaussian(mu_v[None], R_v, f64(scales), rays)
    alpha = torch.clamp(f64(opac) * torch.exp(-0.5 * d2), max=alpha_max)
    hit = (t > near) & (t <= within) & (alpha >= alpha_min) & (mu_v[:, 2] > near)[None]
    alpha = torch.where(hit, alpha, torch.zeros_like(alpha))
    return hit, alpha, t


def test_ray_census_matches_the_float64_reference_on_random_gaussians():
    from gof_warp.training.near_camera import near_ray_census

    cam = _camera((0.0, 0.0, 0.0))
    gen = torch.Generator().manual_seed(3)
    n = 25
    depth = torch.rand(n, generator=gen) * 2.0 + 0.15  # world +y is the view direction; some nearer than `near`
    means = torch.stack([(torch.rand(n, generator=gen) - 0.5) * 1.6 * depth, depth,
                         (torch.rand(n, generator=gen) - 0.5) * 1.2 * depth], 1).double()
    quats = torch.randn(n, 4, generator=gen).double()
    scales = (torch.rand(n, 3, generator=gen) * 0.06 + 0.01).double()
    opac = torch.rand(n, generator=gen).double()
    kw = dict(within=1.5, near=0.2, alpha_min=1 / 255, alpha_max=0.99)
    got = near_ray_census(means, quats, scales, opac, cam, rays_across=16, top=n, **kw)
    hit, alpha, t = _ray_census_f64(means, quats, scales, opac, cam, nx=16, **kw)
    assert got["rays"] == hit.shape[0] == 16 * 12
    assert 0.05 < got["covered"] < 1.0  # some rays meet nothing near: the test can fail both ways
    assert got["covered"] == pytest.approx(float(hit.any(1).double().mean()), abs=1e-4)
    assert got["near_alpha"] == pytest.approx(float((1 - torch.prod(1 - alpha, 1)).mean()), abs=1e-5)
    counts = hit.sum(0)
    order = torch.argsort(alpha.sum(0), descending=True)
    order = order[counts[order] > 0]
    assert len(got["contributors"]) == len(order) > 3
    for c, i in zip(got["contributors"], order.tolist()):
        assert c["coverage"] == pytest.approx(float(counts[i]) / hit.shape[0], abs=1e-4)
        assert c["mean_alpha"] == pytest.approx(float(alpha[:, i].sum() / counts[i]), abs=1e-4)
        assert c["t_mean"] == pytest.approx(float(t[hit[:, i], i].mean()), abs=1e-4)
        assert c["opacity"] == pytest.approx(float(opac[i]), abs=1e-4)


def test_ray_census_sees_a_wide_gaussian_whose_centre_lies_beside_the_image():
    from gof_warp.training.near_camera import near_ray_census

    cam = _camera((0.0, 0.0, 0.0))  # 40x30, fx 40: the image spans x/z in [-0.5, 0.5]
    means = torch.tensor([[1.2, 0.5, 0.0],    # centre at x/z = 2.4: outside the image; a wide flat disc
                          [0.0, 0.1, 0.0],    # centre nearer than the near plane: culled, as the renderer does
                          [0.0, 3.0, 0.0]])   # far beyond `within`
    quats = torch.tensor([[1.0, 0, 0, 0]] * 3)
    scales = torch.tensor([[1.0, 0.01, 1.0], [0.5, 0.5, 0.5], [2.0, 0.01, 2.0]])  # world y thin: faces the camera
    opac = torch.tensor([0.8, 0.9, 0.9])
    centres = near_camera_census(means, opac, scales, cam, within=1.0)
    assert [n["depth"] for n in centres["nearest"]] == [pytest.approx(0.1)]  # it misses the wide one
    rays = near_ray_census(means, quats, scales, opac, cam, within=1.0, rays_across=20)
    assert rays["covered"] == 1.0 and len(rays["contributors"]) == 1
    (c,) = rays["contributors"]
    assert not c["in_image"] and c["depth"] == pytest.approx(0.5) and c["t_mean"] == pytest.approx(0.5, abs=1e-3)
    assert c["coverage"] == 1.0 and 0.3 < c["mean_alpha"] <= 0.8
    assert near_ray_census(means, quats, scales, opac, cam, within=0.4, rays_across=20)["covered"] == 0.0


def test_near_camera_bounds_from_the_nearest_point_each_camera_sees():
    from gof_warp.training.near_camera import near_camera_bounds

    cams = [_camera((0.0, 0.0, 0.0), "a"), _camera((0.0, 5.0, 0.0), "b"), _camera((0.0, 0.0, 9.0), "c")]
    pts = torch.tensor([[0.0, 2.0, 0.0], [0.1, 3.0, 0.1], [0.0, 8.0, 0.0]], dtype=torch.float64)
    # a sees the points at depths 2, 3, 8; b sees only the one 3 ahead; c's image holds none of them
    assert near_camera_bounds(pts, cams, 0.5).tolist() == pytest.approx([1.0, 1.5, 0.0])


def test_gaussians_in_front_of_cameras_match_the_float64_ray_test_per_camera():
    from gof_warp.training.near_camera import in_front_of_cameras, stack_cameras

    cams = [_camera((0.0, 0.0, 0.0), "a"), _camera((0.3, 1.0, 0.0), "b"), _camera((0.0, 0.0, 2.0), "c")]
    bounds = torch.tensor([1.2, 0.8, 0.1])  # c's bound is below the near plane: nothing counts in front of it
    gen = torch.Generator().manual_seed(5)
    n = 300
    means = torch.stack([torch.rand(n, generator=gen) * 3 - 1.5, torch.rand(n, generator=gen) * 4 - 0.5,
                         torch.rand(n, generator=gen) * 3 - 1.0], 1).double()
    quats = torch.randn(n, 4, generator=gen).double()
    scales = (torch.rand(n, 3, generator=gen) * 0.08 + 0.01).double()
    opac = torch.rand(n, generator=gen).double()
    got = in_front_of_cameras(means, quats, scales, opac, stack_cameras(cams, dtype=torch.float64), bounds,
                              rays_across=16, chunk=50)
    want = torch.zeros(n, dtype=torch.bool)
    for cam, b in zip(cams, bounds.tolist()):
        if b > 0.2:
            hit, _, _ = _ray_census_f64(means, quats, scales, opac, cam, b, 0.2, 1 / 255, 0.99, 16)
            want |= hit.any(0)
    assert 5 < int(want.sum()) < n and torch.equal(got, want)
    # the wide disc beside the image of the census test above is in front of camera a; nothing is beyond a bound
    wide = in_front_of_cameras(torch.tensor([[1.2, 0.5, 0.0], [0.0, 1.5, 0.0]]), torch.tensor([[1.0, 0, 0, 0]] * 2),
                               torch.tensor([[1.0, 0.01, 1.0], [0.3, 0.3, 0.3]]), torch.tensor([0.8, 0.9]),
                               stack_cameras(cams[:1]), torch.tensor([1.0]), rays_across=20)
    assert wide.tolist() == [True, False]


@pytest.mark.slow
def test_the_trainer_removes_a_gaussian_planted_in_front_of_a_camera_at_a_late_prune(tmp_path):
    scene = load_scene(make_scene("default", tmp_path / "s", views=6, resolution=(32, 32), device="cpu"))
    late = {"densify": {**TINY["densify"], "late_prune_interval": 2, "near_camera_fraction": 0.5}}
    off = Trainer(scene, merge(merge(TrainConfig(), TINY), late), tmp_path / "r0", "cpu")  # random start
    assert off._in_front is None and off.init_info["near_camera_prune"] == "off: no initial points"
    scene.points = np.random.default_rng(0).uniform(-0.5, 0.5, (200, 3))  # points around the object
    scene.point_colors = np.full((200, 3), 0.5)
    cfg = merge(merge(TrainConfig(), TINY), {**late, "model": {**TINY["model"], "init": "sfm"}})
    t = Trainer(scene, cfg, tmp_path / "run", "cpu")
    cam = t.cameras[2]
    nearest = min(float(z[inside].min()) for z, inside in [centre_depths(torch.tensor(scene.points), cam)])
    with torch.no_grad():
        t.gaussians.params["means"][0] = torch.tensor(cam.center + 0.2 * nearest * cam.R[2])  # well inside the bound
        t.gaussians.params["means"][1] = torch.tensor(cam.center + 0.9 * nearest * cam.R[2])  # beyond it
        t.gaussians.params["opacity_logits"][:2] = 4.0
    assert t.init_info["near_camera_prune"]["fraction"] == 0.5
    flagged = t._in_front()
    assert flagged[0] and not flagged[1]
    marker = t.gaussians.means[1].clone()
    n = len(t.gaussians)
    report = t.densifier.step(cfg.densify.stop_iter, t.gaussians, t.optimizer, scene.extent, near_camera=t._in_front)
    assert report.late_pruned and report.num_near_camera >= 1 and len(t.gaussians) == n - report.num_pruned
    assert not t._in_front().any() and (t.gaussians.means == marker).all(1).any()  # the far one stays


def test_render_near_from_points_gives_every_camera_its_own_near_plane(tmp_path):
    """``render.near_from_points``: each train and test camera clips at that fraction of its nearest initial point
    (never below ``render.near``); a Gaussian planted nearer than that is not drawn in that view but is beyond it;
    the planes reach ``cameras.json`` (what extraction and pictures read); off, with a warning, without points."""
    from gof_warp.rendering.render import render
    from gof_warp.training.run_folder import cameras_from_json

    scene = load_scene(make_scene("default", tmp_path / "s", views=6, resolution=(32, 32), device="cpu"))
    scene.test = scene.train[4:]
    scene.train = scene.train[:4]
    clip = {"render": {"near_from_points": 0.5}}
    off = Trainer(scene, merge(merge(TrainConfig(), TINY), clip), tmp_path / "r0", "cpu")  # random start
    assert off.init_info["camera_near"] == "off: no initial points" and all(c.near == 0 for c in off.cameras)
    scene.points = np.random.default_rng(0).uniform(-0.5, 0.5, (200, 3))
    scene.point_colors = np.full((200, 3), 0.5)
    cfg = merge(merge(TrainConfig(), TINY), {**clip, "model": {**TINY["model"], "init": "sfm"}})
    t = Trainer(scene, cfg, tmp_path / "run", "cpu")
    assert all(v.camera.near == 0 for v in scene.all_views)  # the caller's scene is left as it was
    for v in t.scene.all_views:
        z, inside = centre_depths(torch.tensor(scene.points), v.camera)
        assert v.camera.near == pytest.approx(0.5 * float(z[inside].min()), rel=1e-9)
    assert t.cameras == t.scene.train_cameras and len(t.scene.test) == 2
    assert t.init_info["camera_near"]["min"] == pytest.approx(min(c.near for c in t.cameras + t.scene.test_cameras), abs=1e-4)
    cam = t.cameras[1]
    with torch.no_grad():  # one opaque Gaussian, first in front of the camera's plane, then beyond it
        t.gaussians.params["opacity_logits"][:] = -20.0
        t.gaussians.params["opacity_logits"][0] = 4.0
        t.gaussians.params["log_scales"][0] = float(np.log(0.05))
        seen = []
        for depth in (0.6 * cam.near, 1.5 * cam.near):
            t.gaussians.params["means"][0] = torch.tensor(cam.center + depth * cam.R[2])
            seen.append(float(render(t.gaussians, cam, config=t.render_config)["alpha"].max()))
    assert seen[0] == 0.0 and seen[1] > 0.1, seen
    t._write_static_files()
    assert [c.near for c in cameras_from_json(tmp_path / "run" / "cameras.json")] == [c.near for c in t.cameras]


@pytest.mark.slow
def test_a_random_start_bounds_its_cameras_by_the_rendered_surfaces_and_resumes_with_them(tmp_path, monkeypatch):
    """``model.surface_points_iter``: a random start gets the SfM-point bounds (near planes, near-camera prune) from
    the surfaces its renders agree on at that iteration; cameras.json carries them; a run resumed after it bounds its
    cameras alike, and the run continues bit-for-bit."""
    from gof_warp.training.run_folder import cameras_from_json

    scene = load_scene(make_scene("default", tmp_path / "s", views=8, resolution=(32, 32), device="cpu"))
    bound = {"render": {"near_from_points": 0.5},
             "densify": {**TINY["densify"], "late_prune_interval": 2, "near_camera_fraction": 0.25,
                         "opacity_reset_interval": 1000, "min_opacity": 0.001},
             "model": {**TINY["model"], "surface_points_iter": 14}}
    cfg = merge(merge(TrainConfig(), TINY), bound)
    t = Trainer(scene, cfg, tmp_path / "run", "cpu")
    assert t._in_front is None and all(c.near == 0 for c in t.cameras)
    # 14 iterations make no opaque surface (surface_points itself: tests/training/test_surface_points.py); the points
    # the renders would agree on are given here, so that what the trainer does with them is under test
    import gof_warp.training.surface_points as sp

    given = np.random.default_rng(0).uniform(-0.5, 0.5, (200, 3))
    calls = []
    monkeypatch.setattr(sp, "surface_points", lambda g, cams, cfg: calls.append(len(cams)) or given)
    for _ in range(13):
        t.step()
    assert not calls and all(c.near == 0 for c in t.cameras)
    t.step()
    assert calls == [len(t.cameras)] and t.init_info["surface_points"] == {"iteration": 14, "points": 200}
    for v in t.scene.all_views:  # as SfM points would: half the depth of the nearest point in each view
        z, inside = centre_depths(torch.tensor(given), v.camera)
        assert v.camera.near == pytest.approx(0.5 * float(z[inside].min()), rel=1e-9)
    assert t._in_front is not None
    t.run()
    assert [c.near for c in cameras_from_json(tmp_path / "run" / "cameras.json")] == [c.near for c in t.cameras]
    # resumed from the checkpoint at 12 (before) and at 24 (after the bounds): both end where the run ended
    ckpts = sorted((tmp_path / "run" / "checkpoints").glob("ckpt_*.pt"))
    assert [p.name for p in ckpts][-1] == "ckpt_24.pt" or len(ckpts) >= 1
    r = Trainer(scene, cfg, tmp_path / "run", "cpu")
    r.resume()
    assert r._surface_points is not None and [c.near for c in r.cameras] == [c.near for c in t.cameras]
    # off without the setting, and ignored by a run from measured points
    plain = Trainer(scene, merge(merge(TrainConfig(), TINY), {**bound, "model": TINY["model"]}), tmp_path / "p", "cpu")
    assert plain._surface_points_at == 0
