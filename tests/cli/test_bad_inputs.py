"""Bad inputs as a new user makes them: one clear ``error:`` line and exit 2 (or a warning where going on is
reasonable), never a traceback or a silent success, and nothing already written is lost."""

import json

import numpy as np
import pytest
import torch
import trimesh

from _scene_fixtures import make_blender_scene, make_colmap_scene, make_dtu_scene, make_ingp_scene
from gof_warp.cli import extract
from gof_warp.cli import inspect_scene as inspect
from gof_warp.cli import train
from gof_warp.core.config import ConfigError
from gof_warp.data import DataConfig, load_scene
from gof_warp.core.model import Gaussians
from gof_warp.benchmarking.stability import _blob
from gof_warp.training.trainer import TrainConfig

HUGE_LOG_SCALE = 50.0  # e^50: its square overflows float32 (a diverged model)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A tiny Blender scene: cameras on a ring of radius 3 around the origin, where the blob of Gaussians sits."""
    return make_blender_scene(tmp_path_factory.mktemp("scene") / "blender", n_train=6, n_test=2)


def _ply(path, log_scale=None, n_huge=None, tiny=False):
    m, q, s, o = _blob()
    s = np.full_like(s, 1e-12) if tiny else s
    g = Gaussians.from_activated(m, q, s, o, np.full((len(m), 3), 0.5), device="cpu")
    if log_scale is not None:
        with torch.no_grad():
            g.params["log_scales"][: n_huge or len(g)] = log_scale
        g.filter_3d = torch.full((len(g),), 1e-3)  # as training writes them: the filter turns the overflow into NaN
    g.save_ply(path)
    return path


def _extract(capsys, ply, scene, method, out):
    rc = extract.main([str(ply), "--scene", str(scene), "--method", method, "--out", str(out), "--resolution", "32",
                       "--binary-steps", "2", "--no-pictures", "--quiet"])
    return rc, capsys.readouterr()


