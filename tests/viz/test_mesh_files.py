"""Meshes with colours in the pictures: reading PLY/OBJ/GLB with their vertex colours or texture (textured files
built here with trimesh), the newest mesh of a run, and the mesh column drawn in the mesh's own colours (a
flat-coloured mesh gives exactly its colour, vertex colours interpolate like a float64 reference, a texture shows
the right way up) while an uncoloured mesh stays shaded."""

import os

import numpy as np
import pytest
import trimesh
from PIL import Image

from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError
from gof_warp.core.model import Gaussians
from gof_warp.mesh.export import save_mesh_file
from gof_warp.viz.mesh_files import find_mesh, load_mesh_file, run_meshes, sample_texture
from gof_warp.viz.panels import BACKGROUND, CastMesh, shade_cast_mesh, shade_mesh, view_panels

BG = np.round(np.asarray(BACKGROUND) * 255).astype(np.uint8)
# A unit quad in the z = 0 plane seen square-on from +z, world +y up in the image, filling the middle of the image.
QUAD_V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
QUAD_F = np.array([[0, 1, 2], [1, 3, 2]])
FRONT = look_at([0.5, 0.5, 2.0], [0.5, 0.5, 0.0], up=(0.0, 1.0, 0.0), fx=40.0, width=48, height=40, name="front")
# Four texels: red top-left, green top-right, blue bottom-left, yellow bottom-right (as the image is stored).
QUADRANTS = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 0]]], np.uint8)


def _textured_quad(fmt, folder):
    """The quad with uv = (x, y) and a 16x16 texture of :data:`QUADRANTS` (base colour factor 1), written by trimesh
    as ``fmt`` (GLB: an embedded baseColorTexture; OBJ: OBJ + MTL + PNG)."""
    image = Image.fromarray(np.kron(QUADRANTS, np.ones((8, 8, 1), np.uint8)))
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=image, baseColorFactor=[255, 255, 255, 255])
    mesh = trimesh.Trimesh(QUAD_V, QUAD_F, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=QUAD_V[:, :2], material=material))
    path = folder / f"mesh_tex.{fmt}"
    mesh.export(path)
    return path


# ------------------------------------------------------------------------------------------ reading files
@pytest.mark.parametrize("fmt", ["ply", "glb", "obj"])
def test_our_coloured_files_read_back_with_their_vertex_colours(fmt, tmp_path):
    rng = np.random.default_rng(1)
    colours = rng.integers(0, 256, (4, 3)).astype(np.uint8)
    save_mesh_file(tmp_path / f"c.{fmt}", QUAD_V, QUAD_F, colours)
    m = load_mesh_file(tmp_path / f"c.{fmt}")
    assert m.appearance == "vertex" and m.coloured
    np.testing.assert_allclose(m.vertices, QUAD_V, atol=1e-6)
    np.testing.assert_array_equal(m.faces, QUAD_F)
    if fmt == "glb":  # stored linear in 8 bits (glTF): back within its rounding
        assert np.abs(m.vertex_colors.astype(int) - colours.astype(int)).max() <= 6
    else:
        np.testing.assert_array_equal(m.vertex_colors, colours)
    save_mesh_file(tmp_path / f"u.{fmt}", QUAD_V, QUAD_F)
    plain = load_mesh_file(tmp_path / f"u.{fmt}")
    assert plain.appearance == "none" and not plain.coloured
    with pytest.raises(GofError, match="no colours"):
        plain.colour_at(np.array([0]), np.array([[0.2, 0.2]]))


@pytest.mark.parametrize("fmt", ["glb", "obj"])
def test_textured_files_read_back_with_uv_and_image(fmt, tmp_path):
    m = load_mesh_file(_textured_quad(fmt, tmp_path))
    assert m.appearance == "texture"
    assert m.texture.shape == (16, 16, 3)
    np.testing.assert_array_equal(m.texture[::8, ::8], QUADRANTS)
    by_vertex = {tuple(np.round(p, 6)): tuple(t) for p, t in zip(m.vertices, m.uv)}
    assert by_vertex[(1.0, 1.0, 0.0)] == (1.0, 1.0) and by_vertex[(0.0, 1.0, 0.0)] == (0.0, 1.0)


