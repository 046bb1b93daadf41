"""The viewer's mesh and first view: the run's newest mesh goes to viser with its vertex colours or texture, shown
from the start; the page opens exactly at a training camera. And the real thing: coloured GLB and OBJ files
(written by ``save_mesh_file``) and a textured GLB loaded by viser's three.js page (its GLTFLoader) in a headless
Chromium, whose screenshot must show the mesh's colours at the middle and the background at the corners."""

import importlib.util
import io
import json
import math
import os
import socket
import struct

import numpy as np
import pytest
import trimesh
from PIL import Image

from gof_warp.cli.view import HIDE_NOTIFICATIONS_JS, find_chromium, screenshot
from gof_warp.core.camera import look_at
from gof_warp.core.model import Gaussians
from gof_warp.mesh.export import save_mesh_file
from gof_warp.rendering.render import RenderConfig
from gof_warp.viz.mesh_files import find_mesh, load_mesh_file

HAVE_VISER = importlib.util.find_spec("viser") is not None
pytestmark = pytest.mark.skipif(not HAVE_VISER, reason="viser is not installed: pip install -e '.[viewer]'")
CHROMIUM = find_chromium()
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="no Chromium binary: apt-get install "
                                    "chromium-headless-shell (or chromium), or set GOF_WARP_CHROMIUM")

QUAD_V = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [-1.0, 1.0, 0.0], [1.0, 1.0, 0.0]])
QUAD_F = np.array([[0, 1, 2], [1, 3, 2]])  # its normal: +z, towards the cameras below
COLOUR = np.array([210, 40, 30], np.uint8)
BACKGROUND = (0.1, 0.1, 0.1)
# Four quadrants as stored in the texture image: red top-left, green top-right, blue bottom-left, yellow bottom-right.
QUADRANTS = np.array([[[230, 20, 20], [20, 230, 20]], [[20, 20, 230], [230, 230, 20]]], np.uint8)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cameras():
    """Three cameras on the +z side of the quad; the second looks straight at its centre (the start camera), with
    a roll and a principal point of its own."""
    return [look_at([2.5, 0.5, 2.0], [0.0, 0.9, 0.0], up=(0.0, 1.0, 0.0), fx=50.0, width=64, height=48, name="a"),
            look_at([0.3, -0.2, 3.0], [0.0, 0.0, 0.0], up=(0.4, 1.0, 0.0), fx=60.0, width=80, height=60, name="b"),
            look_at([-2.0, 0.0, 2.0], [0.0, -0.9, 0.0], up=(0.0, 1.0, 0.0), fx=50.0, width=64, height=48, name="c")]


def _faint_gaussians():
    """Gaussians that render as the background (nearly transparent), their centres' median at the origin."""
    means = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [-0.1, 0.0, 0.0]])
    return Gaussians.from_activated(means, np.tile([1.0, 0, 0, 0], (3, 1)), np.full((3, 3), 0.05), np.full(3, 1e-4),
                                    colors=np.full((3, 3), 0.5), device="cpu")


def _textured_quad(path):
    image = Image.fromarray(np.kron(QUADRANTS, np.ones((16, 16, 1), np.uint8)))
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=image, baseColorFactor=[255, 255, 255, 255])
    uv = (QUAD_V[:, :2] + 1) / 2
    trimesh.Trimesh(QUAD_V, QUAD_F, process=False,
                    visual=trimesh.visual.TextureVisuals(uv=uv, material=material)).export(path)
    return path


def _viewer(mesh):
    from gof_warp.viz.viewer import Viewer

    return Viewer(_faint_gaussians(), _cameras(), mesh=mesh, port=_free_port(), max_size=96,
                  render_config=RenderConfig(background=BACKGROUND))


def _sent_glb(viewer):
    """The GLB the viewer gave viser for its mesh: ``(trimesh mesh, its glTF JSON)``."""
    glb = viewer._mesh_handle._impl.props.glb_data
    (json_len,) = struct.unpack_from("<I", glb, 12)
    (mesh,) = trimesh.load(io.BytesIO(glb), file_type="glb", process=False).geometry.values()
    return mesh, json.loads(glb[20:20 + json_len])


