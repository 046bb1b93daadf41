"""USD stages (gof_warp.mesh.usd_export): prim types and counts; the cameras' world transforms and intrinsics through
USD's own camera maths (Gf.Camera's frustum) against gof_warp's projection, and a hand-computed golden pixel; the
collision prim's physics APIs; a synthetic texture's material; atomic writes; a clear error without usd-core."""

import sys

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="USD output needs usd-core (the gof_warp[usd] extra; in the test extra)")
from pxr import Gf, Usd, UsdGeom, UsdPhysics, UsdShade  # noqa: E402

from gof_warp.core.camera import Camera, look_at  # noqa: E402
from gof_warp.core.errors import GofError  # noqa: E402
from gof_warp.mesh import usd_export as U  # noqa: E402
from gof_warp.mesh.export import format_of, save_mesh_file  # noqa: E402


def _tetra():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], np.int64)
    return v, f


def _cameras():
    return [look_at([3.0, -2.0, 1.5], [0.1, 0.2, 0.0], fx=70.0, fy=64.0, cx=41.3, cy=27.9, width=80, height=60,
                    name="a"),
            look_at([-1.0, 2.5, -2.0], [0.0, 0.0, 0.2], fx=50.0, fy=55.0, cx=30.0, cy=38.0, width=64, height=72,
                    name="b")]


def _usd_pixel(prim, point):
    """A world point's pixel through the USD camera alone: its world transform, Gf.Camera's frustum (focal length,
    apertures, offsets) and NDC → pixels with the image's size from the prim."""
    cam = UsdGeom.Camera(prim).GetCamera(Usd.TimeCode.Default())
    frustum = cam.frustum
    m = frustum.ComputeViewMatrix() * frustum.ComputeProjectionMatrix()
    ndc = m.Transform(Gf.Vec3d(*map(float, point)))
    w, h = prim.GetCustomDataByKey("gof:imageSize")
    return np.array([(ndc[0] + 1) / 2 * w, (1 - ndc[1]) / 2 * h])


def test_stage_layout_cameras_and_collision(tmp_path):
    v, f = _tetra()
    colours = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [128, 128, 128]], np.uint8)
    cams = _cameras()
    coll = (v * 1.1, f)
    out = tmp_path / "scene.usda"
    info = U.write_usd(out, v, f, colours=colours, cameras=cams, collision=coll)
    assert info["format"] == "usda" and info["cameras"] == 2 and info["collision_faces"] == 4
    assert [p.name for p in tmp_path.iterdir()] == ["scene.usda"]  # no temporary left
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == "/World"

    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/mesh"))
    assert mesh and mesh.GetPrim().GetTypeName() == "Mesh"
    np.testing.assert_allclose(np.array(mesh.GetPointsAttr().Get()), v)
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == [3] * 4
    np.testing.assert_array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), f)
    np.testing.assert_allclose(np.array(mesh.GetExtentAttr().Get()), [[0, 0, 0], [1, 1, 1]])
    assert mesh.GetSubdivisionSchemeAttr().Get() == "none"
    dc = mesh.GetDisplayColorPrimvar()
    assert dc.GetInterpolation() == "vertex"
    np.testing.assert_allclose(np.array(dc.Get())[:3], np.eye(3), atol=1e-6)
    assert np.array(dc.Get())[3, 0] == pytest.approx(((128 / 255 + 0.055) / 1.055) ** 2.4, rel=1e-5)  # linear

    for i, cam in enumerate(cams):
        prim = stage.GetPrimAtPath(f"/World/cameras/cam_{i:04d}")
        assert prim.GetTypeName() == "Camera" and prim.GetCustomDataByKey("gof:name") == cam.name
        world = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default())
        np.testing.assert_allclose(np.array(world.ExtractTranslation()), cam.center, atol=1e-9)
        # the camera looks down its -z: the world direction of local -z is the OpenCV camera's +z (R's third row)
        look = np.array(world.TransformDir(Gf.Vec3d(0, 0, -1)))
        np.testing.assert_allclose(look, cam.R[2], atol=1e-9)
        rng = np.random.default_rng(i)
        points = cam.center + (cam.R.T @ np.column_stack([rng.uniform(-0.5, 0.5, (20, 2)),
                                                          rng.uniform(1.0, 4.0, 20)]).T).T
        uv, _ = cam.project(points)
        got = np.array([_usd_pixel(prim, p) for p in points])
        np.testing.assert_allclose(got, uv, atol=1e-6)

    coll_prim = stage.GetPrimAtPath("/World/collision")
    assert coll_prim.GetTypeName() == "Mesh"
    assert coll_prim.HasAPI(UsdPhysics.CollisionAPI) and coll_prim.HasAPI(UsdPhysics.MeshCollisionAPI)
    assert UsdPhysics.MeshCollisionAPI(coll_prim).GetApproximationAttr().Get() == "none"
    assert UsdGeom.Imageable(coll_prim).GetPurposeAttr().Get() == "guide"
    assert len(UsdGeom.Mesh(coll_prim).GetPointsAttr().Get()) == 4


