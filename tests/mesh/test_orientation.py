"""Upright assets: the scene's up from its cameras, the rotation to a format's up, and GLB/OBJ/USD written upright
and read back in the scene's frame."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError
from gof_warp.core.orientation import parse_up, rotation_taking, scene_up, world_from_file
from gof_warp.mesh.export import save_mesh_file, save_textured_mesh
from gof_warp.mesh.texture import TexturedMesh
from gof_warp.viz.mesh_files import load_mesh_file

# a tetrahedron standing on z = 0 with its apex up (+z): upright means its apex along the format's up
TET_V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.2, 0.2, 1.5]])
TET_F = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])


def _orbit(up=(0.0, 0.0, 1.0), n=12, elevation=30.0, Q=np.eye(3)):
    """``n`` cameras orbiting the origin at ``elevation`` degrees, their images upright for ``up``; the whole rig
    turned by ``Q``."""
    cams = []
    e = math.radians(elevation)
    for i in range(n):
        a = 2 * math.pi * i / n
        eye = np.array([3 * math.cos(a) * math.cos(e), 3 * math.sin(a) * math.cos(e), 3 * math.sin(e)])
        cams.append(look_at(Q @ eye, (0, 0, 0), up=Q @ np.asarray(up), width=32, height=24, fx=30.0))
    return cams


def _random_rotation(seed):
    q = np.random.default_rng(seed).normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_parse_up_takes_auto_and_signed_axes_and_names_the_choices_otherwise():
    assert parse_up("auto") is None
    assert parse_up("+z").tolist() == [0, 0, 1] and parse_up("-y").tolist() == [0, -1, 0]
    assert parse_up("x").tolist() == [1, 0, 0]
    with pytest.raises(GofError, match=r"up must be one of auto, \+x"):
        parse_up("up")


@pytest.mark.parametrize("a, b", [((0, 0, 1), (0, 1, 0)), ((0, -1, 0), (0, 1, 0)), ((0, 1, 0), (0, 1, 0)),
                                  ((1, 2, 3), (0, 0, 1)), ((0, 0, -1), (0, 0, 1))])
def test_rotation_taking_is_a_rotation_that_takes_a_to_b(a, b):
    R = rotation_taking(a, b)
    a_, b_ = np.asarray(a, float) / np.linalg.norm(a), np.asarray(b, float) / np.linalg.norm(b)
    np.testing.assert_allclose(R @ a_, b_, atol=1e-12)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_rotation_taking_z_to_y_is_blenders_z_up_to_gltf_y_up():
    """x stays, y_file = z_world, z_file = -y_world: the conversion Blender's glTF exporter applies."""
    np.testing.assert_allclose(rotation_taking((0, 0, 1), (0, 1, 0)), [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-15)


def test_the_up_of_an_orbit_is_its_axis_exactly_and_follows_a_turned_rig():
    assert scene_up(_orbit()).tolist() == [0.0, 0.0, 1.0]  # snapped: bit for bit the axis
    Q = _random_rotation(3)
    up = scene_up(_orbit(Q=Q))
    np.testing.assert_allclose(up, Q @ [0, 0, 1], atol=1e-9)  # not near an axis: not snapped
    assert not np.any(np.abs(up) == 1.0)


def test_a_colmap_like_rig_with_y_down_gives_minus_y():
    """COLMAP / OpenCV worlds are often y-down: cameras held upright in such a world have image-up along -y."""
    Q = rotation_taking((0, 0, 1), (0, -1, 0))
    assert scene_up(_orbit(Q=Q)).tolist() == [0.0, -1.0, 0.0]


def test_cameras_rolled_every_way_give_no_up():
    cams = []
    for i, roll in enumerate(np.linspace(0, 2 * math.pi, 8, endpoint=False)):
        c = _orbit(n=8)[i]
        Rz = np.array([[math.cos(roll), -math.sin(roll), 0], [math.sin(roll), math.cos(roll), 0], [0, 0, 1]])
        cams.append(SimpleNamespace(R=Rz @ np.asarray(c.R)))  # each image rolled by its own angle
    assert scene_up(cams) is None
    assert scene_up([]) is None


@pytest.mark.parametrize("suffix, colours", [(".glb", None), (".glb", True), (".obj", None), (".obj", True)])
def test_glb_and_obj_are_written_upright_and_read_back_in_the_scene_frame(tmp_path, suffix, colours):
    col = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 255]], np.uint8) if colours else None
    path = tmp_path / f"tet{suffix}"
    save_mesh_file(path, TET_V, TET_F, col, up=np.array([0.0, 0.0, 1.0]))
    raw = trimesh.load(path, process=False, force="mesh")
    apex = np.asarray(raw.vertices)[np.argmax(np.asarray(raw.vertices)[:, 1])]
    np.testing.assert_allclose(apex, [0.2, 1.5, -0.2], atol=1e-6)  # the apex up +Y, as any glTF/OBJ tool shows it
    back = load_mesh_file(path)
    np.testing.assert_allclose(back.vertices, TET_V, atol=1e-6)
    np.testing.assert_array_equal(back.faces, TET_F)
    if colours:
        np.testing.assert_array_equal(back.vertex_colors[:, :3], col)
    # winding kept: the volume stays positive after the rotation
    assert trimesh.Trimesh(np.asarray(raw.vertices), np.asarray(raw.faces), process=False).volume > 0