def _linear_to_srgb(c):
    c = np.asarray(c, float)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055)


# ------------------------------------------------------------------------------------------ what goes to viser
def test_the_newest_mesh_goes_to_viser_with_its_vertex_colours_shown_from_the_start(tmp_path):
    save_mesh_file(tmp_path / "mesh_tetra.ply", QUAD_V, QUAD_F)
    save_mesh_file(tmp_path / "mesh_tetra.glb", QUAD_V, QUAD_F, np.tile(COLOUR, (4, 1)))
    os.utime(tmp_path / "mesh_tetra.ply", ns=(10**18, 10**18))
    os.utime(tmp_path / "mesh_tetra.glb", ns=(10**18 + 10**9, 10**18 + 10**9))
    assert find_mesh(tmp_path).name == "mesh_tetra.glb"
    with _viewer(load_mesh_file(find_mesh(tmp_path))) as viewer:
        assert viewer._mesh_handle.visible and viewer._show_mesh.value is True and viewer.mesh_shown
        sent, doc = _sent_glb(viewer)
        np.testing.assert_allclose(sent.vertices, QUAD_V, atol=1e-6)
        colour_0 = sent.visual.vertex_attributes["color"][:, :3]  # trimesh: COLOR_0 beside a material
        # glTF's COLOR_0 is linear: the file's sRGB colours come back from it through the sRGB curve (8-bit steps).
        back = _linear_to_srgb(colour_0 / 255.0) * 255.0
        assert np.abs(back - np.tile(COLOUR, (4, 1))).max() <= 4
        assert not np.array_equal(colour_0, np.tile(COLOUR, (4, 1)))
        assert load_mesh_file(tmp_path / "mesh_tetra.glb").appearance == "vertex"
        (material,) = doc["materials"]
        assert "KHR_materials_unlit" in material["extensions"] and material["doubleSided"] is True
        assert "KHR_materials_unlit" in doc["extensionsUsed"]
        viewer._show_mesh.value = False  # the checkbox hides it
        viewer._mesh_toggled()
        assert not viewer._mesh_handle.visible and not viewer.mesh_shown


def test_a_textured_mesh_goes_to_viser_with_its_texture(tmp_path):
    with _viewer(load_mesh_file(_textured_quad(tmp_path / "mesh_tex.glb"))) as viewer:
        sent, doc = _sent_glb(viewer)
        assert sent.visual.kind == "texture" and "KHR_materials_unlit" in doc["materials"][0]["extensions"]
        image = np.asarray(sent.visual.material.baseColorTexture.convert("RGB"))
        np.testing.assert_array_equal(image[::16, ::16], QUADRANTS)
        np.testing.assert_allclose(sent.visual.uv, (QUAD_V[:, :2] + 1) / 2, atol=1e-6)


def test_an_uncoloured_mesh_goes_as_a_grey_surface(tmp_path):
    from gof_warp.viz.viewer import MESH_COLOR

    save_mesh_file(tmp_path / "mesh_tetra.obj", QUAD_V, QUAD_F)
    with _viewer(load_mesh_file(tmp_path / "mesh_tetra.obj")) as viewer:
        props = viewer._mesh_handle._impl.props
        assert tuple(props.color) == MESH_COLOR and viewer._mesh_handle.visible
        np.testing.assert_allclose(props.vertices, QUAD_V, atol=1e-6)


def test_the_page_opens_exactly_at_the_training_camera_that_faces_the_centre():
    from gof_warp.viz.viewer import viewer_pose

    with _viewer(None) as viewer:
        assert viewer.start_index == 1 and not viewer.mesh_shown
        cam = viewer.cameras[1]
        initial = viewer.server.initial_camera
        np.testing.assert_allclose(initial.position, cam.center, atol=1e-12)
        z = initial.look_at - initial.position
        assert np.linalg.norm(z) == pytest.approx(float(cam.R[2] @ np.zeros(3) + cam.t[2]))  # orbit about the centre
        z /= np.linalg.norm(z)
        up = np.asarray(initial.up, float)
        y = -(up - (up @ z) * z)
        y /= np.linalg.norm(y)
        np.testing.assert_allclose(np.stack([np.cross(y, z), y, z], 1), cam.R.T, atol=1e-12)
        assert initial.fov == pytest.approx(2 * math.atan(0.5 * cam.height / cam.fy)) == viewer_pose(cam)[2]