def test_golden_pixel():
    """A camera at (1, 2, 3) looking along world +y (OpenCV: x right = world +x, y down = world -z), fx 100, fy 80,
    cx 30, cy 20 in a 64x48 image: the world point (1.5, 6, 2.6), 4 in front, 0.5 right and 0.4 up, is at
    u = 100 * 0.5 / 4 + 30 = 42.5, v = 80 * 0.4 / 4 + 20 = 28, through the USD camera."""
    R = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    cam = Camera(R=R, t=-R @ np.array([1.0, 2.0, 3.0]), fx=100.0, fy=80.0, cx=30.0, cy=20.0, width=64, height=48)
    stage = Usd.Stage.CreateInMemory()
    p = U.usd_camera_params(cam)
    ucam = UsdGeom.Camera.Define(stage, "/c")
    for name in ("focalLength", "horizontalAperture", "verticalAperture", "horizontalApertureOffset",
                 "verticalApertureOffset"):
        getattr(ucam, f"Create{name[0].upper()}{name[1:]}Attr")(float(p[name]))
    ucam.AddTransformOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Matrix4d(p["transform"].T.tolist()))
    ucam.GetPrim().SetCustomDataByKey("gof:imageSize", Gf.Vec2i(64, 48))
    np.testing.assert_allclose(_usd_pixel(ucam.GetPrim(), [1.5, 6.0, 2.6]), [42.5, 28.0], atol=1e-9)
    assert p["horizontalAperture"] == pytest.approx(0.36)  # 36 mm in tenths of a metre
    assert p["focalLength"] == pytest.approx(100 * 0.36 / 64)
    assert p["horizontalApertureOffset"] == pytest.approx((32 - 30) * 0.36 / 64)
    assert U.usd_camera_params(cam, 0.01)["horizontalAperture"] == pytest.approx(36.0)  # centimetre stage: mm


@pytest.mark.parametrize("per_corner", [True, False])
def test_texture_material(tmp_path, per_corner):
    """A 4x2 synthetic texture: the stage's material reads the PNG written beside it (same pixels), and the UVs
    come back as written (faceVarying per corner or vertex per vertex)."""
    from PIL import Image

    v, f = _tetra()
    tex = np.arange(4 * 2 * 3, dtype=np.uint8).reshape(2, 4, 3) * 10
    uvs = (np.random.default_rng(0).random((4, 3, 2)) if per_corner else np.random.default_rng(1).random((4, 2)))
    out = tmp_path / "t.usdc"
    info = U.write_usd(out, v, f, texture=tex, uvs=uvs)
    png = tmp_path / "t_texture.png"
    assert info["texture"] == str(png) and info["format"] == "usdc"
    np.testing.assert_array_equal(np.asarray(Image.open(png).convert("RGB")), tex)
    stage = Usd.Stage.Open(str(out))
    mesh = stage.GetPrimAtPath("/World/mesh")
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == ("faceVarying" if per_corner else "vertex")
    np.testing.assert_allclose(np.array(st.Get()), uvs.reshape(-1, 2), atol=1e-7)
    material, _ = UsdShade.MaterialBindingAPI(mesh).ComputeBoundMaterial()
    assert material.GetPath() == "/World/Looks/mesh_material"
    surface = material.ComputeSurfaceSource()[0]
    assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
    src = surface.GetInput("diffuseColor").GetConnectedSources()[0][0].source
    tex_shader = UsdShade.Shader(src.GetPrim())
    assert tex_shader.GetIdAttr().Get() == "UsdUVTexture"
    asset = tex_shader.GetInput("file").Get()
    assert (tmp_path / asset.path).resolve() == png.resolve() and asset.resolvedPath
    with pytest.raises(GofError, match="both"):
        U.write_usd(tmp_path / "x.usda", v, f, texture=tex)
    with pytest.raises(GofError, match="UVs"):
        U.write_usd(tmp_path / "x.usda", v, f, texture=tex, uvs=np.zeros((5, 2)))
    with pytest.raises(GofError, match="uint8"):
        U.write_usd(tmp_path / "x.usda", v, f, texture=tex.astype(np.float32), uvs=uvs)