def test_texture_lookup_is_bilinear_between_texel_centres_and_v_points_up():
    image = np.kron(QUADRANTS, np.ones((8, 8, 1), np.uint8))
    # Texel centres of the corner texels; uv (0.25, 0.75) is the middle of the top-left (red) quadrant.
    got = sample_texture(image, np.array([[0.5 / 16, 1 - 0.5 / 16], [0.25, 0.75], [0.75, 0.25], [0.5, 0.75]]))
    np.testing.assert_allclose(got[:3] * 255, [[255, 0, 0], [255, 0, 0], [255, 255, 0]], atol=1e-9)
    np.testing.assert_allclose(got[3] * 255, [127.5, 127.5, 0], atol=1e-9)  # halfway between red and green


def test_missing_or_unreadable_mesh_files_are_named(tmp_path):
    with pytest.raises(GofError, match="nothing.glb"):
        load_mesh_file(tmp_path / "nothing.glb")
    (tmp_path / "bad.obj").write_text("this is not an obj\n")
    with pytest.raises(GofError, match="bad.obj"):
        load_mesh_file(tmp_path / "bad.obj")


def test_the_newest_mesh_of_a_run_is_the_last_modified_of_any_format(tmp_path):
    assert find_mesh(tmp_path) is None
    for i, name in enumerate(["mesh_tetra.ply", "mesh_tetra.obj", "mesh_tetra.glb", "mesh_cubes.ply"]):
        save_mesh_file(tmp_path / name, QUAD_V, QUAD_F)
        os.utime(tmp_path / name, ns=(10**18 + i * 10**9, 10**18 + i * 10**9))
    (tmp_path / "mesh_tetra.json").write_text("{}")  # extract's summary: not a mesh
    (tmp_path / "other.glb").write_bytes((tmp_path / "mesh_tetra.glb").read_bytes())  # not named mesh_*
    assert find_mesh(tmp_path).name == "mesh_cubes.ply"
    os.utime(tmp_path / "mesh_tetra.glb", ns=(2 * 10**18, 2 * 10**18))
    assert find_mesh(tmp_path).name == "mesh_tetra.glb"
    assert [p.name for p in run_meshes(tmp_path)] == ["mesh_tetra.ply", "mesh_tetra.obj", "mesh_cubes.ply",
                                                       "mesh_tetra.glb"]


# ------------------------------------------------------------------------------------------ drawing
def test_a_flat_coloured_mesh_is_drawn_in_exactly_its_colour_where_the_shaded_one_covers(device, tmp_path):
    v, f = trimesh.creation.icosphere(subdivisions=1, radius=0.6).vertices, trimesh.creation.icosphere(1).faces
    colour = np.array([200, 60, 30], np.uint8)
    save_mesh_file(tmp_path / "flat.ply", v, f, np.tile(colour, (len(v), 1)))
    cam = look_at([1.6, -1.9, 0.8], [0.0, 0.0, 0.0], fx=30.0, width=32, height=28)
    mesh = CastMesh.of(load_mesh_file(tmp_path / "flat.ply"), device)
    assert mesh.appearance == "vertex"
    img = shade_cast_mesh(mesh, cam, mode="colour", supersample=1)
    shaded = shade_mesh(v, f, cam, supersample=1, device=device)
    hit = np.any(shaded != BG, axis=-1)
    assert 60 < hit.sum() < hit.size - 60
    assert (img[hit] == colour).all(), "every covered pixel has the vertex colour, unlit"
    assert (img[~hit] == BG).all()
    with pytest.raises(ValueError, match="colour"):
        shade_cast_mesh(CastMesh.build(v, f, device), cam, mode="colour")


