"""Scene readers on tiny folders written by the tests: every format, undistortion, options, bad input."""

from __future__ import annotations

import json
import os

import numpy as np
import pycolmap
import pytest
from _scene_fixtures import (
    SCALE_RADIUS,
    H,
    W,
    make_blender_scene,
    make_colmap_scene,
    make_dtu_scene,
    make_ingp_scene,
    random_image,
    ring_cameras,
    save_image,
)
from PIL import Image
from scipy.ndimage import map_coordinates

from gof_warp.data import DataConfig, detect_format, load_scene, read_plan
from gof_warp.data.colmap import lens_from_colmap
from gof_warp.data.undistort import (
    LensCamera,
    distort_normalized,
    undistort_image,
    undistort_normalized,
    undistort_pixels,
    undistorted_intrinsics,
)
from gof_warp.core.errors import GofError, SceneError
from gof_warp.cli.inspect_scene import main as inspect_main

POSE_ATOL = 1e-9  # poses go through text files with 17 significant digits
REPROJ_ATOL_PX = 1e-6  # float64 Newton inversion converges to ~1e-12 normalised units
KERNEL_ATOL = 1  # uint8 outputs: float32 kernel vs float64 reference may round to neighbouring levels
EDGE_MARGIN_PX = 1e-3  # float32 vs float64 may disagree about rays this close to the image border

LENSES = {  # COLMAP model → parameters (fx/f, [fy], cx, cy, distortion…) for a 48x36 image
    "SIMPLE_RADIAL": [40.0, 23.5, 17.0, 0.12],
    "RADIAL": [40.0, 23.5, 17.0, -0.1, 0.03],
    "OPENCV": [40.0, 42.0, 24.5, 18.5, 0.1, -0.05, 0.002, -0.003],
    "FULL_OPENCV": [40.0, 42.0, 24.5, 18.5, -0.08, 0.02, 0.001, 0.002, 0.01, 0.0, 0.0, 0.0],
}


def _cfg(**kw):
    return DataConfig(**kw)


def _load(path, **kw):
    return load_scene(path, _cfg(**kw), device="cpu")


def _assert_same_pose(a, b):
    np.testing.assert_allclose(a.R, b.R, atol=POSE_ATOL)
    np.testing.assert_allclose(a.t, b.t, atol=POSE_ATOL)


# --------------------------------------------------------------------------------------------- detection
def test_detect_format_each_layout_and_unknown(tmp_path):
    assert detect_format(make_colmap_scene(tmp_path / "c")) == "colmap"
    assert detect_format(make_blender_scene(tmp_path / "b")) == "blender"
    assert detect_format(make_ingp_scene(tmp_path / "i")) == "ingp"
    assert detect_format(make_dtu_scene(tmp_path / "d")[0]) == "dtu"
    assert detect_format(tmp_path / "i" / "transforms.json") == "ingp"  # a file inside the folder
    (tmp_path / "empty").mkdir()
    with pytest.raises(SceneError, match="empty: no known scene format"):
        detect_format(tmp_path / "empty")
    with pytest.raises(SceneError, match="missing: scene folder does not exist"):
        load_scene(tmp_path / "missing")


# ------------------------------------------------------------------------------------------------ COLMAP
@pytest.mark.parametrize("binary", [False, True])
def test_colmap_pinhole_text_and_binary(tmp_path, binary):
    root = make_colmap_scene(tmp_path / "s", n=10, binary=binary)
    scene = _load(root, test_every=8)
    truth = {c.name: c for c in ring_cameras(10)}
    views = scene.all_views
    assert [v.name for v in scene.test] == ["0000", "0008"]  # name-sorted, index % 8 == 0
    assert len(scene.train) == 8 and scene.format == "colmap" and scene.camera_models == ["PINHOLE"]
    for v in views:
        _assert_same_pose(v.camera, truth[v.name])
        assert (v.camera.fx, v.camera.cx) == (truth[v.name].fx, truth[v.name].cx)
        np.testing.assert_array_equal(v.image, random_image(seed=int(v.name)))
    assert scene.points.shape == (50, 3) and scene.point_colors.shape == (50, 3)


