"""``extract --texture``: a GLB with the texture embedded (the default format), OBJ + MTL + PNG side by side, after
``--max-faces``; the defaults (photos, glb) and the combinations that mean nothing."""

import json
import logging

import numpy as np
import pytest
import trimesh

from gof_warp.cli import extract

pytest.importorskip("xatlas", reason="--texture needs the optional xatlas (gof-warp[texture] / [test])")

from tests.cli.test_extract_colour import colour_run  # noqa: E402,F401 - the fixture


def _extract(cli_in_process, run, *args):
    rc, err = cli_in_process(extract.main, str(run), "--device", "cpu", "--no-pictures", "--quiet", *args)
    assert rc == 0, err[-3000:]


def test_textured_glb_and_obj(colour_run, tmp_path, cli_in_process):  # noqa: F811
    out = tmp_path / "t"
    _extract(cli_in_process, colour_run, "--out", str(out), "--texture", "--color", "gaussians", "--texture-size",
             "64", "--max-faces", "300")
    glb = out  # no known suffix: --texture's default format, glb, at the path given
    stats = json.loads(out.with_suffix(".json").read_text())["meshes"][0]
    assert stats["format"] == "glb" and stats["texture"]["size"] == 64 and stats["faces"] <= 300
    m = trimesh.load(glb, process=False, force="mesh", file_type="glb")
    assert len(m.faces) == stats["faces"] and m.visual.uv.shape == (len(m.vertices), 2)
    img = np.asarray(m.visual.material.baseColorTexture)
    assert img.shape[:2] == (64, 64) and img[..., :3].std() > 0
    obj = tmp_path / "t.obj"
    _extract(cli_in_process, colour_run, "--out", str(obj), "--texture", "--color", "gaussians", "--texture-size",
             "64")
    assert (tmp_path / "t.mtl").is_file() and (tmp_path / "t.png").is_file()
    assert "map_Kd t.png" in (tmp_path / "t.mtl").read_text()
    m = trimesh.load(obj, process=False, force="mesh")
    assert np.asarray(m.visual.material.image).shape[:2] == (64, 64)


def test_texture_defaults():
    a = extract.parse_args(["run", "--texture"])
    assert a.color == "photos" and a.format == "glb" and extract.mesh_base(a, extract.Path("run")).suffix == ".glb"
    a = extract.parse_args(["run", "--texture", "--out", "m.obj", "--color", "gaussians"])
    assert a.color == "gaussians" and extract.format_of(extract.mesh_base(a, extract.Path("run")), a.format) == "obj"
    assert extract.parse_args(["run", "--color", "photos"]).format is None  # no --texture: as before


@pytest.mark.parametrize("argv,match", [
    (["--texture", "--color", "none"], "--color none"),
    (["--texture", "--texture-size", "8"], "--texture-size"),
    (["--texture", "--texture-size", "100000"], "--texture-size"),
    (["--volume", "--texture"], "--texture"),
])
def test_texture_combinations_that_mean_nothing(argv, match, tmp_path, cli_in_process):
    rc, err = cli_in_process(extract.main, str(tmp_path / "run"), "--device", "cpu", *argv)
    assert rc == 2 and match in err, err


def test_texture_size_without_texture_warns(caplog):
    with caplog.at_level(logging.WARNING, logger="gof_warp.extract"):
        extract.check_args(extract.parse_args(["run", "--texture-size", "512"]))
    assert any("--texture-size" in r.getMessage() and "ignored" in r.getMessage() for r in caplog.records)


def test_textured_usd_stage_with_its_texture_beside_it(colour_run, tmp_path, cli_in_process):  # noqa: F811
    """``--texture --format usd``: the stage's mesh is the atlas's, with a UsdPreviewSurface reading the texture PNG
    written beside it (USD's UVs: v up)."""
    pytest.importorskip("pxr", reason="USD output needs the optional usd-core (gof-warp[usd] / [test])")
    from pxr import Usd, UsdGeom, UsdShade

    stage_path = tmp_path / "t.usda"
    _extract(cli_in_process, colour_run, "--out", str(stage_path), "--texture", "--color", "gaussians",
             "--texture-size", "64", "--max-faces", "300")
    png = tmp_path / "t_texture.png"
    assert png.is_file()
    stage = Usd.Stage.Open(str(stage_path))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/mesh"))
    st = UsdGeom.PrimvarsAPI(mesh.GetPrim()).GetPrimvar("st")
    uv = np.asarray(st.Get())
    assert len(uv) and uv.min() >= -1e-6 and uv.max() <= 1 + 1e-6
    material, _ = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()
    assert material
    files = [str(p.GetAttribute("inputs:file").Get()) for p in stage.Traverse() if p.GetAttribute("inputs:file")]
    assert any("t_texture.png" in f for f in files)
    # the texture's bytes: an RGB image of the size asked for
    from PIL import Image

    assert Image.open(png).size == (64, 64)
