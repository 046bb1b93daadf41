"""A random start keeps its points and Gaussians where two training cameras see them (``model.random_min_views``):
the count against a float64 reference, the redrawn initial points, the densifier's prune and the trainer's rule."""

import math

import numpy as np
import pytest
import torch

from gof_warp.core.camera import look_at
from gof_warp.core.config import ConfigError, merge
from gof_warp.core.errors import GofError
from gof_warp.core.scene import Scene, View
from gof_warp.data import load_scene
from gof_warp.data.init_points import initial_point_cloud, views_seeing_points
from gof_warp.synthetic import make_scene
from gof_warp.training.near_camera import stack_cameras, views_seeing
from gof_warp.training.trainer import ModelConfig, TrainConfig, Trainer

from test_trainer import TINY

SIZE = 32


def _ring(n=8, radius=3.0, f=30.0, arc=2 * np.pi):
    """``n`` cameras on (an ``arc`` of) a circle at height 1 looking at the origin (about 56 degrees across)."""
    step = arc / n if arc >= 2 * np.pi else arc / (n - 1)
    return [look_at((radius * math.cos(a), radius * math.sin(a), 1.0), (0, 0, 0), fx=f, fy=f, width=SIZE,
                    height=SIZE, name=f"c{i}") for i, a in enumerate(step * np.arange(n))]


def _scene(cams) -> Scene:
    return Scene(train=[View(c, np.zeros((SIZE, SIZE, 3), np.uint8), name=c.name) for c in cams])


def _reference_counts(points: np.ndarray, cameras, near) -> np.ndarray:
    """Float64, from the definition: ``z > near``, ``0 <= u < W``, ``0 <= v < H``."""
    out = np.zeros(len(points), int)
    for cam, nr in zip(cameras, near):
        pc = points @ np.asarray(cam.R, np.float64).T + np.asarray(cam.t, np.float64)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = cam.fx * pc[:, 0] / z + cam.cx
            v = cam.fy * pc[:, 1] / z + cam.cy
        out += (z > nr) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    return out


def test_views_seeing_matches_the_float64_count():
    cams = _ring()
    pts = np.random.default_rng(0).uniform(-4, 4, (5000, 3))  # inside, beside and behind the cameras
    near = np.linspace(0.1, 2.5, len(cams))
    ref = _reference_counts(pts, cams, near)
    got = views_seeing(torch.tensor(pts), stack_cameras(cams, dtype=torch.float64), torch.tensor(near), chunk=777)
    assert np.array_equal(got.numpy(), ref)
    assert set(np.unique(ref)) >= {0, 1, 2} and ref.max() == len(cams)  # every case occurs
    assert np.array_equal(views_seeing_points(pts, cams), _reference_counts(pts, cams, np.zeros(len(cams))))


def test_a_point_right_in_front_of_one_camera_is_seen_by_it_alone():
    """Cameras on a quarter circle (a capture from one side): what lies right in front of the middle camera is in
    its image alone, the point they all look at in every image. (On a whole ring the cameras across the circle
    look back at it.)"""
    cams = _ring(n=5, arc=np.pi / 2)
    c = cams[2]
    front = c.center + 0.3 * np.asarray(c.R)[2]
    assert views_seeing_points(np.stack([front, np.zeros(3)]), cams).tolist() == [1, len(cams)]
    assert views_seeing_points(front[None], _ring())[0] > 1


def test_random_points_are_drawn_where_two_cameras_see_them():
    cams = _ring()
    scene = _scene(cams)
    box = (-3.5, -3.5, -1.0, 3.5, 3.5, 2.0)  # reaches past the cameras
    plain, _, _ = initial_point_cloud(scene, "random", random_points=4000, init_box=box, seed=1)
    assert (views_seeing_points(plain, cams) < 2).mean() > 0.03  # the box holds space one camera at most sees
    pts, cols, info = initial_point_cloud(scene, "random", random_points=4000, init_box=box, seed=1, min_views=2)
    assert len(pts) == len(cols) == 4000 and info["random_min_views"] == 2
    assert (views_seeing_points(pts, cams) >= 2).all()
    lo, hi = np.asarray(box[:3]), np.asarray(box[3:])
    assert ((pts >= lo) & (pts <= hi)).all()
    kept = views_seeing_points(plain, cams) >= 2  # those already seen keep their draws
    assert np.array_equal(pts[kept], plain[kept])