@pytest.mark.parametrize("model", list(LENSES))
def test_colmap_distortion_matches_pycolmap_projection(model):
    """Our OpenCV formula with COLMAP's parameter mapping == pycolmap's own camera model."""
    params = LENSES[model]
    lens = lens_from_colmap(model, params, W, H, "test")
    ref = pycolmap.Camera(model=model, width=W, height=H, params=params)
    xy = np.random.default_rng(1).uniform(-0.5, 0.5, (200, 2))
    ours = distort_normalized(xy, lens) * [lens.fx, lens.fy] + [lens.cx, lens.cy]
    np.testing.assert_allclose(ours, ref.img_from_cam(np.hstack([xy, np.ones((200, 1))])), atol=1e-9)
    back = undistort_normalized(distort_normalized(xy, lens), lens)
    np.testing.assert_allclose(back, xy, atol=1e-10)


@pytest.mark.parametrize("model", ["SIMPLE_RADIAL", "OPENCV"])
def test_colmap_distorted_model_observations_reproject(tmp_path, model):
    """Observed (distorted) pixels, undistorted, coincide with the projection by the scene's pinhole camera."""
    root = make_colmap_scene(tmp_path / "s", model=model, params=LENSES[model], binary=True)
    plan = read_plan(root, _cfg())
    rec = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    for im in rec.images.values():
        view = next(v for v in plan.views if v.name == im.name[:-4])
        cam = view.camera
        assert view.lens is not None and view.lens.model == model
        obs = [(p.xy, rec.points3D[p.point3D_id].xyz) for p in im.points2D if p.has_point3D()]
        uv = undistort_pixels(np.array([o[0] for o in obs]), view.lens, cam.fx, cam.fy, cam.cx, cam.cy)
        np.testing.assert_allclose(cam.project(np.array([o[1] for o in obs]))[0], uv, atol=REPROJ_ATOL_PX)


def test_colmap_unsupported_model_names_file_and_model(tmp_path):
    root = make_colmap_scene(tmp_path / "s", n=3)
    cams = root / "sparse" / "0" / "cameras.txt"
    cams.write_text(cams.read_text().replace("PINHOLE 48 36 40 42 24 18", "OPENCV_FISHEYE 48 36 40 42 24 18 0.1 0 0 0"))
    with pytest.raises(SceneError, match=r"cameras.txt \(camera 1\): unsupported camera model OPENCV_FISHEYE"):
        _load(root)