def test_export_format_and_errors(tmp_path, monkeypatch):
    v, f = _tetra()
    assert [format_of(f"m{s}") for s in (".usd", ".USDA", ".usdc", ".ply")] == ["usd", "usd", "usd", "ply"]
    out = tmp_path / "m.usd"
    assert save_mesh_file(out, v, f, np.full((4, 3), 0.5)) == "usd"
    stage = Usd.Stage.Open(str(out))
    assert out.read_bytes().startswith(b"PXR-USDC")  # .usd: the binary crate
    assert len(UsdGeom.Mesh(stage.GetPrimAtPath("/World/mesh")).GetPointsAttr().Get()) == 4
    assert not stage.GetPrimAtPath("/World/cameras") and not stage.GetPrimAtPath("/World/collision")
    U.write_usd(tmp_path / "y.usda", v, f, cameras=_cameras()[:1], up_axis="Y", meters_per_unit=0.01)
    ystage = Usd.Stage.Open(str(tmp_path / "y.usda"))
    assert UsdGeom.GetStageUpAxis(ystage) == "Y" and UsdGeom.GetStageMetersPerUnit(ystage) == pytest.approx(0.01)
    prim = ystage.GetPrimAtPath("/World/cameras/cam_0000")
    cam = _cameras()[0]
    point = cam.center + 2.0 * cam.R[2] + 0.3 * cam.R[0]
    np.testing.assert_allclose(_usd_pixel(prim, point), cam.project(point[None])[0][0], atol=1e-6)
    with pytest.raises(GofError, match="must end"):
        U.write_usd(tmp_path / "m.ply", v, f)
    with pytest.raises(GofError, match="up_axis"):
        U.write_usd(out, v, f, up_axis="X")
    before = out.read_bytes()
    with pytest.raises(GofError):
        U.write_usd(out, v, np.array([[0, 1, 9]]))  # a bad index: the old file stays
    assert out.read_bytes() == before
    monkeypatch.setitem(sys.modules, "pxr", None)  # as if usd-core were not installed
    with pytest.raises(GofError, match=r"gof-warp\[usd\]"):
        U.write_usd(tmp_path / "n.usda", v, f)


def test_usd_validators_find_nothing(tmp_path):
    """USD's own validators (stage metadata, material bindings, shader compliance, physics colliders, ...) report no
    error on a stage with every part: colours, texture, cameras, collision."""
    try:
        from pxr import UsdValidation
    except ImportError:
        pytest.skip("this usd-core has no UsdValidation (added in 24.11)")
    v, f = _tetra()
    out = tmp_path / "all.usda"
    U.write_usd(out, v, f, colours=np.ones((4, 3)), cameras=_cameras(), collision=(v, f),
                texture=np.zeros((2, 2, 3), np.uint8), uvs=np.random.default_rng(0).random((4, 3, 2)))
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    assert len(validators) > 10
    errors = UsdValidation.ValidationContext(validators).Validate(Usd.Stage.Open(str(out)))
    assert [(e.GetName(), e.GetMessage()) for e in errors] == []
    bare = Usd.Stage.CreateInMemory()  # the validators do find things: no up axis, no units, no default prim
    UsdGeom.Mesh.Define(bare, "/m")
    assert len(UsdValidation.ValidationContext(validators).Validate(bare)) > 0
