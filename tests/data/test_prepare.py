"""Camera poses for plain photos (gof_warp.data.prepare): the similarity alignment on exact data, input and
output checks, and structure from motion end to end on a synthetic scene whose true poses are known."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from gof_warp.core.errors import GofError, SceneError
from gof_warp.data import DataConfig, detect_format, load_scene
from gof_warp.data.prepare import (PrepareConfig, PrepareError, align_similarity, pose_errors, prepare_scene,
                                   read_scene_poses, rotation_angle_deg)  # fmt: skip


def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _write_photos(folder, n, size=(64, 48)):
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for i in range(n):
        Image.fromarray(rng.integers(0, 255, (size[1], size[0], 3), dtype=np.uint8)).save(folder / f"{i:03d}.png")
    return folder


# --- alignment -----------------------------------------------------------------------------------------------


def test_align_similarity_recovers_an_exact_similarity():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(20, 3))
    R, s, t = _rotation(rng), 2.7, np.array([1.0, -3.0, 0.5])
    dst = s * src @ R.T + t
    s2, R2, t2 = align_similarity(src, dst)
    assert s2 == pytest.approx(s, rel=1e-10)
    np.testing.assert_allclose(R2, R, atol=1e-10)
    np.testing.assert_allclose(t2, t, atol=1e-10)
    assert np.linalg.det(R2) == pytest.approx(1.0)


def test_align_similarity_returns_a_rotation_for_mirrored_points():
    rng = np.random.default_rng(2)
    src = rng.normal(size=(10, 3))
    _, R, _ = align_similarity(src, src * np.array([1, 1, -1]))
    assert np.linalg.det(R) == pytest.approx(1.0)
    with pytest.raises(ValueError):
        align_similarity(src[:2], src[:2])


def test_pose_errors_are_zero_for_poses_in_another_similar_frame():
    rng = np.random.default_rng(3)
    n = 8
    ref_R = np.stack([_rotation(rng) for _ in range(n)])
    ref_C = rng.normal(size=(n, 3)) * 4
    A, s, t = _rotation(rng), 0.3, rng.normal(size=3)  # est world = s A ref world + t
    est_C = s * ref_C @ A.T + t
    est_R = ref_R @ A.T  # a camera's rotation from the other world: R_est = R_ref A^T
    err = pose_errors(est_R, est_C, ref_R, ref_C)
    assert err["max_rotation_deg"] < 1e-5 and err["max_position_pct"] < 1e-8
    assert err["scale"] == pytest.approx(1 / s)
    # a 2-degree twist of one camera shows up as 2 degrees
    twist = np.array([[np.cos(0.0349066), -np.sin(0.0349066), 0], [np.sin(0.0349066), np.cos(0.0349066), 0], [0, 0, 1]])
    est_R[0] = twist @ est_R[0]
    assert pose_errors(est_R, est_C, ref_R, ref_C)["max_rotation_deg"] == pytest.approx(2.0, abs=1e-4)
    assert rotation_angle_deg(np.eye(3)) == pytest.approx(0.0)


# --- input and output checks ---------------------------------------------------------------------------------


def test_bad_inputs_are_clear_errors(tmp_path):
    with pytest.raises(PrepareError, match="does not exist"):
        prepare_scene(tmp_path / "nope", tmp_path / "out")
    (tmp_path / "file.jpg").write_bytes(b"x")
    with pytest.raises(PrepareError, match="not a folder"):
        prepare_scene(tmp_path / "file.jpg", tmp_path / "out")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("hi")
    with pytest.raises(PrepareError, match=r"no images \(looked for files ending in .jpg"):
        prepare_scene(tmp_path / "empty", tmp_path / "out")
    two = _write_photos(tmp_path / "two", 2)
    with pytest.raises(PrepareError, match="2 image.*at least 3"):
        prepare_scene(two, tmp_path / "out")
    assert not (tmp_path / "out").exists()
    with pytest.raises(PrepareError, match="matcher"):
        PrepareConfig(matcher="vocab_tree")
    assert issubclass(PrepareError, GofError)


def test_a_non_empty_output_is_refused_and_left_alone(tmp_path):
    photos = _write_photos(tmp_path / "photos", 3)
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(PrepareError, match="not empty.*--overwrite"):
        prepare_scene(photos, out)
    with pytest.raises(PrepareError, match="not written by prepare"):
        prepare_scene(photos, out, PrepareConfig(overwrite=True))
    assert (out / "keep.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "photos"]  # no staging folder left


def test_noise_photos_fail_cleanly_and_leave_nothing(tmp_path):
    photos = _write_photos(tmp_path / "photos", 3)
    with pytest.raises(PrepareError, match="registered|no reconstruction"):
        prepare_scene(photos, tmp_path / "out", PrepareConfig(num_threads=2))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]


def test_train_on_plain_photos_says_run_prepare(tmp_path):
    photos = _write_photos(tmp_path / "photos", 3)
    with pytest.raises(SceneError, match=r"holds photos but no camera poses: run `gof-warp prepare PHOTOS --out SCENE` first"):
        detect_format(photos)
    (tmp_path / "other").mkdir()
    with pytest.raises(SceneError, match="no known scene format"):
        detect_format(tmp_path / "other")


# --- end to end ----------------------------------------------------------------------------------------------

# 24 training views (+ 8 test views, merged: 32 photos) at 256 px: measured on a 2-core CPU (pycolmap 4.2.1)
# 30/32 registered, median / max rotation error 0.16 / 0.34 deg, position 0.26 / 0.93 % of the spread, 35 s of SfM.
# (16 views at 256 px registered only 20/24: the two photos at the ends of the spiral overlap too few others.)
VIEWS = 24
RESOLUTION = (256, 256)
MIN_REGISTERED = 0.9
MAX_POSITION = 0.02  # of the camera spread (RMS distance of the true centres from their centroid)
MAX_ROTATION_DEG = 2.0


@pytest.mark.slow
def test_prepare_recovers_the_poses_of_a_synthetic_scene(tmp_path):
    from PIL import Image

    from gof_warp.synthetic import make_scene

    truth = load_scene(make_scene("background", tmp_path / "synthetic", views=VIEWS, resolution=RESOLUTION,
                                  device="cpu", supersample=1), DataConfig(test_every=0), device="cpu")
    photos = tmp_path / "photos"
    photos.mkdir()
    true_poses = {}
    for i, v in enumerate(truth.train):
        name = f"{i:03d}.png"
        Image.fromarray(v.image[..., :3]).save(photos / name)
        true_poses[name] = (v.camera.R, -v.camera.R.T @ v.camera.t)
    t0 = time.perf_counter()
    report = prepare_scene(photos, tmp_path / "scene", PrepareConfig(num_threads=2))
    seconds = time.perf_counter() - t0
    n = len(truth.train)
    assert report["images"] == n and report["registered"] >= MIN_REGISTERED * n, report
    saved = json.loads((tmp_path / "scene" / "prepare.json").read_text())
    assert saved["registered"] == report["registered"] and saved["points"] > 100
    assert saved["mean_reprojection_error_px"] < 2.0

    est = read_scene_poses(tmp_path / "scene")
    names = sorted(est)
    assert sorted(report["unregistered"]) == sorted(set(true_poses) - set(names))
    assert all("features" in why for why in report["unregistered"].values())
    err = pose_errors([est[k][0] for k in names], [est[k][1] for k in names],
                      [true_poses[k][0] for k in names], [true_poses[k][1] for k in names])
    assert err["max_position_pct"] < MAX_POSITION * 100, (err, report, seconds)
    assert err["max_rotation_deg"] < MAX_ROTATION_DEG, (err, report, seconds)

    scene = load_scene(tmp_path / "scene", DataConfig(test_every=0), device="cpu")
    assert detect_format(tmp_path / "scene") == "colmap"
    assert len(scene.train) == report["registered"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos", "scene", "synthetic"]


def test_pairs_exhaustive_and_sequential():
    from gof_warp.data.prepare import _pairs

    assert _pairs(4, "exhaustive", 10) == [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    seq = _pairs(40, "sequential", 3)
    assert (0, 1) in seq and (0, 3) in seq and (0, 4) in seq and (0, 5) not in seq  # 1..3 ahead, and 1, 2, 4
    assert all(i < j < 40 for i, j in seq) and len(set(seq)) == len(seq)


def test_move_into_place_replaces_only_as_told(tmp_path):
    from gof_warp.data.prepare import _move_into_place

    def scene(name, text):
        d = tmp_path / name
        d.mkdir()
        (d / "prepare.json").write_text(text)
        return d

    _move_into_place(scene("a", "1"), tmp_path / "out")  # absent: renamed
    assert (tmp_path / "out" / "prepare.json").read_text() == "1"
    _move_into_place(scene("b", "2"), tmp_path / "out")  # an earlier output: swapped
    assert (tmp_path / "out" / "prepare.json").read_text() == "2"
    (tmp_path / "empty").mkdir()
    _move_into_place(scene("c", "3"), tmp_path / "empty")  # empty: filled, the folder itself kept
    assert (tmp_path / "empty" / "prepare.json").read_text() == "3"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "out"]
