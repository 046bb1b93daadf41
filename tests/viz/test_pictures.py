"""Pictures of a run: mesh ray-cast coverage against a numpy reference, the panel PNG of a tiny trained run,
the CLI and the extract hook."""

import numpy as np
import pytest
from PIL import Image

from gof_warp.cli.pictures import main as pictures_main
from gof_warp.viz import pictures
from gof_warp.core.camera import Camera, look_at
from gof_warp.core.errors import GofError
from gof_warp.viz.pictures import BACKGROUND, panel_layout, shade_mesh

BG = np.round(np.asarray(BACKGROUND) * 255).astype(np.uint8)


# ------------------------------------------------------------------------------------ numpy reference
def _reference_hits(vertices, faces, camera: Camera, samples=1, near=0.0):
    """Closest hit face (-1 = miss) and whether it is seen from behind, per sample ray, in float64
    (Möller–Trumbore against every triangle, hits deeper than ``near`` only: the rays' parameter is the depth).
    Rays on the grid of ``kernels/raycast``."""
    s = samples
    u = (np.arange(camera.width * s) + 0.5) / s
    v = (np.arange(camera.height * s) + 0.5) / s
    uu, vv = np.meshgrid((u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, indexing="xy")
    d = (np.stack([uu, vv, np.ones_like(uu)], -1) @ camera.R).reshape(-1, 3)
    o = camera.center
    best_t = np.full(len(d), np.inf)
    best_f = np.full(len(d), -1)
    for k, (a, b, c) in enumerate(np.asarray(vertices, np.float64)[faces]):
        e1, e2 = b - a, c - a
        p = np.cross(d, e2)
        det = p @ e1
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = o - a
        bu = (p @ tv) * inv
        q = np.cross(tv, e1)
        bv = (d @ q) * inv
        t = (q @ e2) * inv
        hit = ok & (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (t > near) & (t < best_t)
        best_t[hit], best_f[hit] = t[hit], k
    fn = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    back = np.zeros(len(d), bool)
    m = best_f >= 0
    back[m] = np.einsum("ij,ij->i", fn[best_f[m]], d[m]) > 0
    shape = (camera.height * s, camera.width * s)
    return best_f.reshape(shape), back.reshape(shape)


def _cube(center=(0.0, 0.0, 0.0), half=0.5, outward=True):
    c = np.asarray(center, float)
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half + c
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]  # outward (CCW)
    f = np.array([t for a, b, cc, d in quads for t in ((a, b, cc), (a, cc, d))])
    return v, (f if outward else f[:, ::-1])


# An off-centre principal point and unequal focal lengths, a tiny image, and a pose whose pixel-centre rays
# do not graze the cube's edges.
CAM = look_at([1.9, -2.3, 1.35], [0.07, 0.03, -0.05], fx=31.0, fy=29.0, cx=13.3, cy=10.1, width=27, height=21,
              name="ref")


@pytest.mark.parametrize("outward", [True, False])
def test_shaded_cube_covers_exactly_the_reference_pixels_and_tints_back_faces(outward, device):
    v, f = _cube(outward=outward)
    img = shade_mesh(v, f, CAM, supersample=1, device=device)
    face, back = _reference_hits(v, f, CAM)
    assert img.shape == (CAM.height, CAM.width, 3) and img.dtype == np.uint8
    covered = np.any(img != BG, axis=-1)
    hit = face >= 0
    assert 40 < hit.sum() < hit.size - 40, "the test camera must see both the cube and the background"
    np.testing.assert_array_equal(covered, hit)
    assert np.all(back[hit] == (not outward)), "the reference sees all front (or all back) faces, as built"
    r, g = img[..., 0].astype(int), img[..., 1].astype(int)
    if outward:
        assert np.all(np.abs(r - g)[hit] <= 3), "front faces must be neutral grey"
    else:
        assert np.all((r - g)[hit] > 30), "faces seen from behind must be tinted red"


def test_half_inside_out_mesh_tints_exactly_the_back_faces(device):
    v, f = _cube()
    f = f.copy()
    f[::3] = f[::3, ::-1]  # flip every third triangle
    img = shade_mesh(v, f, CAM, supersample=1, device=device)
    face, back = _reference_hits(v, f, CAM)
    hit = face >= 0
    red = (img[..., 0].astype(int) - img[..., 1].astype(int)) > 30
    assert back[hit].any() and (~back[hit]).any()
    np.testing.assert_array_equal(red[hit], back[hit])


def test_one_quad_supersampled_edges_and_normals_mode(device):
    # a quad in the plane z = 0 facing +z, seen from above; pixels are background iff no sample hits it
    v = np.array([[-0.6, -0.4, 0.0], [0.5, -0.45, 0.0], [0.55, 0.5, 0.0], [-0.5, 0.45, 0.0]])
    f = np.array([[0, 1, 2], [0, 2, 3]])
    cam = look_at([0.1, -0.2, 2.0], [0.0, 0.0, 0.0], up=(0, 1, 0), fx=14.0, width=20, height=16, name="top")
    s = 3
    img = shade_mesh(v, f, cam, supersample=s, device=device)
    face, _ = _reference_hits(v, f, cam, samples=s)
    hits_per_pixel = (face >= 0).reshape(cam.height, s, cam.width, s).sum(axis=(1, 3))
    covered = np.any(img != BG, axis=-1)
    np.testing.assert_array_equal(covered, hits_per_pixel > 0)
    assert (hits_per_pixel == s * s).any() and ((hits_per_pixel > 0) & (hits_per_pixel < s * s)).any()
    # normals mode: the quad's colour is (n + 1) / 2 = (0.5, 0.5, 1) everywhere, so each pixel is the
    # coverage-weighted mean of that and the background
    normals = shade_mesh(v, f, cam, supersample=s, mode="normals", device=device)
    frac = (hits_per_pixel / (s * s))[..., None]
    expected = np.round((frac * np.array([0.5, 0.5, 1.0]) + (1 - frac) * np.asarray(BACKGROUND)) * 255)
    np.testing.assert_allclose(normals, expected, atol=1)


@pytest.mark.parametrize("mode", ["shaded", "normals"])
def test_one_cast_mesh_drawn_from_many_cameras_matches_shading_each_alone(mode, device):
    v, f = _cube()
    f = f.copy()
    f[::3] = f[::3, ::-1]  # front and back faces both in view
    cast = pictures.CastMesh.build(v, f, device)
    cams = [CAM] + [look_at([2.0 * np.cos(a), 1.2, 2.0 * np.sin(a)], [0.0, 0.0, 0.0], up=(0, 1, 0), fx=18.0, width=21,
                            height=17, name=f"c{a:.1f}") for a in (0.3, 2.0, 4.1)]
    for cam in cams:
        np.testing.assert_array_equal(pictures.shade_cast_mesh(cast, cam, mode=mode, supersample=2),
                                      shade_mesh(v, f, cam, mode=mode, supersample=2, device=device))


def test_shade_mesh_validates_its_inputs():
    v, f = _cube()
    with pytest.raises(ValueError, match="faces"):
        shade_mesh(v, f + 100, CAM)
    with pytest.raises(ValueError, match="vertices"):
        shade_mesh(v[:, :2], f, CAM)
    with pytest.raises(ValueError, match="mode"):
        shade_mesh(v, f, CAM, mode="wire")
    empty = shade_mesh(v, np.zeros((0, 3), int), CAM)
    assert np.all(empty == BG)


def _two_quads():
    """A small quad at depth 2 (wound away from the camera: drawn red) in front of a large one at depth 3 facing it,
    seen by a camera at z = 3 looking straight down."""
    small = np.array([[-0.3, -0.3, 1.0], [0.3, -0.3, 1.0], [0.3, 0.3, 1.0], [-0.3, 0.3, 1.0]])
    large = np.array([[-2.0, -2.0, 0.0], [2.0, -2.0, 0.0], [2.0, 2.0, 0.0], [-2.0, 2.0, 0.0]])
    v = np.concatenate([small, large])
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]])
    cam = look_at([0.0, 0.0, 3.0], [0.0, 0.0, 0.0], up=(0, 1, 0), fx=20.0, width=24, height=18, name="down")
    return v, f, cam