def test_a_box_every_camera_sees_draws_the_same_points_as_before():
    """The README job's box (objects at the centre of a ring): no redraw, the same model as without the rule."""
    scene = _scene(_ring())
    box = (-0.5, -0.5, -0.5, 0.5, 0.5, 0.5)
    a = initial_point_cloud(scene, "random", random_points=500, init_box=box, seed=4)
    b = initial_point_cloud(scene, "random", random_points=500, init_box=box, seed=4, min_views=2)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_a_box_no_two_cameras_see_is_an_error_naming_the_setting():
    scene = _scene(_ring())
    with pytest.raises(GofError, match=r"model.random_min_views.*model.init_box"):
        initial_point_cloud(scene, "random", random_points=50, init_box=(20, 20, 20, 21, 21, 21), min_views=2)


def test_the_setting_is_validated():
    for bad in (-1, 1.5, True, "2"):
        with pytest.raises(ConfigError, match="model.random_min_views"):
            ModelConfig(random_min_views=bad)


def test_the_trainer_prunes_what_fewer_than_two_training_cameras_see_at_each_densification(tmp_path):
    scene = load_scene(make_scene("default", tmp_path / "s", views=6, resolution=(SIZE, SIZE), device="cpu"))
    cfg = merge(merge(TrainConfig(), TINY), {"model": {**TINY["model"], "init_box": [-4, -4, -4, 4, 4, 4]}})
    t = Trainer(scene, cfg, tmp_path / "run", "cpu")
    assert t.init_info["unseen_prune"] == {"min_views": 2}
    cams = t.cameras

    def counts():
        return views_seeing_points(t.gaussians.means.detach().double().numpy(), cams)

    assert (counts() >= 2).all()  # the initial points
    # a point right in front of a camera (beyond the near plane) that no other training camera's image holds
    axis_points = np.stack([c.center + d * np.asarray(c.R)[2] for c in cams for d in (0.3, 0.5, 0.8)])
    lonely = axis_points[views_seeing_points(axis_points, cams) == 1]
    assert len(lonely)
    with torch.no_grad():
        t.gaussians.params["means"][0] = torch.tensor(lonely[0])
    assert counts()[0] == 1
    while t.iteration < cfg.densify.start_iter + 1:  # the first densification
        t.step()
    assert t.densifier.unseen_pruned >= 1 and (counts() >= 2).all()
    metrics = t.run()
    assert metrics["unseen_pruned"] == t.densifier.unseen_pruned
    # a run from points, or the setting 0: no such rule
    off = Trainer(scene, merge(cfg, {"model": {"random_min_views": 0}}), tmp_path / "off", "cpu")
    assert off._unseen is None and "unseen_prune" not in off.init_info


def test_far_points_lie_beyond_the_box_out_to_the_far_background_where_two_cameras_see_them():
    cams = _ring()
    scene = _scene(cams)
    box = np.array([-0.5, -0.5, -0.5, 0.5, 0.5, 0.5])
    pts, cols, info = initial_point_cloud(scene, "random", random_points=2000, init_box=box, seed=2, min_views=2,
                                          far_fraction=0.25)
    assert len(pts) == len(cols) == 2000 and info["random_far_points"] == 500
    inside = np.all((pts >= box[:3]) & (pts <= box[3:]), axis=1)
    assert inside[:1500].all() and not inside[1500:].any()  # the box's points first, then the far ones
    r = np.linalg.norm(pts[1500:], axis=1)
    r0, r1 = 0.5 * np.linalg.norm(box[3:] - box[:3]), 20.0 * np.linalg.norm(cams[0].center)
    assert r.min() >= r0 - 1e-9 and r.max() <= r1 + 1e-9
    assert np.median(r) > 3.0 * r0  # log-uniform: half of them beyond the geometric mean of r0 and r1
    assert (views_seeing_points(pts, cams) >= 2).all()
    # no far points: the box's draws as before
    a = initial_point_cloud(scene, "random", random_points=300, init_box=box, seed=2, min_views=2)
    b = initial_point_cloud(scene, "random", random_points=300, init_box=box, seed=2, min_views=2, far_fraction=0.0)
    assert np.array_equal(a[0], b[0]) and "random_far_points" not in b[2]


def test_the_far_fraction_is_validated():
    for bad in (-0.1, 1.0, True, "0.5"):
        with pytest.raises(ConfigError, match="model.random_far_fraction"):
            ModelConfig(random_far_fraction=bad)
