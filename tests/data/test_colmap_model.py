"""The NumPy reader of COLMAP model files against pycolmap's own reading of the same files."""

from pathlib import Path

import numpy as np
import pycolmap
import pytest
from scipy.spatial.transform import Rotation

from _scene_fixtures import make_colmap_scene
from gof_warp.data.colmap_model import quaternion_to_rotation, read_model
from gof_warp.core.errors import SceneError

EXACT = 1e-12


def _compare_with_pycolmap(model_dir: Path):
    ours, ref = read_model(model_dir), pycolmap.Reconstruction(str(model_dir))
    assert sorted(ours.cameras) == sorted(ref.cameras)
    for cid, cam in ref.cameras.items():
        mine = ours.cameras[cid]
        assert (mine.model, mine.width, mine.height) == (cam.model.name, cam.width, cam.height)
        np.testing.assert_array_equal(mine.params, np.asarray(cam.params))
    assert sorted(ours.images) == sorted(ref.images)
    for iid, im in ref.images.items():
        mine = ours.images[iid]
        assert (mine.name, mine.camera_id) == (im.name, im.camera_id)
        cfw = im.cam_from_world
        m = np.asarray((cfw() if callable(cfw) else cfw).matrix())
        np.testing.assert_allclose(quaternion_to_rotation(mine.qvec), m[:, :3], atol=EXACT)
        np.testing.assert_allclose(mine.tvec, m[:, 3], atol=EXACT)
        observed = [(p.xy[0], p.xy[1], p.point3D_id) for p in im.points2D if p.has_point3D()]
        np.testing.assert_array_equal(mine.observations, np.array(observed, float).reshape(-1, 3))
    assert sorted(ours.point_ids.tolist()) == sorted(ref.points3D)
    for k, pid in enumerate(ours.point_ids):
        np.testing.assert_array_equal(ours.xyz[k], ref.points3D[int(pid)].xyz)
        np.testing.assert_array_equal(ours.rgb[k], ref.points3D[int(pid)].color)
    return ours


@pytest.mark.parametrize("binary", [False, True], ids=["text", "binary"])
@pytest.mark.parametrize("model", ["PINHOLE", "OPENCV"])
def test_fixture_models_read_as_pycolmap_reads_them(tmp_path, binary, model):
    params = None if model == "PINHOLE" else [40.0, 41.0, 24.0, 18.0, 0.05, -0.01, 0.001, -0.002]
    root = make_colmap_scene(tmp_path / "s", n=5, model=model, params=params, binary=binary)
    ours = _compare_with_pycolmap(root / "sparse" / "0")
    assert len(ours.images) == 5 and len(ours.xyz) > 0


@pytest.mark.slow
def test_colmap_can_reads_as_pycolmap_reads_it(shared_data):
    ours = _compare_with_pycolmap(shared_data / "colmap_can" / "sparse" / "0")
    assert len(ours.images) == 71 and len(ours.xyz) == 4414


def test_quaternion_to_rotation_matches_scipy():
    q = np.random.default_rng(0).normal(size=(20, 4)) * 3.0  # not unit: normalised inside
    for w, x, y, z in q:
        np.testing.assert_allclose(quaternion_to_rotation([w, x, y, z]), Rotation.from_quat([x, y, z, w]).as_matrix(),
                                   atol=EXACT)


def test_damaged_binary_files_name_file_and_problem(tmp_path):
    root = make_colmap_scene(tmp_path / "s", n=3, binary=True)
    model_dir = root / "sparse" / "0"
    images = (model_dir / "images.bin").read_bytes()
    (model_dir / "images.bin").write_bytes(images[:-5])
    with pytest.raises(SceneError, match=r"images.bin: truncated at byte"):
        read_model(model_dir)
    (model_dir / "images.bin").write_bytes(images + b"\0\0")
    with pytest.raises(SceneError, match=r"images.bin: 2 bytes left after the last record"):
        read_model(model_dir)
    (model_dir / "images.bin").write_bytes(images)
    cams = bytearray((model_dir / "cameras.bin").read_bytes())
    cams[12:16] = (99).to_bytes(4, "little")  # the first camera's model id
    (model_dir / "cameras.bin").write_bytes(bytes(cams))
    with pytest.raises(SceneError, match=r"cameras.bin: camera \d+ has unknown model id 99"):
        read_model(model_dir)


def test_images_of_a_missing_camera_and_short_camera_lines(tmp_path):
    root = make_colmap_scene(tmp_path / "s", n=3)
    model_dir = root / "sparse" / "0"
    text = (model_dir / "cameras.txt").read_text()
    first = [ln for ln in text.splitlines() if ln and not ln.startswith("#")][0]
    (model_dir / "cameras.txt").write_text(first.rsplit(" ", 1)[0] + "\n")  # one parameter short
    with pytest.raises(SceneError, match=r"cameras.txt: camera 1 \(PINHOLE\) has 3 parameters, expected 4"):
        read_model(model_dir)
    (model_dir / "cameras.txt").write_text(first.replace("1 PINHOLE", "7 PINHOLE", 1) + "\n")
    with pytest.raises(SceneError, match=r"images.txt: images refer to camera id\(s\) \[1, 2, 3\]"):
        read_model(model_dir)


def _python(code: str):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-W", "always::RuntimeWarning", "-c", code], capture_output=True,
                          text=True, timeout=120, cwd=Path(__file__).resolve().parents[2])


@pytest.mark.slow
def test_pycolmap_after_gof_warp_leaves_png_writing_working_and_before_it_warns(tmp_path):
    """With pycolmap's wheel loaded before Pillow's C module, Pillow's PNG writer aborts the process (pycolmap 4.2.1).
    ``import gof_warp`` loads Pillow first, so a later pycolmap import is safe; an earlier one is warned about."""
    save = ("import numpy as np; from PIL import Image; "
            f"Image.fromarray(np.zeros((64, 64, 3), np.uint8)).save(r'{tmp_path}/x.png')")
    ok = _python(f"import gof_warp, pycolmap; {save}; print('saved')")
    assert ok.returncode == 0 and "saved" in ok.stdout, ok.stderr[-500:]
    warned = _python("import pycolmap, gof_warp")
    assert warned.returncode == 0 and "pycolmap was imported before Pillow" in warned.stderr


def test_an_unregistered_image_is_not_in_the_files(tmp_path):
    """COLMAP writes only registered (posed) images into ``images``; an image whose frame is deregistered is absent,
    which is why the reader takes every listed image as posed (pycolmap's ``has_pose`` was checked before)."""
    root = make_colmap_scene(tmp_path / "s", n=3, binary=True)
    rec = pycolmap.Reconstruction(str(root / "sparse" / "0"))
    if not hasattr(rec, "deregister_frame"):
        pytest.skip(f"pycolmap {pycolmap.__version__} has no frames to deregister")
    dropped = sorted(rec.images)[1]
    rec.deregister_frame(rec.images[dropped].frame_id)
    for write, name in ((rec.write_binary, "bin"), (rec.write_text, "txt")):
        out = tmp_path / name
        out.mkdir()
        write(str(out))
        model = read_model(out)
        assert sorted(model.images) == sorted(set(rec.images) - {dropped}), name
