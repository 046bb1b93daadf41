"""Camera conventions: projection, pixel rays, OpenGL→OpenCV conversion, resizing, validation."""

import numpy as np
import pytest

from gof_warp.core.camera import Camera, camera_extent, look_at
from gof_warp.core.errors import SceneError


def test_look_at_projects_target_to_principal_point_with_z_depth():
    cam = look_at([3.0, -2.0, 1.0], [0.0, 0.0, 0.0], fx=400, fy=380, cx=150.3, cy=90.7, width=320, height=200)
    uv, z = cam.project(np.zeros((1, 3)))
    np.testing.assert_allclose(uv[0], [150.3, 90.7], atol=1e-9)
    np.testing.assert_allclose(z[0], np.sqrt(14.0), rtol=1e-12)
    # World "up" (+z) appears upward in the image: smaller row coordinate (OpenCV y down).
    uv_up, _ = cam.project(np.array([[0.0, 0.0, 0.5]]))
    assert uv_up[0, 1] < 90.7


def test_pixel_rays_hit_pixel_centres():
    cam = look_at([0.0, -4.0, 0.5], [0.1, 0.0, 0.0], fx=55, fy=60, cx=13.0, cy=9.5, width=31, height=17)
    o, d = cam.pixel_rays()
    pts = o + 2.5 * d  # depth 2.5 along every ray
    uv, z = cam.project(pts.reshape(-1, 3))
    np.testing.assert_allclose(z, 2.5, rtol=1e-12)
    jj, ii = np.mgrid[0:17, 0:31]
    np.testing.assert_allclose(uv[:, 0], ii.ravel() + 0.5, atol=1e-9)
    np.testing.assert_allclose(uv[:, 1], jj.ravel() + 0.5, atol=1e-9)


def test_from_c2w_opengl_flips_y_and_z():
    cam = look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    c2w_gl = cam.c2w.copy()
    c2w_gl[:3, 1:3] *= -1
    back = Camera.from_c2w(c2w_gl, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, opengl=True)
    np.testing.assert_allclose(back.R, cam.R, atol=1e-12)
    np.testing.assert_allclose(back.t, cam.t, atol=1e-12)
    np.testing.assert_allclose(back.center, [1, 2, 3], atol=1e-12)


def test_scaled_camera_keeps_pixel_geometry():
    cam = look_at([0.0, -3.0, 0.0], [0.0, 0.0, 0.0], fx=300, cx=170.2, cy=101.9, width=333, height=211)
    half = cam.scaled(0.5)
    assert (half.width, half.height) == (166, 106)
    p = np.array([[0.3, 0.1, -0.2]])
    uv, _ = cam.project(p)
    uv2, _ = half.project(p)
    np.testing.assert_allclose(uv2[0], uv[0] * [166 / 333, 106 / 211], rtol=1e-12)


def test_invalid_cameras_raise():
    with pytest.raises(SceneError, match="not a rotation"):
        Camera(R=np.diag([1.0, 1.0, 2.0]), t=np.zeros(3), fx=1, fy=1, cx=0, cy=0, width=2, height=2)
    with pytest.raises(SceneError, match="focal"):
        Camera(R=np.eye(3), t=np.zeros(3), fx=-1, fy=1, cx=0, cy=0, width=2, height=2)
    with pytest.raises(SceneError, match="NaN"):
        Camera(R=np.eye(3), t=np.array([0, np.nan, 0]), fx=1, fy=1, cx=0, cy=0, width=2, height=2)
    with pytest.raises(SceneError, match="size"):
        Camera(R=np.eye(3), t=np.zeros(3), fx=1, fy=1, cx=0, cy=0, width=0, height=2)


def test_camera_extent_is_3dgs_radius():
    cams = [look_at(e, [0, 0, 0]) for e in ([2.0, 0, 0], [-2.0, 0, 0], [0, 1.0, 0])]
    centres = np.array([[2.0, 0, 0], [-2.0, 0, 0], [0, 1.0, 0]])
    expected = 1.1 * np.linalg.norm(centres - centres.mean(0), axis=1).max()
    assert camera_extent(cams) == pytest.approx(expected)
    with pytest.raises(SceneError):
        camera_extent([])


