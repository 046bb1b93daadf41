"""``extract --color`` and ``--format``: coloured PLY, GLB and OBJ that load back in trimesh with the same vertices and
colours; without ``--color`` the PLY's bytes are those of ``--color none`` and it has no colour properties; the
combinations that mean nothing are errors before any work."""

import json

import numpy as np
import pytest
import trimesh

from gof_warp.cli import extract
from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError
from gof_warp.core.model import Gaussians
from gof_warp.mesh.export import format_of, save_mesh_file
from gof_warp.viz.mesh_files import load_mesh_file


def _ring_cameras(n=8, size=40):
    cams = []
    for a in range(n):
        ang = 2 * np.pi * a / n
        cams.append(look_at([2.0 * np.cos(ang), 2.0 * np.sin(ang), 0.9 * np.sin(3 * ang)], [0, 0, 0], fx=80,
                            width=size, height=size, name=f"c{a:02d}"))
    return cams


@pytest.fixture(scope="module")
def colour_run(tmp_path_factory):
    """A run folder of two Gaussians (point_cloud.ply + cameras.json, no photos)."""
    run = tmp_path_factory.mktemp("colour_run")
    g = Gaussians.from_activated(np.array([[0.0, 0, 0], [0.25, 0, 0]]), [[1.0, 0, 0, 0], [1.0, 0, 0, 0]],
                                 np.full((2, 3), 0.15), [0.95, 0.95], device="cpu")
    g.save_ply(run / "point_cloud.ply")
    (run / "cameras.json").write_text(json.dumps({"train": [c.to_dict() for c in _ring_cameras()], "test": []}))
    return run


def _extract(cli_in_process, run, *args):
    rc, err = cli_in_process(extract.main, str(run), "--device", "cpu", "--no-pictures", "--quiet", *args)
    assert rc == 0, err[-3000:]


def test_default_bytes_unchanged_and_coloured_files_load_back(colour_run, tmp_path, cli_in_process):
    plain, none = tmp_path / "plain.ply", tmp_path / "none.ply"
    _extract(cli_in_process, colour_run, "--out", str(plain))
    _extract(cli_in_process, colour_run, "--out", str(none), "--color", "none")
    assert plain.read_bytes() == none.read_bytes()
    header = plain.read_bytes().split(b"end_header")[0]
    assert b"red" not in header and b"property float x" in header
    base = trimesh.load(plain, process=False)
    for name, extra in (("c.ply", []), ("c.glb", []), ("c.obj", []), ("f.bin", ["--format", "glb"])):
        out = tmp_path / name
        _extract(cli_in_process, colour_run, "--out", str(out), "--color", "gaussians", *extra)
        stats = json.loads(out.with_suffix(".json").read_text())
        assert stats["meshes"][0]["color"] == "gaussians" and "colour_s" in stats["command"]
        if format_of(out, "glb" if extra else None) == "glb":  # glTF's linear COLOR_0, read back to sRGB
            glb = out.with_suffix(".glb")
            if glb != out:
                glb.write_bytes(out.read_bytes())
            m = load_mesh_file(glb)
            rgb = m.vertex_colors
        else:
            m = trimesh.load(out, process=False, force="mesh")
            rgb = np.asarray(m.visual.vertex_colors)[:, :3]
        assert len(m.vertices) == len(base.vertices) and len(m.faces) == len(base.faces)
        assert rgb.std() > 0 or rgb.mean() > 0  # coloured, not trimesh's default grey
        if name == "c.ply":
            ply_rgb = rgb
    # glTF and OBJ files stand upright: the built-in scene's +z (found from its cameras) is their +Y; PLY keeps the
    # scene's frame
    assert json.loads((tmp_path / "c.json").read_text())["command"]["up"] == [0.0, 0.0, 1.0]
    assert "up" not in json.loads(plain.with_suffix(".json").read_text())["command"]
    for name in ("c.glb", "c.obj"):
        raw = np.asarray(trimesh.load(tmp_path / name, process=False, force="mesh").vertices)
        np.testing.assert_allclose(raw[:, 1], np.asarray(base.vertices)[:, 2], atol=1e-5)
        np.testing.assert_allclose(raw[:, 2], -np.asarray(base.vertices)[:, 1], atol=1e-5)
    # the same colours through every format (OBJ's floats round back to the same bytes; GLB's linear 8 bits within
    # their rounding)
    m = trimesh.load(tmp_path / "c.obj", process=False, force="mesh")
    np.testing.assert_array_equal(np.asarray(m.visual.vertex_colors)[:, :3], ply_rgb)
    assert np.abs(load_mesh_file(tmp_path / "c.glb").vertex_colors.astype(int) - ply_rgb.astype(int)).max() <= 6


def test_export_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(30, 3)).astype(np.float32)
    f = rng.integers(0, 30, size=(40, 3))
    c = rng.integers(0, 256, size=(30, 3)).astype(np.uint8)
    for fmt in ("ply", "glb", "obj"):
        path = tmp_path / f"m.{fmt}"
        assert save_mesh_file(path, v, f, c) == fmt
        m = load_mesh_file(path)
        assert len(m.vertices) == 30 and len(m.faces) == 40
        np.testing.assert_allclose(m.vertices, v, atol=1e-5)
        if fmt == "glb":
            assert np.abs(m.vertex_colors.astype(int) - c.astype(int)).max() <= 6
        else:
            np.testing.assert_array_equal(m.vertex_colors, c)
    with pytest.raises(GofError, match="colours"):
        save_mesh_file(tmp_path / "bad.ply", v, f, c[:3])


@pytest.mark.parametrize("argv,match", [
    (["--volume", "--color", "gaussians"], "--color"),
    (["--volume", "--format", "glb"], "--format"),
    (["--format", "glb", "--out", "m.obj"], "one format"),
])
def test_combinations_that_mean_nothing_are_errors(argv, match, tmp_path, cli_in_process):
    rc, err = cli_in_process(extract.main, str(tmp_path / "run"), "--device", "cpu", *argv)
    assert rc == 2 and match in err


def test_photos_need_photos(colour_run, tmp_path, cli_in_process):
    rc, err = cli_in_process(extract.main, str(colour_run), "--device", "cpu", "--no-pictures", "--quiet",
                             "--out", str(tmp_path / "p.ply"), "--color", "photos")
    assert rc == 2 and "no photos" in err
