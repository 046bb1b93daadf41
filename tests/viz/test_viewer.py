"""The live web viewer: camera conversions to and from viser, what each mode renders, clear errors, and the real
thing — the viewer of a tiny trained run loaded in a headless Chromium, whose screenshot must show the scene;
``train --viewer`` serves the page during and after training."""

import importlib.util
import math
import socket
import sys
import urllib.request

import numpy as np
import pytest
import torch
from PIL import Image

from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError
from gof_warp.core.model import Gaussians
from gof_warp.cli.view import find_chromium, grow_mask, page_difference
from gof_warp.viz.viewer import (
    FAR_DEPTH,
    FRUSTUM_COLOR,
    MODES,
    UNSEEN_COLOR,
    Viewer,
    camera_from_viewer,
    matrix_to_quat,
    quat_to_matrix,
    render_mode,
    require_viser,
    start_camera,
    viewer_look_at,
    viewer_pose,
)

HAVE_VISER = importlib.util.find_spec("viser") is not None
needs_viser = pytest.mark.skipif(not HAVE_VISER, reason="viser is not installed: pip install -e '.[viewer]'")
CHROMIUM = find_chromium()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ------------------------------------------------------------------------------------------ cameras
def test_quaternions_round_trip():
    rng = np.random.default_rng(0)
    for q in rng.normal(size=(50, 4)).tolist() + [[0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [1, 0, 0, 0]]:
        q = np.asarray(q) / np.linalg.norm(q)
        R = quat_to_matrix(q)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(matrix_to_quat(R), q if q[0] >= 0 else -q, atol=1e-9)


def test_browser_camera_becomes_our_camera_and_back():
    cam = look_at([2.0, -3.0, 1.5], [0.1, 0.2, -0.1], fx=60.0, fy=60.0, width=80, height=60)
    wxyz, position, fov, aspect = viewer_pose(cam)
    np.testing.assert_allclose(position, cam.center, atol=1e-12)
    assert aspect == pytest.approx(80 / 60) and fov == pytest.approx(2 * math.atan(30 / 60))
    back = camera_from_viewer(position, wxyz, fov, aspect, max_size=160)  # twice the size, same view
    assert (back.width, back.height) == (160, 120) and back.fy == pytest.approx(120.0)
    np.testing.assert_allclose(back.R, cam.R, atol=1e-12)
    np.testing.assert_allclose(back.t, cam.t, atol=1e-12)
    R_c2w = quat_to_matrix(wxyz)  # viser: +z forward, +x right, +y down in the image
    for direction, (du, dv) in ((R_c2w[:, 2], (0, 0)), (R_c2w[:, 2] + 0.2 * R_c2w[:, 0], (1, 0)),
                                (R_c2w[:, 2] + 0.2 * R_c2w[:, 1], (0, 1))):
        p = back.R @ (position + 3.0 * direction) + back.t
        u, v = back.fx * p[0] / p[2] + back.cx, back.fy * p[1] / p[2] + back.cy
        assert np.sign(round(u - back.cx, 6)) == du and np.sign(round(v - back.cy, 6)) == dv
    tall = camera_from_viewer(position, wxyz, fov, 0.5, max_size=100)
    assert (tall.width, tall.height) == (50, 100)
    with pytest.raises(GofError, match="bad viewer camera"):
        camera_from_viewer(position, wxyz, 0.0, 1.0, 100)


def _pose_from_look_at(position, look, up):
    """Camera-to-world rotation ``[3, 3]`` (OpenCV axes) of a camera at ``position`` looking at ``look`` with ``up``
    up in the image, as three.js's ``lookAt`` (viser's page) builds it: ``z`` forward, ``-y`` the part of ``up``
    across the axis, ``x = y × z``."""
    z = np.asarray(look, float) - np.asarray(position, float)
    z /= np.linalg.norm(z)
    up = np.asarray(up, float)
    y = -(up - (up @ z) * z)
    y /= np.linalg.norm(y)
    return np.stack([np.cross(y, z), y, z], 1)


def test_the_first_view_is_the_training_camera_looking_most_directly_at_the_centre():
    centre = np.array([0.3, -0.2, 0.1])
    cams = [look_at([3.0, 0.0, 1.0], centre + [0.0, 0.8, 0.0], fx=50.0, width=64, height=48, name="off"),
            look_at([-1.0, 2.5, 1.5], centre + [0.05, 0.0, 0.0], up=(0.3, 0.0, 1.0), fx=50.0, width=64, height=48,
                    name="near"),
            look_at([0.0, -3.0, 0.5], centre + [0.0, 0.0, 0.6], fx=50.0, width=64, height=48, name="above")]
    assert start_camera(cams, centre) == 1
    assert start_camera([cams[0], cams[0]], centre) == 0, "ties: the first"
    cam = cams[1]
    position, look, up = viewer_look_at(cam, 2.0)
    np.testing.assert_allclose(position, cam.center, atol=1e-12)
    assert np.linalg.norm(look - position) == pytest.approx(2.0)
    np.testing.assert_allclose(_pose_from_look_at(position, look, up), cam.R.T, atol=1e-12)  # roll included


# ------------------------------------------------------------------------------------------ pictures
def _blob_scene():
    """One big opaque red Gaussian at the origin, a camera looking at it from 3 units away."""
    g = Gaussians.from_activated(np.zeros((1, 3)), np.array([[1.0, 0, 0, 0]]), np.full((1, 3), 0.4), np.array([0.99]),
                                 colors=np.array([[0.9, 0.1, 0.1]]), device="cpu")
    cam = look_at([0.0, -3.0, 0.0], [0.0, 0.0, 0.0], fx=40.0, fy=40.0, width=48, height=40, name="c")
    return g, cam


@pytest.mark.parametrize("mode", MODES)
def test_every_mode_shows_the_gaussian_in_the_middle_and_not_in_the_corner(mode):
    g, cam = _blob_scene()
    image, depth = render_mode(g, cam, mode, train_cameras=[cam], slice_depth=3.0)
    assert image.shape == (40, 48, 3) and image.dtype == np.uint8
    centre, corner = image[20, 24].astype(int), image[1, 1].astype(int)
    assert np.abs(centre - corner).sum() > 80, (mode, centre, corner)
    if mode == "render":
        assert centre[0] > 150 and centre[1] < 80, "the Gaussian is red"
    if mode == "opacity slice":
        assert depth is None and centre.min() > 200 and corner.max() < 40, "opaque white inside, transparent black out"
    else:
        assert depth.shape == (40, 48) and depth[1, 1] == FAR_DEPTH
        assert depth[20, 24] == pytest.approx(3.0, abs=0.3), "camera-space depth of the Gaussian's surface"


def test_opacity_slice_marks_points_no_training_camera_sees():
    g, cam = _blob_scene()
    far_away = look_at([0.0, 3.0, 30.0], [0.0, 3.0, 40.0], fx=40.0, fy=40.0, width=48, height=40)
    image, _ = render_mode(g, cam, "opacity slice", train_cameras=[far_away], slice_depth=3.0)
    assert (image.reshape(-1, 3) == UNSEEN_COLOR).all(axis=1).all()
    with pytest.raises(GofError, match="mode"):
        render_mode(g, cam, "wireframe")


# ------------------------------------------------------------------------------------------ errors
def test_missing_viser_is_named_with_the_install_command(monkeypatch, tmp_path, capsys):
    from gof_warp.cli import train
    from gof_warp.cli import view

    monkeypatch.setitem(sys.modules, "viser", None)  # import viser -> ImportError
    with pytest.raises(GofError, match=r"pip install 'gof_warp\[viewer\]'"):
        require_viser()
    assert view.main([str(tmp_path)]) == 2
    assert train.main(["--out", str(tmp_path / "run"), "--viewer"]) == 2
    err = capsys.readouterr().err
    assert err.count("error: the web viewer needs viser") == 2 and "Traceback" not in err


def test_bad_viewer_options_are_refused(tmp_path, capsys):
    from gof_warp.cli import train
    from gof_warp.cli import view

    g, cam = _blob_scene()
    with pytest.raises(GofError, match="max-size"):
        Viewer(g, [cam], max_size=4)
    with pytest.raises(GofError, match="port"):
        Viewer(g, [cam], port=70000)
    with pytest.raises(GofError, match="camera"):
        Viewer(g, [])
    assert train.main(["--out", str(tmp_path / "run"), "--viewer", "--viewer-every", "0"]) == 2
    assert "--viewer-every must be >= 1" in capsys.readouterr().err
    if HAVE_VISER:
        assert view.main([str(tmp_path / "nothing")]) == 2
        assert "is not a run folder" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------ the real thing
TINY = {"iterations": 12, "checkpoint_every": 100, "log_every": 4,
        "model": {"sh_degree": 0, "init": "random", "random_init_points": 400},
        "optim": {"means_lr_max_steps": 12}, "loss": {"regularization_from_iter": 100},
        "densify": {"start_iter": 100, "stop_iter": 100, "filter_3d_until_iter": 0}}


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A trained run folder (12 iterations on 40x30 images of the default synthetic scene) with a mesh."""
    import trimesh

    from gof_warp.core.config import merge
    from gof_warp.data import load_scene
    from gof_warp.synthetic import make_scene
    from gof_warp.training.trainer import TrainConfig, Trainer

    run = tmp_path_factory.mktemp("view") / "run"
    make_scene("default", run / "scene", views=5, resolution=(40, 30), device="cpu")
    Trainer(load_scene(run / "scene"), merge(TrainConfig(), TINY), run, "cpu").run()
    trimesh.creation.icosphere(subdivisions=2, radius=0.5).export(run / "mesh_tetra.ply")
    return run


@pytest.mark.slow
@needs_viser
@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium binary: apt-get install chromium-headless-shell (or chromium), "
                                             "or set GOF_WARP_CHROMIUM")
def test_headless_browser_screenshot_shows_the_rendered_scene(tiny_run, tmp_path, monkeypatch, capsys):
    from gof_warp.cli import view
    from gof_warp.viz import viewer

    made = []
    real_open_run = viewer.open_run
    monkeypatch.setattr(viewer, "open_run", lambda *a, **k: made.append(real_open_run(*a, **k)) or made[-1])
    png = tmp_path / "viewer.png"
    assert view.main([str(tiny_run), "--host", "127.0.0.1", "--port", str(_free_port()), "--device", "cpu",
                      "--max-size", "128", "--screenshot", str(png)]) == 0
    assert f"wrote {png}" in capsys.readouterr().out
    shot = np.asarray(Image.open(png).convert("RGB"))
    assert shot.shape == (800, 1200, 3)
    viewer = made[0]
    frame, camera = viewer.last_frame, viewer.last_camera  # our renderer's image, as sent to the browser
    h, w = frame.shape[:2]
    assert w == 128 and abs(w / h - 1.5) < 0.02, "rendered at the page's aspect ratio, 128 px wide"
    start = viewer.cameras[viewer.start_index]  # the browser's camera, as it reported it: the start camera's pose
    np.testing.assert_allclose(camera.R, start.R, atol=2e-3)
    np.testing.assert_allclose(camera.center, start.center, atol=2e-3 * viewer.scene_size)
    assert camera.fy / camera.height == pytest.approx(start.fy / start.height, rel=2e-3), "its vertical field of view"
    # The page shows that image stretched over the whole canvas, under the GUI panel (top right), the orange
    # camera frustums and the mesh (shown from the start): scaled back to the frame's size it must match it where
    # none of them covers it.
    orange = np.abs(shot.astype(int) - FRUSTUM_COLOR).sum(-1) < 90
    assert orange.sum() > 30, "the training cameras are drawn as orange frustums"
    covered = viewer.mesh_coverage(camera)
    assert 0.02 < covered.mean() < 0.8, "the run's mesh is in view"
    inner = ~grow_mask(~covered)  # the mesh's pixels clear of its rim, scaled up to the page
    inner = np.asarray(Image.fromarray(inner).resize((1200, 800), Image.Resampling.NEAREST))
    mesh_pixels = shot[inner].astype(int)
    assert len(mesh_pixels) > 1000 and np.median(np.abs(mesh_pixels[:, 0] - mesh_pixels[:, 2])) < 12, \
        "the uncoloured mesh is drawn grey where the ray cast says it is"
    diff = page_difference(shot, frame, covered)
    assert diff.size > 0.3 * h * w
    assert np.median(diff) < 12 and diff.mean() < 20, f"the page does not show our render ({diff.mean():.1f} levels off)"
    empty = page_difference(np.full_like(shot, 255), frame)  # viser's page without our image is near-white
    assert empty.mean() > 3 * diff.mean() + 30, "the render is indistinguishable from an empty page"
    assert frame.std() > 5, "the render shows something, not a flat colour"


@pytest.mark.slow
@needs_viser
def test_train_with_viewer_serves_the_page_and_updates_the_model(tiny_run, tmp_path, monkeypatch, capsys):
    from gof_warp.cli import train
    from gof_warp.viz.viewer import Viewer

    shown, served = [], {}
    original = Viewer.update

    def update(self, gaussians, iteration=None):
        shown.append(iteration)
        original(self, gaussians, iteration)

    def keep_serving(viewer):  # instead of waiting for Ctrl-C: fetch the page once
        with urllib.request.urlopen(viewer.url, timeout=20) as r:
            served["status"], served["html"] = r.status, r.read(4096).decode("utf-8", "replace")

    monkeypatch.setattr(Viewer, "update", update)
    monkeypatch.setattr(train, "_keep_serving", keep_serving)
    port = _free_port()
    overrides = ["log_every=2", "checkpoint_every=100", "model.sh_degree=0", "model.init=random",
                 "model.random_init_points=200", "densify.start_iter=100", "densify.stop_iter=100",
                 "densify.filter_3d_until_iter=0", "loss.regularization_from_iter=100"]
    assert train.main([str(tiny_run / "scene"), "--out", str(tmp_path / "run"), "--config", "quick", "--iterations", "6",
                       "--device", "cpu", "--quiet", "--no-pictures", "--viewer", "--viewer-host", "127.0.0.1",
                       "--viewer-port", str(port), "--viewer-every", "2", *overrides]) == 0
    out = capsys.readouterr().out
    assert f"viewer at http://127.0.0.1:{port}/?websocket=ws://127.0.0.1:{port}/?token=" in out
    assert f"ssh -L {port}:127.0.0.1:{port}" in out
    assert shown == [2, 4, 6, 6], "every 2 iterations, and the final model"
    assert served["status"] == 200 and "<html" in served["html"].lower()


@pytest.mark.slow
@needs_viser
def test_viewer_shows_a_copy_of_the_newest_model(tiny_run):
    from gof_warp.viz.viewer import open_run

    viewer = open_run(tiny_run, device="cpu", host="127.0.0.1", port=_free_port())
    assert viewer.mesh is not None and len(viewer.mesh.faces) == 320, "the run's mesh_*.ply is found"
    with viewer:
        g = Gaussians.random_in_box(7, sh_degree=0, device="cpu")
        viewer.update(g, iteration=3)
        assert viewer.iteration == 3 and viewer.num_gaussians == 7
        shown = viewer._gaussians.means
        assert torch.equal(shown, g.means) and shown is not g.means
        with torch.no_grad():
            g.means.add_(1.0)  # training goes on changing its model: the viewer's copy is untouched
        assert not torch.equal(viewer._gaussians.means, g.means)