def test_near_plane_hides_what_lies_in_front_of_it(device):
    """A surface in front of the camera's clip is not drawn: the mesh picture then shows what the Gaussian render
    beside it shows (the renderer clips at the same plane). Golden case: with the clip between the two quads, the
    pixels of the small one see the large one, at its depth."""
    import warp as wp

    from gof_warp.kernels import raycast

    v, f, cam = _two_quads()
    for near, small_seen in ((0.0, True), (1.5, True), (2.5, False)):
        face, _ = _reference_hits(v, f, cam, near=near)
        img = shade_mesh(v, f, cam, supersample=1, device=device, near=near)
        assert np.all(face >= 0)  # the large quad fills the view
        assert np.isin(face, (0, 1)).any() == small_seen
        mesh = wp.Mesh(points=wp.array(v.astype(np.float32), dtype=wp.vec3, device=device),
                       indices=wp.array(f.astype(np.int32).ravel(), dtype=wp.int32, device=device))
        hits = raycast.cast_pinhole_rays(mesh, cam.R, cam.t, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                                         min_depth=near)
        quad = hits["face"].numpy() // 2  # pixel centres on a quad's diagonal may hit either of its triangles
        np.testing.assert_array_equal(quad, face // 2)
        depth = hits["depth"].numpy()
        np.testing.assert_allclose(depth[quad == 1], 3.0, atol=1e-4)  # depths stay camera z, not from the plane
        np.testing.assert_allclose(depth[quad == 0], 2.0, atol=1e-4)
        red = (img[..., 0].astype(int) - img[..., 1].astype(int)) > 30
        np.testing.assert_array_equal(red, face // 2 == 0)
    with pytest.raises(ValueError, match="min_depth"):
        raycast.cast_pinhole_rays(mesh, cam.R, cam.t, cam.fx, cam.fy, cam.cx, cam.cy, 4, 3, min_depth=-1.0)


@pytest.mark.slow
def test_mesh_column_is_clipped_where_the_render_is(tiny_run):
    """view_panels draws the mesh from the larger of render.near and the camera's own clip, as the renderer does."""
    import dataclasses

    from gof_warp.core.model import Gaussians
    from gof_warp.rendering.render import RenderConfig

    run, _ = tiny_run
    g = Gaussians.load_ply(run / "point_cloud.ply", device="cpu")
    v, f, cam = _two_quads()
    for cam_near, cfg_near, expect in ((0.0, 0.01, 0.0), (2.5, 0.01, 2.5), (0.0, 2.5, 2.5), (1.0, 2.5, 2.5)):
        c = dataclasses.replace(cam, near=cam_near)
        panels = pictures.view_panels(g, [c], mesh=(v, f), render_config=RenderConfig(near=cfg_near), device="cpu")
        x0, y0, x1, y1 = panels.boxes[(0, "mesh")]
        np.testing.assert_array_equal(panels.image[y0:y1, x0:x1], shade_mesh(v, f, c, device="cpu", near=expect))
    assert not np.array_equal(shade_mesh(v, f, cam, device="cpu"), shade_mesh(v, f, cam, device="cpu", near=2.5))


# --------------------------------------------------------------------------------------- a tiny run
TINY = {
    "iterations": 12,
    "checkpoint_every": 100,
    "log_every": 4,
    "model": {"sh_degree": 0, "init": "random", "random_init_points": 400},
    "optim": {"means_lr_max_steps": 12},
    "densify": {"start_iter": 100, "stop_iter": 100, "filter_3d_until_iter": 0},
    "loss": {"regularization_from_iter": 100},
}


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A trained run laid out as the built-in default run: RUN/scene holds the scene (with its ground-truth
    mesh), 40x30 images (no downscaling in the picture)."""
    from gof_warp.core.config import merge
    from gof_warp.data import load_scene
    from gof_warp.synthetic import make_scene
    from gof_warp.training.trainer import TrainConfig, Trainer

    run = tmp_path_factory.mktemp("pics") / "run"
    make_scene("default", run / "scene", views=5, resolution=(40, 30), device="cpu")
    scene = load_scene(run / "scene")
    trainer = Trainer(scene, merge(TrainConfig(), TINY), run, "cpu")
    trainer.run()
    return run, scene


def _columns_of(png, columns, scene, k):
    cams = [v.camera for v in scene.test] or [v.camera for v in scene.train]
    idx = sorted(set(np.round(np.linspace(0, len(cams) - 1, min(k, len(cams)))).astype(int).tolist()))
    width, height, boxes = panel_layout(columns, [(cams[i].width, cams[i].height) for i in idx])
    img = np.asarray(Image.open(png).convert("RGB"))
    assert img.shape == (height, width, 3)
    return img, boxes, idx


@pytest.mark.slow
def test_run_pictures_with_mesh_show_photo_render_and_mesh(tiny_run):
    run, scene = tiny_run
    paths = pictures.write_run_pictures(run, mesh_path=run / "scene" / "gt_mesh.ply", views=2, device="cpu")
    assert paths == [run / "pictures" / "mesh_gt_mesh.png"] and paths[0].is_file()
    columns = ["photo", "render", "depth", "normal", "mesh"]
    img, boxes, idx = _columns_of(paths[0], columns, scene, 2)
    views = scene.test or scene.train
    for r, i in enumerate(idx):

        def tile(name):
            x0, y0, x1, y1 = boxes[(r, name)]
            return img[y0:y1, x0:x1]

        np.testing.assert_array_equal(tile("photo"), views[i].image)
        mesh = tile("mesh").astype(float)
        not_bg = np.any(tile("mesh") != BG, axis=-1).mean()
        assert 0.05 < not_bg < 0.999 and mesh.std() > 10, f"mesh tile of row {r} looks blank"
        assert tile("render").astype(float).std() > 5 and tile("depth").astype(float).std() > 5
    assert not list((run / "pictures").glob(".*.tmp"))


@pytest.mark.slow
def test_run_pictures_without_photos_still_show_the_model(tiny_run, tmp_path, caplog):
    run, scene = tiny_run
    bare = tmp_path / "bare"
    bare.mkdir()
    for name in ("point_cloud.ply", "cameras.json", "config.yaml"):
        (bare / name).write_bytes((run / name).read_bytes())
    with caplog.at_level("INFO", logger="gof_warp.viz.pictures"):
        (path,) = pictures.write_run_pictures(bare, views=3, device="cpu")
    assert path == bare / "pictures" / "views.png"
    assert "photo column is left out" in caplog.text
    _columns_of(path, ["render", "depth", "normal"], scene, 3)


@pytest.mark.slow
def test_wide_cameras_are_scaled_to_the_width_limit(tiny_run):
    from gof_warp.core.model import Gaussians

    run, scene = tiny_run
    g = Gaussians.load_ply(run / "point_cloud.ply", device="cpu")
    cam = scene.train[0].camera
    panels = pictures.view_panels(g, [cam], photos=[scene.train[0].image], max_width=120)
    assert panels.image.shape[1] <= 120 and panels.columns == ["photo", "render", "depth", "normal"]


@pytest.mark.slow
def test_cli_writes_the_picture_and_reports_errors_in_one_line(tiny_run, tmp_path, capsys):
    run, _ = tiny_run
    assert pictures_main([str(run), "--views", "1", "--out", str(tmp_path / "p"), "--device", "cpu", "--quiet"]) == 0
    assert (tmp_path / "p" / "views.png").is_file()
    capsys.readouterr()
    assert pictures_main([str(tmp_path / "nothing"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "neither a run folder" in err and err.count("\n") == 1
    assert pictures_main([str(run), "--mesh", str(tmp_path / "none.ply"), "--quiet"]) == 2
    assert "none.ply" in capsys.readouterr().err


@pytest.mark.slow
def test_extract_writes_the_mesh_picture_unless_told_not_to(tiny_run, tmp_path, monkeypatch, caplog):
    from gof_warp.cli import extract

    run, _ = tiny_run
    cube = _cube(half=0.4)
    monkeypatch.setattr(extract, "extract_mesh", lambda *a, **k: [cube])  # the hook is under test, not extraction
    out = tmp_path / "m.ply"
    args = [str(run), "--out", str(out), "--device", "cpu", "--quiet"]
    assert extract.main(args + ["--no-pictures"]) == 0
    assert out.is_file() and not (run / "pictures" / "mesh_m.png").exists()
    assert extract.main(args) == 0
    picture = np.asarray(Image.open(run / "pictures" / "mesh_m.png"))
    assert picture.shape[1] == panel_layout(["photo", "render", "depth", "normal", "mesh"], [(40, 30)])[0]
    # drawn from the model and mesh in memory: the same picture as from the files written
    (again,) = pictures.write_run_pictures(run, mesh_path=out, out_dir=tmp_path / "again", device="cpu")
    np.testing.assert_array_equal(np.asarray(Image.open(again)), picture)
    with pytest.raises(GofError, match="mesh_path"):
        pictures.write_run_pictures(run, mesh=cube, out_dir=tmp_path / "again", device="cpu")

    def broken(*a, **k):
        raise RuntimeError("no pictures today")

    monkeypatch.setattr(pictures, "write_run_pictures", broken)
    out.unlink()
    with caplog.at_level("WARNING", logger="gof_warp.cli.extract"):
        assert extract.main(args) == 0
    assert out.is_file() and "no pictures today" in caplog.text


@pytest.mark.slow
def test_run_pictures_draw_a_coloured_glb_in_its_colour(tiny_run, tmp_path):
    """``pictures --mesh X.glb``: the file's vertex colours reach the mesh column (a flat-coloured mesh: every covered
    pixel exactly its colour), titled "coloured mesh"."""
    import trimesh

    from gof_warp.mesh.export import save_mesh_file

    run, scene = tiny_run
    gt = trimesh.load(run / "scene" / "gt_mesh.ply", process=False, force="mesh")
    colour = np.array([30, 160, 220], np.uint8)
    save_mesh_file(tmp_path / "mesh_flat.glb", gt.vertices, gt.faces, np.tile(colour, (len(gt.vertices), 1)))
    from gof_warp.viz.mesh_files import load_mesh_file

    colour = load_mesh_file(tmp_path / "mesh_flat.glb").vertex_colors[0]  # through glTF's linear 8 bits
    assert np.abs(colour.astype(int) - [30, 160, 220]).max() <= 2
    assert pictures_main([str(run), "--mesh", str(tmp_path / "mesh_flat.glb"), "--views", "1", "--out",
                          str(tmp_path / "p"), "--device", "cpu", "--quiet"]) == 0
    columns = ["photo", "render", "depth", "normal", "mesh"]
    img, boxes, _ = _columns_of(tmp_path / "p" / "mesh_flat.png", columns, scene, 1)
    x0, y0, x1, y1 = boxes[(0, "mesh")]
    tile = img[y0:y1, x0:x1].reshape(-1, 3)
    is_colour, is_bg = (tile == colour).all(1), (tile == BG).all(1)
    assert is_colour.mean() > 0.05, "the mesh is drawn in its colour"
    # edge pixels average the colour with the background: every pixel is a mix of the two
    mix = (tile.astype(float) - BG) / (colour.astype(float) - BG)
    assert np.abs(mix - mix[:, :1]).max() < 0.05 and (is_colour | is_bg).mean() > 0.8