# ------------------------------------------------------------------------------------------ the real thing
@pytest.mark.slow
@needs_chromium
@pytest.mark.parametrize("kind", ["glb", "obj", "textured glb"])
def test_headless_browser_draws_the_mesh_file_in_its_colours(kind, tmp_path):
    """viser's page parses the GLB it is sent with three.js's GLTFLoader (the coloured OBJ goes the same way, read
    by trimesh): seen from the start camera, which looks straight at the quad, the middle of each quadrant of the
    quad has the mesh's colour there and the corners our render's background. The mesh is unlit, but viser's page
    tone-maps the meshes it draws (react-three-fiber's default, ACES filmic): more contrast, and strongly
    saturated colours shift (measured: vertex colour (210, 40, 30) → (222, 22, 26); texels (230, 20, 20) →
    (236, 1, 24), (20, 230, 20) → (124, 217, 74)). So: every quadrant's strong channels stand 80 levels above its
    weak ones, and the vertex colour is within 25 levels (sent without the sRGB → linear conversion it shows as
    (232, 129, 108))."""
    if kind == "textured glb":
        path = _textured_quad(tmp_path / "mesh_tex.glb")
    else:
        path = tmp_path / f"mesh_c.{kind}"
        save_mesh_file(path, QUAD_V, QUAD_F, np.tile(COLOUR, (4, 1)))
    viewer = _viewer(load_mesh_file(path))
    png = tmp_path / "page.png"
    width, height = 800, 600  # the start camera's aspect (80 x 60): the page shows its picture exactly
    cam = viewer.cameras[1]

    def centre_of(page):
        """The page's pixels at points of the quad's quadrants' middles (±0.5, ±0.5, 0), seen from the start
        camera, as ``[4, 3]`` in the order of :data:`QUADRANTS` (top-left, top-right, bottom-left, bottom-right of
        the texture: world (-x, +y), (+x, +y), (-x, -y), (+x, -y))."""
        out = []
        for x, y in ((-0.5, 0.5), (0.5, 0.5), (-0.5, -0.5), (0.5, -0.5)):
            p = cam.R @ np.array([x, y, 0.0]) + cam.t
            u = (cam.fx * p[0] / p[2] + cam.cx) / cam.width * width
            v = (cam.fy * p[1] / p[2] + cam.cy) / cam.height * height
            out.append(page[int(v) - 3:int(v) + 4, int(u) - 3:int(u) + 4].reshape(-1, 3).mean(0))
        return np.array(out)

    expect = (QUADRANTS.reshape(4, 3) if kind == "textured glb" else np.tile(COLOUR, (4, 1))).astype(float)

    def colours_ok(page):
        got = centre_of(page)
        for g, e in zip(got, expect):
            strong = e > 128
            if g[strong].min() < g[~strong].max() + 80:
                return False
        return kind == "textured glb" or np.abs(got - expect).max() <= 25

    with viewer:
        screenshot(viewer.url, png, width=width, height=height, ready=lambda: viewer.frames_sent > 0, accept=colours_ok,
                   timeout=60, stable=True, script=HIDE_NOTIFICATIONS_JS)
    page = np.asarray(Image.open(png).convert("RGB")).astype(int)
    assert colours_ok(page), centre_of(page)
    bg = np.round(np.asarray(BACKGROUND) * 255)
    # The GUI panel is at the top right, viser's axes at the bottom left, the start camera's frustum on the border.
    for corner in (page[5:25, 5:25], page[-25:-5, -25:-5]):
        assert np.abs(corner.reshape(-1, 3).mean(0) - bg).max() < 12, corner.reshape(-1, 3).mean(0)