def test_vertex_colours_are_interpolated_like_a_float64_reference(device):
    """One triangle with red, green and blue corners: each pixel centre's colour is the barycentric mix of the
    corners at the point its ray meets (found here by intersecting the ray with the triangle's plane)."""
    v = np.array([[-1.0, -1.0, 0.0], [1.2, -0.8, 0.0], [0.1, 1.1, 0.0]])
    f = np.array([[0, 1, 2]])
    c = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]], np.uint8)
    cam = look_at([0.2, -0.3, 3.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0), fx=30.0, width=40, height=36)
    img = shade_cast_mesh(CastMesh.build(v, f, device, colours=c), cam, mode="colour", supersample=1)
    u = (np.arange(cam.width) + 0.5 - cam.cx) / cam.fx
    w = (np.arange(cam.height) + 0.5 - cam.cy) / cam.fy
    uu, ww = np.meshgrid(u, w, indexing="xy")
    d = np.stack([uu, ww, np.ones_like(uu)], -1) @ cam.R
    p = cam.center + d * (-cam.center[2] / d[..., 2])[..., None]  # on the plane z = 0
    a, b, cc = v
    M = np.stack([b - a, cc - a], 1)[:2]  # barycentrics from x, y (the plane is z = 0)
    l12 = np.linalg.solve(M, (p[..., :2] - a[:2]).reshape(-1, 2).T).T.reshape(p.shape[:2] + (2,))
    weights = np.concatenate([1 - l12.sum(-1, keepdims=True), l12], -1)
    inside = (weights > 0.02).all(-1)  # clear of the edges
    assert inside.sum() > 150
    expect = weights @ c.astype(float)
    assert np.abs(img[inside].astype(float) - expect[inside]).max() <= 1.0


@pytest.mark.parametrize("fmt", ["glb", "obj"])
def test_a_textured_mesh_shows_its_texture_the_right_way_up(fmt, tmp_path, device):
    mesh = CastMesh.of(load_mesh_file(_textured_quad(fmt, tmp_path)), device)
    assert mesh.appearance == "texture"
    img = shade_cast_mesh(mesh, FRONT, mode="colour", supersample=1)
    # The quad spans 20 px around the image centre (24, 20); a quadrant's middle lies 5 px from the centre.
    for (row, col), colour in zip([(15, 19), (15, 29), (25, 19), (25, 29)], QUADRANTS.reshape(4, 3)):
        np.testing.assert_array_equal(img[row - 2:row + 3, col - 2:col + 3], np.broadcast_to(colour, (5, 5, 3)))
    assert (img[1, 1] == BG).all()


def _panel_gaussians():
    return Gaussians.from_activated(np.array([[0.5, 0.5, -1.0]]), np.array([[1.0, 0, 0, 0]]), np.full((1, 3), 0.3),
                                    np.array([0.9]), colors=np.array([[0.2, 0.7, 0.2]]), device="cpu")


def test_the_mesh_column_is_coloured_for_a_coloured_mesh_and_shaded_otherwise(tmp_path):
    g = _panel_gaussians()
    colour = np.array([40, 90, 220], np.uint8)
    save_mesh_file(tmp_path / "c.ply", QUAD_V, QUAD_F, np.tile(colour, (4, 1)))
    save_mesh_file(tmp_path / "u.ply", QUAD_V, QUAD_F)
    tiles = {}
    for name in ("c", "u"):
        panels = view_panels(g, [FRONT], mesh=load_mesh_file(tmp_path / f"{name}.ply"), device="cpu")
        x0, y0, x1, y1 = panels.boxes[(0, "mesh")]
        tiles[name] = panels.image[y0:y1, x0:x1]
    middle = (slice(12, 28), slice(16, 32))
    assert (tiles["c"][middle] == colour).all(), "the coloured mesh is drawn in its colour"
    grey = tiles["u"][middle].astype(int)
    assert np.abs(grey[..., 0] - grey[..., 2]).max() <= 8 and grey.min() > 100, "the uncoloured mesh stays shaded"
    np.testing.assert_array_equal(tiles["u"], shade_mesh(QUAD_V, QUAD_F, FRONT, device="cpu"))
    # In memory, as extract passes it: (vertices, faces, colours) gives the same tile as the file.
    panels = view_panels(g, [FRONT], mesh=(QUAD_V, QUAD_F, np.tile(colour, (4, 1))), device="cpu")
    x0, y0, x1, y1 = panels.boxes[(0, "mesh")]
    np.testing.assert_array_equal(panels.image[y0:y1, x0:x1], tiles["c"])
    with pytest.raises(GofError, match="vertex colours must be"):
        view_panels(g, [FRONT], mesh=(QUAD_V, QUAD_F, np.zeros((3, 3))), device="cpu")