def test_dict_round_trip_and_incomplete_record():
    cam = look_at([1.0, -2.0, 0.5], [0, 0, 0], fx=321.5, fy=300.25, cx=40.3, cy=30.1, width=81, height=59, name="v7")
    back = Camera.from_dict(cam.to_dict())
    np.testing.assert_array_equal(back.R, cam.R)
    np.testing.assert_array_equal(back.t, cam.t)
    assert (back.fx, back.fy, back.cx, back.cy, back.width, back.height, back.name) == (321.5, 300.25, 40.3, 30.1, 81, 59, "v7")
    with pytest.raises(SceneError, match="incomplete"):
        Camera.from_dict({"name": "x", "R": np.eye(3).tolist()})


def test_intrinsics_are_declared_once_for_pinhole_and_lens_cameras():
    import dataclasses

    from gof_warp.core.camera import Intrinsics
    from gof_warp.data.undistort import LensCamera

    names = ["fx", "fy", "cx", "cy", "width", "height"]
    assert [f.name for f in dataclasses.fields(Intrinsics)] == names
    for cls in (Camera, LensCamera):  # the fields come from Intrinsics, not a second declaration
        assert issubclass(cls, Intrinsics)
        assert not set(names) & set(cls.__dict__.get("__annotations__", {})), cls
    cam = look_at([0.0, -3.0, 0.0], [0.0, 0.0, 0.0], fx=300, fy=310, cx=170.2, cy=101.9, width=333, height=211)
    lens = LensCamera(**dataclasses.asdict(cam.intrinsics), k1=0.1, model="RADIAL")
    assert lens.intrinsics == cam.intrinsics and lens.intrinsics != lens  # value comparison, distortion dropped
    np.testing.assert_array_equal(lens.K, cam.K)
    assert cam.pinhole == lens.pinhole == (300.0, 310.0, 170.2, 101.9)
    half, lens_half = cam.scaled(0.5), lens.scaled(166, 106)  # one resizing rule for both
    assert lens_half.intrinsics == half.intrinsics and lens_half.k1 == 0.1 and lens_half.model == "RADIAL"
    np.testing.assert_array_equal(half.R, cam.R)


def test_lens_cameras_validate_like_cameras_and_cameras_compare_by_identity():
    from gof_warp.data.undistort import LensCamera

    with pytest.raises(SceneError, match=r"lens camera \(OPENCV\): focal lengths must be positive"):
        LensCamera(fx=0.0, fy=1.0, cx=0.0, cy=0.0, width=2, height=2)
    with pytest.raises(SceneError, match="lens camera .*: image size must be positive"):
        LensCamera(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=2, height=-1)
    with pytest.raises(SceneError, match="distortion k2 is not finite"):
        LensCamera(fx=1.0, fy=1.0, cx=0.0, cy=0.0, width=2, height=2, k2=float("nan"))
    a, b = look_at([1.0, 0, 0], [0, 0, 0]), look_at([1.0, 0, 0], [0, 0, 0])
    assert a != b and a == a and len({a, b}) == 2  # views with equal poses stay distinct


def test_project_tensor_matches_project_in_float64_and_stays_finite_behind_the_camera():
    import torch

    cam = look_at(np.array([1.0, -3.0, 0.5]), np.zeros(3), fx=50.0, width=64, height=48)
    pts = np.random.default_rng(1).uniform(-4, 4, (300, 3))
    uv, z = cam.project(pts)
    u, v, zt = cam.project_tensor(torch.tensor(pts, dtype=torch.float64))
    front = z > 0
    assert 0 < front.sum() < len(pts)  # points on both sides of the camera
    assert np.allclose(zt.numpy(), z, atol=1e-12)
    assert np.allclose(u.numpy()[front], uv[front, 0], atol=1e-9) and np.allclose(v.numpy()[front], uv[front, 1], atol=1e-9)
    assert torch.isfinite(u).all() and torch.isfinite(v).all()
    u32, _, _ = cam.project_tensor(torch.tensor(pts, dtype=torch.float32))
    assert u32.dtype == torch.float32
    assert np.allclose(cam.to_camera_tensor(torch.tensor(pts, dtype=torch.float64)).numpy(), cam.to_camera(pts),
                       atol=1e-12)  # the torch twin of to_camera
    *_, inside = cam.in_image_tensor(torch.tensor(pts, dtype=torch.float64))  # the torch twin of in_image
    expected = cam.in_image(pts)[2]
    assert 0 < expected.sum() < front.sum() and np.array_equal(inside.numpy(), expected)
