"""``extract --collision`` and ``--format usd``: the closed mesh beside the mesh (and in the USD stage), its check
printed and in the JSON; the flag combinations that mean nothing."""

import json

import numpy as np
import pytest
import trimesh

from gof_warp.cli import extract
from gof_warp.core.camera import look_at
from gof_warp.core.model import Gaussians


def _cameras(n=8, size=40):
    return [look_at([2.0 * np.cos(2 * np.pi * a / n), 2.0 * np.sin(2 * np.pi * a / n), 0.9 * np.sin(3 * a)],
                    [0, 0, 0], fx=80, width=size, height=size, name=f"c{a:02d}") for a in range(n)]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """A run folder of two overlapping Gaussians (point_cloud.ply + cameras.json)."""
    run = tmp_path_factory.mktemp("collision_run")
    g = Gaussians.from_activated(np.array([[0.0, 0, 0], [0.25, 0, 0]]), [[1.0, 0, 0, 0], [1.0, 0, 0, 0]],
                                 np.full((2, 3), 0.15), [0.95, 0.95], device="cpu")
    g.save_ply(run / "point_cloud.ply")
    (run / "cameras.json").write_text(json.dumps({"train": [c.to_dict() for c in _cameras()], "test": []}))
    return run


def _extract(cli_in_process, run, *args):
    rc, err = cli_in_process(extract.main, str(run), "--device", "cpu", "--no-pictures", *args)
    assert rc == 0, err[-3000:]
    return err


def test_collision_ply_beside_the_mesh(small_run, tmp_path, capsys):
    out = tmp_path / "m.ply"
    capsys.readouterr()
    rc = extract.main([str(small_run), "--device", "cpu", "--no-pictures", "--out", str(out), "--collision",
                       "--collision-resolution", "24", "--collision-faces", "300"])
    printed = capsys.readouterr().out
    assert rc == 0
    coll = tmp_path / "m_collision.ply"
    assert f"wrote {coll}" in printed and "watertight yes" in printed
    m = trimesh.load(coll, process=False)
    assert m.is_watertight and m.is_winding_consistent and m.is_volume and len(m.faces) <= 300
    stats = json.loads(out.with_suffix(".json").read_text())
    assert stats["collision"]["solid"] and "collision_mesh" in stats["stages"]
    assert stats["meshes"][-1] == {"path": str(coll), "collision": True, "vertices": len(m.vertices),
                                   "faces": len(m.faces), "format": "ply"}


def test_collision_bounds(small_run, tmp_path, cli_in_process):
    """A box that cuts the Gaussians in half: the solid is closed on the cut, within the box."""
    out = tmp_path / "b.ply"
    _extract(cli_in_process, small_run, "--out", str(out), "--collision", "--collision-resolution", "24", "--quiet",
             "--collision-bounds", "-1", "-1", "-1", "0.1", "1", "1")
    m = trimesh.load(tmp_path / "b_collision.ply", process=False)
    assert m.is_volume and m.bounds[1][0] < 0.1 + 2.0 / 24


def test_usd_stage_with_cameras_and_collision(small_run, tmp_path, cli_in_process):
    pytest.importorskip("pxr", reason="USD output needs usd-core (the gof_warp[usd] extra; in the test extra)")
    from pxr import Usd, UsdGeom, UsdPhysics

    out = tmp_path / "s.usda"
    _extract(cli_in_process, small_run, "--out", str(out), "--collision", "--collision-resolution", "24",
             "--quiet")
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == "Z"
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/mesh"))
    stats = json.loads(out.with_suffix(".json").read_text())
    assert stats["meshes"][0]["format"] == "usd"
    assert len(mesh.GetPointsAttr().Get()) == stats["meshes"][0]["vertices"]
    cams = [p for p in stage.GetPrimAtPath("/World/cameras").GetChildren() if p.GetTypeName() == "Camera"]
    assert len(cams) == 8
    coll = stage.GetPrimAtPath("/World/collision")
    assert coll.HasAPI(UsdPhysics.CollisionAPI)
    ply = trimesh.load(tmp_path / "s_collision.ply", process=False)
    assert len(UsdGeom.Mesh(coll).GetFaceVertexIndicesAttr().Get()) == 3 * len(ply.faces)


@pytest.mark.parametrize("argv,match", [
    (["--volume", "--collision"], "--collision"),
    (["--format", "ply", "--out", "m.usda"], "one format"),
    (["--collision-faces", "3"], "--collision-faces"),
    (["--collision-resolution", "1"], "--collision-resolution"),
    (["--collision", "--collision-bounds", "0", "0", "0", "1", "1", "0"], "--collision-bounds"),
])
def test_combinations_that_mean_nothing_are_errors(argv, match, tmp_path, cli_in_process):
    rc, err = cli_in_process(extract.main, str(tmp_path / "run"), "--device", "cpu", *argv)
    assert rc == 2 and match in err


def test_collision_settings_without_collision_warn(caplog):
    a = extract.parse_args(["run", "--collision-faces", "1000"])
    extract.check_args(a)
    assert any("--collision-faces ignored" in r.getMessage() for r in caplog.records)


def test_usd_without_usd_core_fails_before_the_work(small_run, tmp_path, cli_in_process, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "pxr", None)  # as if usd-core were not installed
    rc, err = cli_in_process(extract.main, str(small_run), "--device", "cpu", "--out", str(tmp_path / "m.usda"))
    assert rc == 2 and "gof-warp[usd]" in err and "marching" not in err
    assert not list(tmp_path.iterdir())
