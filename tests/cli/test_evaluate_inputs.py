"""``python -m gof_warp.evaluate``'s inputs (issue 56): a reconstruction without faces, an empty ground truth, NaN
vertices and nonsense option values are ``error: <message>`` (exit 2, no traceback), not a silent score."""

import numpy as np
import pytest
import trimesh

from gof_warp.cli.evaluate import main


def _box(path, **kw):
    m = trimesh.creation.box(extents=(1, 1, 1))
    m.export(path)
    return path


def _ply_points(path, points):
    lines = ["ply", "format ascii 1.0", f"element vertex {len(points)}", "property float x", "property float y",
             "property float z", "end_header"] + [" ".join(map(str, p)) for p in points]
    path.write_text("\n".join(lines) + "\n")
    return path


def _error(rc, err):
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def test_a_mesh_without_faces_is_an_error(tmp_path, cli_in_process):
    """Was: scored as a point cloud, silently."""
    gt = _box(tmp_path / "gt.ply")
    pts = _ply_points(tmp_path / "pts.ply", np.random.default_rng(0).random((50, 3)) - 0.5)
    line = _error(*cli_in_process(main, "--mesh", str(pts), "--gt", str(gt)))
    assert "--mesh" in line and "has no faces" in line


def test_an_empty_ground_truth_is_an_error(tmp_path, cli_in_process):
    mesh = _box(tmp_path / "m.ply")
    empty = _ply_points(tmp_path / "empty.ply", [])
    line = _error(*cli_in_process(main, "--mesh", str(mesh), "--gt", str(empty), "--tau", "0.01", "--density",
                                  "0.01", "--max-dist", "0.1"))
    assert "--gt" in line and "no faces and no points" in line


def test_a_ground_truth_point_cloud_is_scored(tmp_path, cli_in_process):
    mesh = _box(tmp_path / "m.ply")
    gt = _ply_points(tmp_path / "gt.ply", trimesh.creation.box(extents=(1, 1, 1)).sample(2000, seed=0))
    rc, err = cli_in_process(main, "--mesh", str(mesh), "--gt", str(gt))
    assert rc == 0, err


@pytest.mark.parametrize("which", ["--mesh", "--gt"])
def test_nan_vertices_are_an_error(which, tmp_path, cli_in_process):
    good = _box(tmp_path / "good.ply")
    m = trimesh.creation.box(extents=(1, 1, 1))
    v = m.vertices.copy()
    v[2] = np.nan
    trimesh.Trimesh(v, m.faces, process=False).export(tmp_path / "nan.ply")
    paths = {"--mesh": good, "--gt": good, which: tmp_path / "nan.ply"}
    line = _error(*cli_in_process(main, "--mesh", str(paths["--mesh"]), "--gt", str(paths["--gt"])))
    assert which in line and "NaN" in line


@pytest.mark.parametrize("flag,value", [
    ("--tau", "0"), ("--tau", "-0.01"), ("--tau", "inf"), ("--tau", "nan"),
    ("--density", "0"), ("--density", "-1"), ("--density", "inf"),
    ("--max-dist", "0"), ("--max-dist", "-1"), ("--max-dist", "nan"),
    ("--patch", "0"), ("--supersample", "0"), ("--min-views", "0"),
    ("--crop", "1 0 0 0 1 1"),
])
def test_a_nonsense_option_is_an_error_naming_it(flag, value, tmp_path, cli_in_process):
    missing = tmp_path / "none.ply"  # the options are checked before any file is read
    line = _error(*cli_in_process(main, "--mesh", str(missing), "--gt", str(missing), flag, *value.split()))
    assert flag in line