def test_a_glb_stores_linear_colour_0_with_an_unlit_material_and_reads_back_srgb(tmp_path):
    """Our GLB follows glTF: COLOR_0 linear (the stored bytes are the sRGB colours converted), an unlit matte
    material beside it (trimesh keeps COLOR_0 as a vertex attribute then); reading converts back to sRGB within
    the 8-bit linear storage's rounding (up to 6 levels at the darkest end, one above 100). The viewer's GLB of the
    read mesh stores the same bytes."""
    import json
    import struct

    from gof_warp.mesh.export import UNLIT, srgb_to_linear
    from gof_warp.viz.viewer import browser_glb

    colours = np.array([[210, 40, 30], [20, 200, 90], [128, 128, 128], [5, 6, 7]], np.uint8)
    save_mesh_file(tmp_path / "c.glb", QUAD_V, QUAD_F, colours)
    raw = (tmp_path / "c.glb").read_bytes()
    n = struct.unpack_from("<I", raw, 12)[0]
    doc = json.loads(raw[20:20 + n])
    assert UNLIT in doc["extensionsUsed"] and all(
        m["pbrMetallicRoughness"]["metallicFactor"] == 0.0 and UNLIT in m["extensions"] for m in doc["materials"])
    stored = trimesh.load(tmp_path / "c.glb", process=False)
    geom = next(iter(stored.geometry.values()))
    stored_rgb = np.asarray(geom.visual.vertex_attributes["color"])[:, :3]
    np.testing.assert_array_equal(stored_rgb, np.round(srgb_to_linear(colours / 255.0) * 255).astype(np.uint8))
    m = load_mesh_file(tmp_path / "c.glb")
    assert m.appearance == "vertex"
    err = np.abs(m.vertex_colors.astype(int) - colours.astype(int))
    assert err[colours >= 100].max() <= 1 and err.max() <= 6, err
    (tmp_path / "unlit.glb").write_bytes(browser_glb(m))
    assert np.array_equal(load_mesh_file(tmp_path / "unlit.glb").vertex_colors, m.vertex_colors)


def test_face_colours_and_a_glb_read_back_go_to_the_browser_too(tmp_path):
    from gof_warp.viz.viewer import browser_glb

    faces_coloured = trimesh.Trimesh(QUAD_V, QUAD_F, process=False, face_colors=[[255, 0, 0, 255], [0, 0, 255, 255]])
    faces_coloured.export(tmp_path / "f.ply")
    m = load_mesh_file(tmp_path / "f.ply")
    assert m.appearance == "face"
    (tmp_path / "f.glb").write_bytes(browser_glb(m))
    back = load_mesh_file(tmp_path / "f.glb")  # three corners per face, each with its face's (linear) colour
    assert back.appearance == "vertex" and len(back.vertices) == 6
    np.testing.assert_array_equal(back.vertex_colors, [[255, 0, 0]] * 3 + [[0, 0, 255]] * 3)
    again = browser_glb(back)  # a GLB with a material beside COLOR_0, sent again
    assert again[:4] == b"glTF"