def test_colmap_images_stored_at_half_resolution_get_scaled_cameras(tmp_path):
    root = make_colmap_scene(tmp_path / "s", n=3, images="images_2", model="SIMPLE_RADIAL", params=LENSES["SIMPLE_RADIAL"])
    for p in (root / "images_2").iterdir():
        save_image(p, random_image(H // 2, W // 2))
    scene = _load(root, images="images_2", test_every=0)
    full = read_plan(root, _cfg(images="images_2")).views[0].camera
    cam = scene.train[0].camera
    assert (cam.width, cam.height) == (W // 2, H // 2)
    np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], np.array([full.fx, full.fy, full.cx, full.cy]) / 2)
    assert any("intrinsics scaled" in w for w in scene.warnings)
    save_image(root / "images_2" / "0001.png", random_image(H // 2, W // 3))  # other aspect ratio
    with pytest.raises(SceneError, match="0001.png: image is 16x18 but its camera is 48x36"):
        _load(root, images="images_2")


def test_colmap_warns_about_cameras_seeing_no_points(tmp_path):
    root = make_colmap_scene(tmp_path / "s", n=3)
    images = root / "sparse" / "0" / "images.txt"
    lines = images.read_text().splitlines()
    head = lines[0].split()
    lines[0] = " ".join(head[:5] + ["0", "0", "-9"] + head[8:])  # camera 1 moved behind all points, looking away
    images.write_text("\n".join(lines) + "\n")
    scene = _load(root)
    assert any("1 camera(s) see none of the 50 initial points: 0000" in w for w in scene.warnings)


# --------------------------------------------------------------------------------------------- Blender
def test_blender_alpha_composited_on_background_and_kept_as_mask(tmp_path):
    root = make_blender_scene(tmp_path / "s")
    scene = _load(root, background=(1.0, 1.0, 1.0))
    assert (len(scene.train), len(scene.test)) == (6, 2) and scene.points is None
    rgba = np.asarray(Image.open(root / "train" / "r_3.png"))
    a = rgba[..., 3:4] / 255.0
    expect = np.rint(rgba[..., :3] * a + 255.0 * (1 - a))
    view = scene.train[3]
    np.testing.assert_array_equal(view.image, expect.astype(np.uint8))
    np.testing.assert_array_equal(view.mask, rgba[..., 3])
    fx = 0.5 * W / np.tan(0.5)
    assert view.camera.fx == pytest.approx(fx) and view.camera.fy == pytest.approx(fx)
    assert (view.camera.cx, view.camera.cy) == (W / 2, H / 2)
    _assert_same_pose(view.camera, ring_cameras(8, fx=fx, fy=fx)[3])
    merged = _load(root, test_every=0)
    assert (len(merged.train), len(merged.test)) == (8, 0)


def test_blender_explicit_intrinsics_and_points_ply(tmp_path):
    import trimesh

    top = {"fl_x": 30.0, "fl_y": 31.0, "cx": 20.5, "cy": 15.25, "w": W, "h": H}
    root = make_blender_scene(tmp_path / "s", top=top)
    pts = np.random.default_rng(3).uniform(-0.3, 0.3, (20, 3))
    trimesh.PointCloud(pts, colors=np.full((20, 4), 200, np.uint8)).export(root / "points3d.ply")
    scene = _load(root)
    cam = scene.test[0].camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (30.0, 31.0, 20.5, 15.25)
    np.testing.assert_allclose(scene.points, pts, atol=1e-6)
    assert scene.point_colors[0].tolist() == [200, 200, 200]


# ------------------------------------------------------------------------------------------- instant-ngp
def test_ingp_distortion_undistorted_and_sorted(tmp_path):
    dist = {"k1": 0.1, "k2": -0.02, "p1": 0.001, "p2": -0.002}
    root = make_ingp_scene(tmp_path / "s", dist=dist)
    scene = _load(root, test_every=4)
    assert scene.camera_models == ["OPENCV"]
    assert [v.name for v in scene.test] == ["0000", "0004", "0008"]  # sorted although the file is reversed
    truth = {c.name: c for c in ring_cameras(9, fx=40.0, fy=41.0, cx=23.1, cy=18.7)}
    lens = LensCamera(fx=40.0, fy=41.0, cx=23.1, cy=18.7, width=W, height=H, **dist)
    fx, fy, cx, cy = undistorted_intrinsics(lens, "valid")
    assert fx > 40.0  # k1 > 0: zoomed in so that no pixel is blank
    for v in scene.all_views:
        _assert_same_pose(v.camera, truth[v.name])
        assert (v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy) == (fx, fy, cx, cy)
    same = _load(root, undistort="same")
    assert same.train[0].camera.fx == 40.0


def test_ingp_camera_angle_fallback_and_unsupported_fisheye(tmp_path):
    root = make_ingp_scene(tmp_path / "s", n=2)
    path = root / "transforms.json"
    data = json.loads(path.read_text())
    for k in ("fl_x", "fl_y", "cx", "cy", "w", "h"):
        data.pop(k)
    data["camera_angle_x"] = 1.2
    path.write_text(json.dumps(data))
    cam = _load(root).train[0].camera
    assert cam.fx == pytest.approx(0.5 * W / np.tan(0.6)) and cam.fy == cam.fx and cam.cx == W / 2
    data["camera_model"] = "OPENCV_FISHEYE"
    path.write_text(json.dumps(data))
    with pytest.raises(SceneError, match="transforms.json frame 0: unsupported camera model 'OPENCV_FISHEYE'"):
        _load(root)
    path.write_text("{ not json")
    with pytest.raises(SceneError, match="transforms.json: invalid JSON at line 1"):
        _load(root)


def test_per_frame_overrides_mask_path_and_scene_warnings(tmp_path):
    root = make_ingp_scene(tmp_path / "s", n=3)
    path = root / "transforms.json"
    data = json.loads(path.read_text())
    frame = next(f for f in data["frames"] if f["file_path"] == "images/0001.jpg")
    frame.update({"w": 30, "h": 20, "fl_x": 25.0, "fl_y": 25.0, "cx": 15.0, "cy": 10.0, "mask_path": "masks/0001"})
    save_image(root / "images" / "0001.jpg", random_image(20, 30))
    mask = np.zeros((20, 30), np.uint8)
    mask[5:15, 5:25] = 255
    save_image(root / "masks" / "0001.png", mask)
    path.write_text(json.dumps(data))
    scene = _load(root, test_every=0)
    v = scene.train[1]
    assert (v.camera.width, v.camera.fx) == (30, 25.0) and scene.train[0].camera.width == W
    np.testing.assert_array_equal(v.mask, mask)
    assert scene.train[0].mask is None
    assert any("2 different sizes" in w for w in scene.warnings)
    assert any("masks missing for 2 of 3 views" in w for w in scene.warnings)


# --------------------------------------------------------------------------------------------------- DTU
def test_dtu_decomposition_gives_unit_sphere_cameras_and_binary_masks(tmp_path):
    root, truth = make_dtu_scene(tmp_path / "s", n=5, negate=(1, 3))
    scene = _load(root, test_every=0)
    assert scene.format == "dtu" and len(scene.train) == 5
    for v, c in zip(scene.train, truth):
        _assert_same_pose(v.camera, c)
        np.testing.assert_allclose([v.camera.fx, v.camera.fy, v.camera.cx, v.camera.cy], [c.fx, c.fy, c.cx, c.cy], atol=1e-9)
        assert set(np.unique(v.mask)) == {0, 255} and v.mask[0, 0] == 0 and v.mask[H // 2, W // 2] == 255
    assert np.linalg.norm(scene.train[0].camera.center) == pytest.approx(np.sqrt(10.0))
    assert SCALE_RADIUS != 1.0  # the scale matrix was really applied


def test_dtu_count_mismatches_name_the_files(tmp_path):
    root, _ = make_dtu_scene(tmp_path / "s", n=4)
    os.remove(root / "mask" / "002.png")
    with pytest.raises(SceneError, match=r"cameras_sphere.npz has 4 cameras but .*mask has 3 masks"):
        _load(root)
    os.remove(root / "image" / "000003.png")
    with pytest.raises(SceneError, match=r"cameras_sphere.npz has 4 cameras but .*image has 3 images"):
        _load(root)


# --------------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("damage", ["missing", "truncated", "not_an_image"])
def test_bad_images_name_the_file_and_nothing_is_written(tmp_path, damage):
    root = make_colmap_scene(tmp_path / "s", n=4)
    target = root / "images" / "0002.png"
    if damage == "missing":
        os.remove(target)
    elif damage == "truncated":
        target.write_bytes(target.read_bytes()[: len(target.read_bytes()) // 2])
    else:
        target.write_text("hello")
    before = sorted(p for p in tmp_path.rglob("*"))
    expect = {"missing": "image file not found", "truncated": "truncated or corrupt", "not_an_image": "not a readable image"}
    with pytest.raises(SceneError, match=f"0002.png: .*{expect[damage]}"):
        _load(root)
    assert sorted(p for p in tmp_path.rglob("*")) == before


def test_blender_missing_frame_image_and_corrupt_colmap_model(tmp_path):
    root = make_blender_scene(tmp_path / "b")
    os.remove(root / "test" / "r_1.png")
    with pytest.raises(SceneError, match=r"r_1: image file not found \(frame 1 of .*transforms_test.json\)"):
        _load(root)
    croot = make_colmap_scene(tmp_path / "c", n=3)
    (croot / "sparse" / "0" / "points3D.txt").write_text("garbage\n")
    with pytest.raises(SceneError, match=r"sparse/0/points3D.txt: cannot parse a 3D point from line 'garbage'"):
        _load(croot)


def test_config_validation():
    for bad in (dict(downscale=0.5), dict(test_every=-1), dict(background=(2, 0, 0)), dict(undistort="crop")):
        with pytest.raises(GofError, match=r"data\.(downscale|test_every|background|undistort)"):
            DataConfig(**bad)


# -------------------------------------------------------------------------------- downscale and memory
def test_downscale_resizes_bicubic_and_scales_intrinsics(tmp_path):
    root = make_ingp_scene(tmp_path / "s", n=2, size=(60, 40))
    scene = _load(root, downscale=3, test_every=0)
    v = scene.train[0]
    assert (v.camera.width, v.camera.height) == (20, 13)  # round(60/3), round(40/3)
    assert v.camera.fx == pytest.approx(40.0 * 20 / 60) and v.camera.cy == pytest.approx(18.7 * 13 / 40)
    src = Image.open(root / "images" / "0000.jpg").convert("RGB")
    np.testing.assert_array_equal(v.image, np.asarray(src.resize((20, 13), Image.Resampling.BICUBIC)))


def test_memory_budget_refuses_and_suggests_a_downscale_that_fits(tmp_path):
    root = make_colmap_scene(tmp_path / "s", n=10)
    need = 10 * W * H * 3
    budget_gb = need / 4.5 / 1e9
    with pytest.raises(SceneError, match=r"over the image memory budget .* use downscale >= (\d+(\.\d)?)") as err:
        _load(root, image_memory_budget_gb=budget_gb)
    fit = float(err.value.args[0].rsplit(">= ", 1)[1].split()[0])
    assert 2.1 <= fit <= 2.6
    scene = _load(root, downscale=fit, image_memory_budget_gb=budget_gb)
    assert scene.image_bytes() <= budget_gb * 1e9


# ------------------------------------------------------------------------------------------ undistortion
def _reference_remap(image, lens, K, background):
    """float64 brute force: pycolmap distorts each output ray; scipy samples bilinearly (edges clamped)."""
    h, w = image.shape[:2]
    jj, ii = np.mgrid[0:h, 0:w]
    rays = np.stack([(ii + 0.5 - K[2]) / K[0], (jj + 0.5 - K[3]) / K[1], np.ones_like(ii, float)], -1).reshape(-1, 3)
    params = [lens.fx, lens.fy, lens.cx, lens.cy, lens.k1, lens.k2, lens.p1, lens.p2, lens.k3, 0, 0, 0]
    uv = pycolmap.Camera(model="FULL_OPENCV", width=w, height=h, params=params).img_from_cam(rays)
    img = image.reshape(h, w, -1).astype(np.float64)
    at = [uv[:, 1] - 0.5, uv[:, 0] - 0.5]  # index space
    out = np.stack([map_coordinates(img[..., c], at, order=1, mode="nearest") for c in range(img.shape[2])], -1)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] <= w) & (uv[:, 1] >= 0) & (uv[:, 1] <= h)
    out[~inside] = np.asarray(background, float) * 255.0
    edge_dist = np.minimum.reduce([np.abs(uv[:, 0]), np.abs(uv[:, 0] - w), np.abs(uv[:, 1]), np.abs(uv[:, 1] - h)])
    near_edge = edge_dist < EDGE_MARGIN_PX
    return out.reshape(image.shape), near_edge.reshape(h, w), inside.reshape(h, w)


@pytest.mark.parametrize("channels", [1, 3, 4])
def test_undistort_kernel_matches_float64_reference(channels, device):
    lens = LensCamera(fx=40.0, fy=42.0, cx=24.5, cy=17.5, width=W, height=H, k1=0.15, k2=-0.03, p1=0.004, p2=-0.003, k3=0.01)
    K = undistorted_intrinsics(lens, "same")
    image = random_image(channels=channels, seed=7)
    image = image[..., 0] if channels == 1 else image
    bg = 0.0 if channels == 1 else [0.2, 0.4, 0.6, 1.0][:channels]
    ours = undistort_image(image, lens, *K, background=bg, device=device)
    ref, near_edge, inside = _reference_remap(image, lens, K, bg)
    assert ours.shape == image.shape and ours.dtype == np.uint8
    assert (~inside).sum() > 10  # k1 > 0 with the file's K: some corners really are blank
    diff = np.abs(ours.astype(np.int32) - np.rint(ref).astype(np.int32))
    assert diff[~near_edge].max() <= KERNEL_ATOL


def test_undistortion_recovers_a_pinhole_image_of_an_analytic_pattern():
    """Distort a smooth pattern defined on pinhole rays; undistorting must give the pinhole image back."""
    lens = LensCamera(fx=80.0, fy=80.0, cx=48.0, cy=36.0, width=96, height=72, k1=-0.2, k2=0.05, p1=0.002)

    def pattern(xy):  # smooth function of the undistorted normalised coordinates, in [0, 255]
        return 127.5 + 120 * np.sin(5 * xy[:, 0]) * np.cos(4 * xy[:, 1])

    jj, ii = np.mgrid[0:72, 0:96]
    pix = np.stack([ii.ravel() + 0.5, jj.ravel() + 0.5], 1)
    xy_d = (pix - [48.0, 36.0]) / 80.0
    distorted = pattern(undistort_normalized(xy_d, lens)).reshape(72, 96)
    K = undistorted_intrinsics(lens, "valid")
    out = undistort_image(np.rint(distorted).astype(np.uint8), lens, *K, device="cpu")
    expect = pattern((pix - [K[2], K[3]]) / [K[0], K[1]]).reshape(72, 96)
    err = np.abs(out.astype(float) - expect)
    assert np.median(err) < 2.0 and err.max() < 12.0  # bilinear resampling of a 5-10 px period pattern


@pytest.mark.parametrize("k1", [0.2, -0.2])
def test_valid_mode_leaves_no_blank_pixels(k1, device):
    lens = LensCamera(fx=40.0, fy=42.0, cx=22.0, cy=19.0, width=W, height=H, k1=k1, p2=0.003)
    fx, fy, cx, cy = undistorted_intrinsics(lens, "valid")
    ones = np.full((H, W), 255, np.uint8)
    out = undistort_image(ones, lens, fx, fy, cx, cy, background=0.0, device=device)
    assert out.min() == 255  # every output ray found data
    assert (fx > lens.fx) == (k1 > 0)
    looser = undistort_image(ones, lens, fx * 0.97, fy * 0.97, cx, cy, background=0.0, device=device)
    assert looser.min() == 0  # and the zoom is tight: 3 % less leaves blank pixels


# ------------------------------------------------------------------------------------------------ inspect
def test_inspect_cli_prints_summary_and_clean_errors(tmp_path, capsys):
    root = make_dtu_scene(tmp_path / "d", n=9)[0]
    assert inspect_main([str(root), "--test-every", "3"]) == 0
    out = capsys.readouterr().out
    assert "format:         dtu" in out and "9 (6 train, 3 test)" in out and "masks:          9" in out
    assert inspect_main([str(root), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["train_views"] == 7
    assert inspect_main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "no known scene format" in err and "Traceback" not in err
