"""The readers on the real scenes in ../shared/data (skipped when that folder is absent).

Each scene is loaded once per module, downscaled to keep decoding fast; geometric checks run on the
cameras at full resolution (``read_plan``, no decoding) where they need pixel accuracy.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from gof_warp.data import DataConfig, load_scene, read_plan
from gof_warp.data.undistort import undistort_pixels
from gof_warp.cli.inspect_scene import main as inspect_main

pytestmark = [pytest.mark.realdata, pytest.mark.slow]  # slow: each scene decoded once per module

COLMAP_REPROJ_MEAN_PX = 1.0  # COLMAP reports 0.75 px mean for this model; undistortion zooms by ~3 %
COLMAP_REPROJ_MEDIAN_PX = 0.8
COLOUR_GAIN = 0.75  # colour error at the projected pixel must be well below that at a 12 px offset
MIC_AXIS_TO_ORIGIN = 1e-3  # NeRF-synthetic cameras aim exactly at the origin (file rounding only)


def _scene(shared_data, name, **cfg):
    return load_scene(shared_data / name, DataConfig(**cfg), device="cpu")


@pytest.fixture(scope="module")
def can(shared_data):
    return _scene(shared_data, "colmap_can", downscale=4, test_every=0)


def _principal_axis_distance(cam, point):
    d = cam.R[2]  # viewing direction (camera z) in world space
    w = point - cam.center
    return np.linalg.norm(w - (w @ d) * d)


# ------------------------------------------------------------------------------------------- colmap_can
def test_colmap_can_observations_reproject(shared_data):
    root = shared_data / "colmap_can"
    plan = read_plan(root, DataConfig())
    assert plan.format == "colmap" and len(plan.views) == 71 and plan.camera_models == ["SIMPLE_RADIAL"]
    import pycolmap  # an independent reader of the same files, with the observations

    rec = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    by_name = {v.name: v for v in plan.views}
    errors, raw = [], []
    for im in list(rec.images.values())[::5]:
        v = by_name[Path(im.name).stem]
        obs = [(p.xy, rec.points3D[p.point3D_id].xyz) for p in im.points2D if p.has_point3D()]
        uv = np.array([o[0] for o in obs])
        proj = v.camera.project(np.array([o[1] for o in obs]))[0]
        und = undistort_pixels(uv, v.lens, v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy)
        errors.append(np.linalg.norm(proj - und, axis=1))
        raw.append(np.linalg.norm(proj - uv, axis=1))
    e = np.concatenate(errors)
    assert e.mean() < COLMAP_REPROJ_MEAN_PX and np.median(e) < COLMAP_REPROJ_MEDIAN_PX
    assert np.concatenate(raw).mean() > 2 * e.mean()  # the distortion is real and was removed


def test_colmap_can_points_land_on_their_colours(can):
    assert can.points.shape == (4414, 3) and len(can.train) == 71
    assert can.train[0].camera.width == 180 and can.train[0].camera.height == 320
    hit, off = [], []
    for v in can.train[::3]:
        uv, z = v.camera.project(can.points)
        ok = (z > 0) & (uv[:, 0] >= 13) & (uv[:, 0] < v.camera.width - 13) & (uv[:, 1] >= 13) & (uv[:, 1] < v.camera.height - 13)
        i = np.floor(uv[ok]).astype(int)
        c = can.point_colors[ok].astype(float)
        hit.append(np.abs(v.image[i[:, 1], i[:, 0]] - c).mean(1))
        off.append(np.abs(v.image[i[:, 1] + 12, i[:, 0] + 12] - c).mean(1))
    assert np.concatenate(hit).mean() < COLOUR_GAIN * np.concatenate(off).mean()


def test_colmap_can_inspect(shared_data, capsys):
    assert inspect_main([str(shared_data / "colmap_can"), "--downscale", "8"]) == 0
    out = capsys.readouterr().out
    assert "format:         colmap" in out and "views:          71 (62 train, 9 test)" in out
    assert "SIMPLE_RADIAL (undistorted to PINHOLE)" in out and "initial points: 4414" in out


# ------------------------------------------------------------------------------------------- dtu_scan24
def test_dtu_scan24_object_inside_every_mask(shared_data):
    scene = _scene(shared_data, "dtu_scan24", test_every=0)
    assert scene.format == "dtu" and len(scene.train) == 49
    assert scene.summary()["resolutions"] == ["800x600"] and scene.summary()["masks"] == 49
    for v in scene.train:
        uv, z = v.camera.project(np.zeros((1, 3)))
        assert z[0] > 0 and v.mask[int(uv[0, 1]), int(uv[0, 0])] == 255, v.name
        assert np.linalg.norm(v.camera.center) > 1.0  # outside the unit sphere
        assert 0.05 < (v.mask > 0).mean() < 0.9


# --------------------------------------------------------------------------------------------- nerf_mic
def test_nerf_mic_splits_alpha_and_cameras_aim_at_origin(shared_data):
    scene = _scene(shared_data, "nerf_mic", background=(1.0, 1.0, 1.0))
    assert (len(scene.train), len(scene.test)) == (100, 5) and scene.format == "blender"
    assert scene.summary()["resolutions"] == ["400x400"] and scene.points is None
    v = scene.train[0]
    assert v.mask is not None and 0 < (v.mask == 255).mean() < 0.5  # alpha kept as the mask
    assert np.all(v.image[v.mask == 0] == 255)  # transparent pixels composited on white
    for cam in scene.train_cameras + scene.test_cameras:
        assert _principal_axis_distance(cam, np.zeros(3)) < MIC_AXIS_TO_ORIGIN


# -------------------------------------------------------------------------------------------------- fox
def test_fox_undistorted_cameras_share_a_focus(shared_data):
    scene = _scene(shared_data, "fox", downscale=4)
    assert len(scene.all_views) == 67 and scene.camera_models == ["OPENCV"]
    plan = read_plan(shared_data / "fox", DataConfig())
    cams = [v.camera for v in plan.views]
    assert all(v.lens is not None and v.lens.k1 != 0 for v in plan.views)
    assert (cams[0].width, cams[0].height) == (540, 960) and cams[0].fx != plan.views[0].lens.fx
    # Least-squares point closest to all principal axes: in front of every camera.
    A = sum(np.eye(3) - np.outer(c.R[2], c.R[2]) for c in cams)
    b = sum((np.eye(3) - np.outer(c.R[2], c.R[2])) @ c.center for c in cams)
    focus = np.linalg.solve(A, b)
    depths = np.array([c.to_camera(focus[None])[0, 2] for c in cams])
    assert depths.min() > 0
    axis = np.array([_principal_axis_distance(c, focus) for c in cams])
    assert np.median(axis / depths) < 0.2  # axes pass within ~11° of the focus
