"""Points on the surfaces the training views agree on (model.surface_points_iter): golden case of a plane seen by
several cameras, with a floater right in front of one of them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gof_warp.core.camera import Camera, look_at
from gof_warp.core.model import Gaussians
from gof_warp.rendering.render import RenderConfig
from gof_warp.training.surface_points import lift, surface_points


def _cameras(n=5):
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        eye = np.array([0.6 * np.cos(a), 0.6 * np.sin(a), 2.0])
        cams.append(look_at(eye, np.zeros(3), up=(0.0, 1.0, 0.0), fx=40.0, fy=40.0, cx=16.0, cy=12.0, width=32,
                            height=24, name=f"c{k}"))
    return cams


def _plane_with_floater(cam0: Camera, floater: bool):
    """Opaque flat Gaussians tiling the plane z = 0 over [-1.5, 1.5]², and a big opaque one 0.3 in front of cam0."""
    xs = np.linspace(-1.5, 1.5, 31)
    xy = np.stack(np.meshgrid(xs, xs, indexing="xy"), -1).reshape(-1, 2)
    means = np.c_[xy, np.zeros(len(xy))]
    scales = np.tile([0.08, 0.08, 0.002], (len(means), 1))
    if floater:
        means = np.r_[means, [cam0.center + 0.3 * cam0.R[2]]]  # 0.3 along the viewing axis
        scales = np.r_[scales, [[0.1, 0.1, 0.1]]]
    rot = np.tile([1.0, 0, 0, 0], (len(means), 1))
    return Gaussians.from_activated(torch.tensor(means, dtype=torch.float32), torch.tensor(rot, dtype=torch.float32),
                                    torch.tensor(scales, dtype=torch.float32), torch.full((len(means),), 0.99),
                                    torch.full((len(means), 3), 0.5))


def test_lift_inverts_the_projection_in_float64():
    cam = _cameras()[1]
    pts = np.random.default_rng(0).uniform(-1, 1, (50, 3))
    uv, z = cam.project(pts)
    back = lift(cam, torch.tensor(uv[:, 0]), torch.tensor(uv[:, 1]), torch.tensor(z)).numpy()
    np.testing.assert_allclose(back, pts, atol=1e-12)


@pytest.mark.parametrize("floater", [False, True])
def test_points_lie_on_the_agreed_plane_and_not_on_a_one_view_floater(floater):
    cams = _cameras()
    g = _plane_with_floater(cams[0], floater)
    cfg = RenderConfig(near=0.05)
    pts = surface_points(g, cams, cfg, stride=2, min_views=2)
    assert len(pts) > 200
    assert np.abs(pts[:, 2]).max() < 0.05  # on the plane (its Gaussians are 2 mm thick; median depth within them)
    near0 = np.linalg.norm(pts - cams[0].center, axis=1).min()
    assert near0 > 1.5  # nothing at the floater's 0.3
    if floater:  # without the agreement test, the floater's pixels would be kept: the test can fail
        single = surface_points(g, cams, cfg, stride=2, min_views=1)
        assert np.linalg.norm(single - cams[0].center, axis=1).min() < 0.5


def test_nothing_opaque_gives_no_points_and_bad_arguments_are_refused():
    cams = _cameras(3)
    g = _plane_with_floater(cams[0], False)
    far = [look_at(np.array([0, 0, -2.0]), np.array([0, 0, -5.0]), up=(0.0, 1.0, 0.0), fx=40.0, fy=40.0, cx=16.0,
                   cy=12.0, width=32, height=24)] * 2  # looking away from the plane
    assert surface_points(g, far, RenderConfig(near=0.05)).shape == (0, 3)
    with pytest.raises(ValueError):
        surface_points(g, cams, min_views=0)