def test_a_textured_glb_is_written_upright_and_read_back_in_the_scene_frame(tmp_path):
    tex = TexturedMesh(vertices=TET_V.astype(np.float32), faces=TET_F,
                       uv=np.array([[0.1, 0.1], [0.9, 0.1], [0.1, 0.9], [0.5, 0.5]], np.float32),
                       texture=np.full((8, 8, 3), 0.5, np.float32), vmap=np.arange(4), info={})
    for suffix in (".glb", ".obj"):
        path = tmp_path / f"tex{suffix}"
        save_textured_mesh(path, tex, up=np.array([0.0, 0.0, 1.0]))
        raw = trimesh.load(path, process=False, force="mesh")
        assert np.asarray(raw.vertices)[:, 1].max() == pytest.approx(1.5, abs=1e-6)
        back = load_mesh_file(path)
        np.testing.assert_allclose(back.vertices, TET_V, atol=1e-6)
        assert back.texture is not None


def test_without_up_the_scene_frame_is_written_and_nothing_is_recorded(tmp_path):
    for suffix in (".glb", ".obj"):
        path = tmp_path / f"plain{suffix}"
        save_mesh_file(path, TET_V, TET_F)
        assert world_from_file(path) is None
        np.testing.assert_allclose(trimesh.load(path, process=False, force="mesh").vertices, TET_V, atol=1e-6)
    # already +Y up: no rotation to record
    save_mesh_file(tmp_path / "y.glb", TET_V, TET_F, up=np.array([0.0, 1.0, 0.0]))
    assert world_from_file(tmp_path / "y.glb") is None


def test_a_recorded_rotation_that_is_not_one_is_refused(tmp_path):
    path = tmp_path / "bad.obj"
    path.write_text("# written by gof_warp\n# gof_warp file_from_world 2 0 0 0 1 0 0 0 1\nv 0 0 0\nv 1 0 0\n"
                    "v 0 1 0\nf 1 2 3\n")
    with pytest.raises(GofError, match="not a rotation"):
        load_mesh_file(path)


def test_a_usd_stage_of_a_y_down_scene_stands_upright(tmp_path):
    pytest.importorskip("pxr")
    from pxr import Gf, Usd, UsdGeom

    Q = rotation_taking((0, 0, 1), (0, -1, 0))  # the tetrahedron in a y-down world
    v = TET_V @ Q.T
    path = tmp_path / "tet.usda"
    from gof_warp.mesh.usd_export import write_usd

    write_usd(path, v, TET_F, cameras=_orbit(Q=Q)[:2], up=np.array([0.0, -1.0, 0.0]))
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    cache = UsdGeom.XformCache()
    mesh = stage.GetPrimAtPath("/World/mesh")
    M = cache.GetLocalToWorldTransform(mesh)
    pts = [M.Transform(Gf.Vec3d(*map(float, p))) for p in UsdGeom.Mesh(mesh).GetPointsAttr().Get()]
    np.testing.assert_allclose(np.array([list(p) for p in pts]), TET_V, atol=1e-6)  # apex up +Z
    # the cameras turn with the mesh: a camera's centre in the stage is its upright position
    cam = stage.GetPrimAtPath("/World/cameras/cam_0000")
    centre = cache.GetLocalToWorldTransform(cam).ExtractTranslation()
    np.testing.assert_allclose(list(centre), Q.T @ _orbit(Q=Q)[0].center, atol=1e-6)
    # no up: no /World rotation, as before
    write_usd(tmp_path / "plain.usda", v, TET_F)
    plain = Usd.Stage.Open(str(tmp_path / "plain.usda"))
    assert not UsdGeom.Xformable(plain.GetPrimAtPath("/World")).GetOrderedXformOps()
