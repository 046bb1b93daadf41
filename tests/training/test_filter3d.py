"""The Mip-Splatting 3D filter as GOF computes it, on hand-built cameras and against a float64 loop."""

import math

import numpy as np
import pytest
import torch

from gof_warp.core.camera import Camera, look_at
from gof_warp.core.errors import GofError
from gof_warp.training.filter3d import compute_filter_3d, nearest_seen_depth_torch, update_filter_3d
from gof_warp.core.model import Gaussians

TOL64 = 1e-12  # float64 throughout: only rounding
TOL32 = 1e-6  # float32 model centres: one rounding per operation
SQRT02 = math.sqrt(0.2)


def _axis_camera(z_offset, fx, cx=40.0, w=64, h=48):
    """Camera at (0, 0, -z_offset) looking down +z (world = camera axes shifted), principal point off-centre."""
    return Camera(R=np.eye(3), t=np.array([0.0, 0.0, z_offset]), fx=fx, fy=fx, cx=cx, cy=20.0, width=w, height=h)


def test_hand_built_cameras():
    near_cam, far_cam = _axis_camera(0.0, fx=100.0), _axis_camera(3.0, fx=150.0)
    # sees none of the points (all behind it) but still sets f_max, as in GOF
    blind = Camera(R=np.diag([1.0, -1.0, -1.0]), t=np.array([0.0, 0.0, -20.0]), fx=300.0, fy=300.0, cx=32.0, cy=24.0,
                   width=64, height=48)
    u_edge = lambda z, frac, cam: (frac * cam.width - cam.cx) * z / cam.fx  # noqa: E731  x giving u = frac·W
    pts = np.array([
        [0.0, 0.0, 2.0],  # seen by both: z = 2 (near) and 5 (far) -> d = 2
        [u_edge(2.0, 1.10, near_cam), 0.0, 2.0],  # inside the 15 % guard band of the near camera -> d = 2
        [u_edge(2.0, 1.20, near_cam), 0.0, 2.0],  # outside the near camera's band; far camera: z = 5
        [0.0, 0.0, 0.1],  # z = 0.1 < near plane for the near camera; far camera sees z = 3.1
        [0.0, 0.0, -10.0],  # behind both cameras: unseen -> max d of the seen ones
    ])
    # the far camera must see point 2 (u = fx x / z + cx within its band)
    u_far = far_cam.fx * pts[2, 0] / 5.0 + far_cam.cx
    assert -0.15 * 64 <= u_far <= 1.15 * 64
    phi = compute_filter_3d(torch.tensor(pts), [near_cam, far_cam, blind]).numpy()
    d = np.array([2.0, 2.0, 5.0, 3.1, 5.0])
    np.testing.assert_allclose(phi, d / 300.0 * SQRT02, rtol=TOL64)  # f_max = the largest fx of all cameras


def _loop_reference(pts, cams, near=0.2):
    d = np.full(len(pts), np.inf)
    for cam in cams:
        for i, p in enumerate(pts):
            x, y, z = cam.R @ p + cam.t
            if z <= near:
                continue
            u, v = cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy
            if -0.15 * cam.width <= u <= 1.15 * cam.width and -0.15 * cam.height <= v <= 1.15 * cam.height:
                d[i] = min(d[i], z)
    seen = np.isfinite(d)
    d[~seen] = d[seen].max()
    return d / max(c.fx for c in cams) * SQRT02


@pytest.mark.parametrize("chunk_elements", [1, 7, 1 << 22])
def test_matches_loop_reference_any_chunking(chunk_elements):
    rng = np.random.default_rng(0)
    cams = [look_at(rng.normal(size=3) * 4, rng.normal(size=3) * 0.3, fx=float(rng.uniform(80, 200)),
                    cx=float(rng.uniform(20, 44)), width=64, height=48) for _ in range(6)]
    pts = rng.normal(size=(300, 3)) * 2.5
    got = compute_filter_3d(torch.tensor(pts), cams, chunk_elements=chunk_elements).numpy()
    ref = _loop_reference(pts, cams)
    assert np.isfinite(ref).all() and len(np.unique(ref)) > 50  # a non-trivial mix of distances
    np.testing.assert_allclose(got, ref, rtol=TOL64)


def test_update_sets_model_buffer_and_errors():
    cam = _axis_camera(0.0, fx=100.0)
    g = Gaussians.from_points(np.array([[0.0, 0.0, 2.0], [0.1, 0.0, 3.0]]), device="cpu")
    phi = update_filter_3d(g, [cam])
    assert g.filter_3d is phi and torch.allclose(phi, torch.tensor([2.0, 3.0]) / 100.0 * SQRT02, rtol=TOL32, atol=0)
    assert compute_filter_3d(torch.zeros(0, 3), [cam]).shape == (0,)
    with pytest.raises(GofError, match="none of the"):
        compute_filter_3d(torch.tensor([[0.0, 0.0, -1.0]]), [cam])
    with pytest.raises(GofError, match="camera"):
        compute_filter_3d(torch.zeros(2, 3), [])
    with pytest.raises(GofError, match="means"):
        compute_filter_3d(torch.zeros(2, 2), [cam])


def test_warp_kernel_matches_float64_reference():
    """float32 centres take the Warp kernel; it agrees with the float64 torch path up to float32 rounding,
    including which cameras see which centre (points placed away from the guard band's edges and the near
    plane, where one rounding could flip the test)."""
    rng = np.random.default_rng(1)
    cams = [look_at(rng.normal(size=3) * 4, rng.normal(size=3) * 0.3, fx=float(rng.uniform(80, 200)),
                    cx=float(rng.uniform(20, 44)), width=64, height=48) for _ in range(7)]
    pts = (rng.normal(size=(2000, 3)) * 2.5).astype(np.float32)
    p64 = torch.tensor(pts, dtype=torch.float64)
    margin_ok = np.ones(len(pts), bool)  # centres at least 1e-3 px / 1e-4 depth away from every decision edge
    for cam in cams:
        x = p64.numpy() @ cam.R.T + cam.t
        z = x[:, 2]
        u, v = cam.fx * x[:, 0] / z + cam.cx, cam.fy * x[:, 1] / z + cam.cy
        for val, lim in ((u, cam.width), (v, cam.height)):
            margin_ok &= (np.abs(val + 0.15 * lim) > 1e-3) & (np.abs(val - 1.15 * lim) > 1e-3)
        margin_ok &= np.abs(z - 0.2) > 1e-4
    ref_depth = nearest_seen_depth_torch(p64, cams).numpy()
    got_depth = compute_filter_3d(torch.tensor(pts), cams).numpy() * max(c.fx for c in cams) / SQRT02
    seen = np.isfinite(ref_depth)
    assert margin_ok.mean() > 0.99 and 0.2 < seen.mean() < 1.0  # seen and unseen centres both present
    np.testing.assert_allclose(got_depth[margin_ok & seen], ref_depth[margin_ok & seen], rtol=TOL32)
    fill = ref_depth[seen].max()  # unseen centres take the largest seen depth
    np.testing.assert_allclose(got_depth[~seen & margin_ok], fill, rtol=TOL32)
    assert compute_filter_3d(torch.tensor(pts), cams).dtype == torch.float32