def _one_error(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# --------------------------------------------------------------------------------- 1: huge scales
def test_huge_scales_cubes_cli_is_a_clear_error_not_a_nan_crash(tmp_path, scene, capsys):
    """Was: ValueError: cannot convert float NaN to integer (grid sizing), with a traceback. The command's ``main`` in
    this process (an exception escaping it fails the test; the real process's exit path: test_extraction.py)."""
    ply = _ply(tmp_path / "huge.ply", HUGE_LOG_SCALE)
    rc = extract.main([str(ply), "--scene", str(scene), "--method", "cubes", "--resolution", "32", "--no-pictures",
                       "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "scales too large" in _one_error(err) and "log-scale up to 50" in err
    assert not (tmp_path / "mesh_cubes.ply").exists()


@pytest.mark.parametrize("method", ["tsdf", "tetra"])
def test_huge_scales_other_methods_give_the_same_error(tmp_path, scene, capsys, method):
    """Was: tsdf segfaulted (NaN grid size); tetra said only 'scales has NaN/inf entries'."""
    rc, cap = _extract(capsys, _ply(tmp_path / "huge.ply", HUGE_LOG_SCALE), scene, method, tmp_path / "m.ply")
    assert rc == 2 and "scales too large" in _one_error(cap.err)
    assert not (tmp_path / "m.ply").exists()


def test_some_huge_scales_are_left_out_with_a_warning(tmp_path, scene, capsys, caplog):
    ply = _ply(tmp_path / "some.ply", HUGE_LOG_SCALE, n_huge=20)
    rc, cap = _extract(capsys, ply, scene, "cubes", tmp_path / "m.ply")
    assert rc == 0, cap.err
    assert any("20 of 300 Gaussians" in r.getMessage() and "left out" in r.getMessage() for r in caplog.records)
    v = np.asarray(trimesh.load(tmp_path / "m.ply", process=False).vertices)
    assert len(v) > 100 and np.isfinite(v).all()


# --------------------------------------------------------------------------------- 2: non-invertible cameras
def _zero_frame(root, make, name: str, frame: int) -> str:
    """A NeRF-style scene from ``make`` whose ``frame`` in ``name`` has an all-zero transform matrix."""
    make(root)
    d = json.loads((root / name).read_text())
    d["frames"][frame]["transform_matrix"] = np.zeros((4, 4)).tolist()
    (root / name).write_text(json.dumps(d))
    return f"{name} frame {frame}"


def _zero_blender(root):
    return _zero_frame(root, make_blender_scene, "transforms_train.json", 2)


def _zero_ingp(root):
    return _zero_frame(root, make_ingp_scene, "transforms.json", 1)


def _zero_dtu(root):
    make_dtu_scene(root)
    z = dict(np.load(root / "cameras_sphere.npz"))
    z["world_mat_3"] = np.zeros((4, 4))
    np.savez(root / "cameras_sphere.npz", **z)
    return "world_mat_3"


def _zero_colmap(root):
    make_colmap_scene(root)
    path = root / "sparse" / "0" / "images.txt"
    lines = path.read_text().splitlines()
    fields = lines[2].split()  # the second image's header line (each image has a header and a points line)
    fields[1:5] = ["0", "0", "0", "0"]
    lines[2] = " ".join(fields)
    path.write_text("\n".join(lines) + "\n")
    return "images.txt (image 0001.png)"


@pytest.mark.parametrize("write", [_zero_blender, _zero_ingp, _zero_dtu, _zero_colmap], ids=lambda f: f.__name__[6:])
def test_zero_camera_matrix_is_a_scene_error_naming_file_and_frame(tmp_path, capsys, write):
    """Was: inspect gave no warning (blender/ingp/colmap: SVD or pycolmap made a rotation of nothing)."""
    where = write(tmp_path / "s")
    assert inspect.main([str(tmp_path / "s")]) == 2
    err = _one_error(capsys.readouterr().err)
    assert where in err and ("singular" in err or "zero" in err), err


# --------------------------------------------------------------------------------- 3: no parallax
def test_single_training_view_warns(tmp_path, capsys, caplog):
    root = make_blender_scene(tmp_path / "one", n_train=1, n_test=1)
    assert any("only 1 training view" in w for w in load_scene(root).warnings)
    assert any("only 1 training view" in r.getMessage() for r in caplog.records)
    assert inspect.main([str(root), "--json"]) == 0
    assert any("only 1 training view" in w for w in json.loads(capsys.readouterr().out)["warnings"])


def test_identical_cameras_warn_no_parallax(tmp_path, capsys):
    root = make_blender_scene(tmp_path / "same", n_train=4, n_test=1)
    d = json.loads((root / "transforms_train.json").read_text())
    for f in d["frames"]:
        f["transform_matrix"] = d["frames"][0]["transform_matrix"]
    (root / "transforms_train.json").write_text(json.dumps(d))
    assert inspect.main([str(root), "--json"]) == 0
    warnings = json.loads(capsys.readouterr().out)["warnings"]
    assert any("no parallax: geometry cannot be recovered" in w for w in warnings), warnings
    assert not any("parallax" in w for w in load_scene(make_blender_scene(tmp_path / "ok"), DataConfig()).warnings)


# --------------------------------------------------------------------------------- 4: empty mesh
@pytest.mark.slow
@pytest.mark.parametrize("method", ["cubes", "tsdf", "tetra"])
def test_empty_mesh_is_an_error_and_keeps_the_existing_mesh(tmp_path, scene, capsys, method):
    """Was: a 0-vertex mesh written over the existing file, exit 0."""
    out = tmp_path / "mesh.ply"
    out.write_bytes(b"an earlier mesh")
    rc, cap = _extract(capsys, _ply(tmp_path / "tiny.ply", tiny=True), scene, method, out)
    assert rc == 2 and "no surface crosses" in _one_error(cap.err) and "empty or degenerate" in cap.err
    assert out.read_bytes() == b"an earlier mesh"
    assert not out.with_suffix(".json").exists()


# --------------------------------------------------------------------------------- 5: iterations
def test_non_positive_iterations_are_a_config_error(tmp_path, scene, capsys):
    """Was: 'done: -5 iterations', exit 0."""
    with pytest.raises(ConfigError, match="iterations must be an integer >= 1"):
        TrainConfig(iterations=0)
    for args in (["--iterations", "-5"], ["iterations=-5"]):
        assert train.main([str(scene), "--out", str(tmp_path / "run"), "--quiet", *args]) == 2
        assert "iterations must be an integer >= 1, got -5" in _one_error(capsys.readouterr().err)
    assert not any((tmp_path / "run").glob("**/*"))  # nothing written (train.py may create the empty folder)
