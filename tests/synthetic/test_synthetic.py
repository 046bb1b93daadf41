"""Synthetic scenes: ray casting vs float64 references, an analytic sphere, the Blender files, the CLI."""

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
import warp as wp
from PIL import Image

from gof_warp import Camera, GofError, look_at
from gof_warp.kernels import raycast
from gof_warp.synthetic import RayCaster, get_preset, list_presets, make_scene, with_rig
from gof_warp.synthetic import meshes as M
from gof_warp.synthetic.__main__ import main as cli_main
from gof_warp.synthetic.render import Lighting

# float32 ray casting at depths ~4: a few ulps of the ray parameter and of the vertex coordinates.
DEPTH_ATOL = 2e-5
# float32 unit normals / colours from float32 arithmetic.
UNIT_ATOL = 2e-5
# Hits within this barycentric margin of a triangle edge may legitimately land on either neighbour.
EDGE_MARGIN = 1e-4
TINY = (20, 16)


# ----------------------------------------------------------------------------------------- references
def bruteforce_cast(o, dirs, V, F):
    """float64 closest hits of rays ``o + t * dirs[k]`` against every triangle (Moller-Trumbore).

    Returns ``t``, ``face`` (-1 = miss), Warp barycentrics ``u`` (weight of p0), ``v`` (of p1) and the
    smallest barycentric (distance to an edge) of each hit."""
    p0, p1, p2 = (V[F[:, k]][None] for k in range(3))  # [1, F, 3]
    d = dirs[:, None]  # [P, 1, 3]
    e1, e2, tvec = p1 - p0, p2 - p0, o - p0
    pvec, qvec = np.cross(d, e2), np.cross(tvec, e1)  # [P, F, 3], [1, F, 3]
    det = (e1 * pvec).sum(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        b1 = (tvec * pvec).sum(-1) / det
        b2 = (d * qvec).sum(-1) / det
        t = (e2 * qvec).sum(-1) / det
    ok = (np.abs(det) > 1e-15) & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > 0)
    t = np.where(ok, t, np.inf)
    face = np.argmin(t, axis=1)
    rows = np.arange(len(dirs))
    tmin = t[rows, face]
    hit = np.isfinite(tmin)
    b1, b2 = b1[rows, face], b2[rows, face]
    margin = np.minimum(np.minimum(b1, b2), 1 - b1 - b2)
    return np.where(hit, tmin, 0.0), np.where(hit, face, -1), 1 - b1 - b2, b1, margin


def pixel_dirs(cam: Camera, samples=1):
    """World ray directions ``[H*s*W*s, 3]`` (camera z = 1) of the sample grid, float64."""
    u = (np.arange(cam.width * samples) + 0.5) / samples
    v = (np.arange(cam.height * samples) + 0.5) / samples
    uu, vv = np.meshgrid(u, v, indexing="xy")
    d_cam = np.stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones_like(uu)], -1).reshape(-1, 3)
    return d_cam @ cam.R


def sphere_depth(o, dirs, r):
    """Closed-form z-depth of the first hit of ``o + t d`` on the sphere ``|x| = r`` (nan = miss)."""
    a = np.einsum("ki,ki->k", dirs, dirs)
    b = 2 * dirs @ o
    disc = b * b - 4 * a * (o @ o - r * r)
    with np.errstate(invalid="ignore"):
        return (-b - np.sqrt(disc)) / (2 * a)


def bilinear_repeat(tex, uv):
    """float64 bilinear texture lookup, repeat addressing, OBJ uv (v up, texel centres at (i + 0.5) / W)."""
    h, w = tex.shape[:2]
    x, y = uv[0] * w - 0.5, (1 - uv[1]) * h - 0.5
    x0, y0 = int(np.floor(x)), int(np.floor(y))
    fx, fy = x - x0, y - y0
    t = tex.astype(np.float64)
    row = [(1 - fx) * t[j % h, x0 % w] + fx * t[j % h, (x0 + 1) % w] for j in (y0, y0 + 1)]
    return (1 - fy) * row[0] + fy * row[1]


def sphere_bounds(part):
    """Inner radius (the inscribed polytope contains the ball of this radius) and the largest angle
    between a face normal and the radial direction of any point on that face."""
    V = part.vertices.astype(np.float32).astype(np.float64)
    n = M.face_normals(V, part.faces)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    r_in = np.einsum("fi,fi->f", n, V[part.faces[:, 0]]).min()
    radial = V[part.faces] / np.linalg.norm(V[part.faces], axis=2, keepdims=True)
    return r_in, np.arccos(np.clip(np.einsum("fi,fki->fk", n, radial), -1, 1)).max()


# ----------------------------------------------------------------------------------------- kernels
@pytest.mark.parametrize("principal", [(0.5, 0.5), (0.62, 0.41)])
def test_cast_matches_float64_bruteforce(device, principal):
    back = M.plane(half_size=3.0).transformed(M.rotation_about((1, 0, 0), np.pi), (0, 0, -1.3))  # seen from behind
    part = M.concatenate([M.sphere(radius=1.0, subdivisions=2), M.box(center=(0.6, 0.5, 0.9), size=(0.5, 0.3, 0.4)),
                          back], "three")
    cam = look_at((2.5, -2.0, 1.5), (0.1, 0, 0.1), fx=30.0, fy=27.0, cx=principal[0] * 24, cy=principal[1] * 20,
                  width=24, height=20)
    caster = RayCaster([part], device=device)
    hits = {k: a.numpy().reshape(cam.height * cam.width, -1) for k, a in caster.cast(cam).items()}
    dirs = pixel_dirs(cam)
    V = caster.points.astype(np.float64)
    t, face, u, v, margin = bruteforce_cast(cam.center, dirs, V, caster.faces)
    clear = (face < 0) | (margin > EDGE_MARGIN)
    assert clear.mean() > 0.9 and (face >= 0).sum() > 100 and (face >= len(caster.faces) - 2).sum() > 20
    np.testing.assert_array_equal(hits["face"][clear, 0] >= 0, face[clear] >= 0)
    np.testing.assert_array_equal(hits["face"][clear, 0], face[clear])
    np.testing.assert_allclose(hits["depth"][clear, 0], t[clear], atol=DEPTH_ATOL)
    on = clear & (face >= 0)
    np.testing.assert_allclose(hits["bary"][on], np.stack([u, v], 1)[on], atol=1e-4)
    n_ref = M.face_normals(V, caster.faces)[face[on]]
    n_ref /= np.linalg.norm(n_ref, axis=1, keepdims=True)
    n_ref *= -np.sign(np.einsum("ki,ki->k", n_ref, dirs[on]))[:, None]  # turned to face the camera
    np.testing.assert_allclose(hits["normal"][on], n_ref, atol=UNIT_ATOL)
    assert np.all(hits["normal"][face < 0] == 0) and np.all(hits["depth"][face < 0] == 0)


def test_shading_matches_float64_reference(device):
    """Texture (bilinear, repeat addressing, uv outside [0, 1]) and constant materials under two lights."""
    rng = np.random.default_rng(3)
    tex = rng.uniform(size=(3, 5, 3)).astype(np.float32)
    quad = M.plane(half_size=1.0, role="object").transformed(M.rotation_about((1, 0, 0), np.pi))  # back to camera
    quad.corner_uvs = np.array([[-0.3, -0.2], [1.7, -0.2], [1.7, 1.4], [-0.3, 1.4]])[quad.faces]
    quad.material = M.Material(kind="texture", color_a=(0.9, 1.0, 0.8), texture=tex)
    plain = M.box(center=(0, 0, -0.5), size=(3, 3, 0.2), material=M.Material(kind="constant", color_a=(0.3, 0.6, 0.9)))
    light = Lighting(directions=((0.3, -0.2, 1.0), (-1.0, 0.4, -0.2)), intensities=(0.7, 0.4), ambient=0.2)
    cam = look_at((0.4, -0.8, 3.0), (0, 0, 0), up=(0, 1, 0), fx=20.0, width=26, height=22)
    caster = RayCaster([quad, plain], lighting=light, device=device)
    hits = caster.cast(cam)
    rgb = raycast.shade_hits(hits, caster.shading, caster.lights, light.ambient, 0).numpy().reshape(-1, 3)
    face = hits["face"].numpy().ravel()
    b = hits["bary"].numpy().reshape(-1, 2)
    n_geo = hits["normal"].numpy().reshape(-1, 3).astype(np.float64)
    w = np.concatenate([b, 1 - b.sum(1, keepdims=True)], 1).astype(np.float64)
    ref = np.zeros_like(rgb, dtype=np.float64)
    on = face >= 0
    assert (caster.face_part[face[on]] == 0).sum() > 50 and (caster.face_part[face[on]] == 1).sum() > 50
    for k in np.nonzero(on)[0]:
        f = face[k]
        if caster.face_part[f] == 0:
            albedo = np.array([0.9, 1.0, 0.8]) * bilinear_repeat(tex, w[k] @ quad.corner_uvs[f])
        else:
            albedo = np.array([0.3, 0.6, 0.9])
        vn = caster.shading["vertex_normals"].numpy()[caster.faces[f]].astype(np.float64)
        n = w[k] @ vn
        n /= np.linalg.norm(n)
        n *= np.sign(n @ n_geo[k])
        ref[k] = albedo * (light.ambient + np.maximum(light.vectors().astype(np.float64) @ n, 0).sum())
    np.testing.assert_allclose(rgb, ref, atol=UNIT_ATOL * 10)


@pytest.mark.slow
def test_procedural_albedo_properties(device):
    """Procedural colours stay between the two colours (times irradiance), vary, and depend on the seed."""
    mat = M.Material(color_a=(0.2, 0.1, 0.0), color_b=(0.8, 0.9, 0.5), noise_scale=4.0)
    part = M.sphere(subdivisions=3, material=mat)
    light = Lighting(directions=((0, 0, 1),), intensities=(0.0,), ambient=1.0)  # irradiance 1: rgb = albedo
    cam = look_at((0, -3, 0.5), (0, 0, 0), fx=40.0, width=32, height=32)
    out = [RayCaster([part], light, seed=s, device=device).render(cam, supersample=1) for s in (0, 0, 1)]
    rgb = out[0].rgba[..., :3][out[0].mask]
    assert np.all(rgb >= np.array(mat.color_a) - 1e-6) and np.all(rgb <= np.array(mat.color_b) + 1e-6)
    assert rgb.std(axis=0).min() > 0.03
    np.testing.assert_array_equal(out[0].rgba, out[1].rgba)
    assert np.abs(out[0].rgba - out[2].rgba).max() > 0.1
    # The shaded colour is the albedo at the ray's hit point o + z d (view independent).
    origin, dirs = cam.pixel_rays()
    x = (origin + out[0].depth[..., None] * dirs)[out[0].mask]
    albedo = wp.zeros(len(x), dtype=wp.vec3, device=device)
    wp.launch(_albedo_at, dim=len(x), inputs=[wp.array(x.astype(np.float32), dtype=wp.vec3, device=device),
              wp.vec3(*mat.color_a), wp.vec3(*mat.color_b), wp.vec4(mat.noise_scale, 0.0, 0.0, 0.0)],
              outputs=[albedo], device=device)
    np.testing.assert_allclose(rgb, albedo.numpy(), atol=1e-4)


@pytest.mark.parametrize("supersample", [1, 2, 3])
def test_resolve_matches_float64_box_filter(device, supersample):
    """Colour = mean of the clamped colours of the hit samples (centre + s x s grid); alpha = hit fraction."""
    parts = [M.sphere(radius=0.8, subdivisions=2), M.box(center=(0.9, 0, 0), size=(0.4, 0.4, 0.4))]
    light = Lighting(intensities=(1.5, 0.5))  # bright enough to clamp somewhere
    caster = RayCaster(parts, light, device=device)
    cam = look_at((0.5, -3, 1), (0.2, 0, 0), fx=24.0, width=21, height=17)
    view = caster.render(cam, supersample)
    grids = [(1, caster.cast(cam, 1))] + ([(supersample, caster.cast(cam, supersample))] if supersample > 1 else [])
    hits, color = np.zeros((17, 21)), np.zeros((17, 21, 3))
    for s, h in grids:
        rgb = np.clip(raycast.shade_hits(h, caster.shading, caster.lights, light.ambient, 0).numpy(), 0, 1)
        hit = (h["face"].numpy() >= 0).astype(np.float64)
        hits += hit.reshape(17, s, 21, s).sum((1, 3))
        color += (rgb * hit[..., None]).reshape(17, s, 21, s, 3).sum((1, 3))
    assert np.any(hits == 0) and np.any(hits == (1 + supersample**2 if supersample > 1 else 1))
    ref_rgb = np.where(hits[..., None] > 0, color / np.maximum(hits, 1)[..., None], 0)
    np.testing.assert_allclose(view.rgba[..., :3], ref_rgb, atol=UNIT_ATOL)
    np.testing.assert_allclose(view.rgba[..., 3], hits / (1 + supersample**2 if supersample > 1 else 1), atol=1e-7)


@wp.kernel
def _albedo_at(x: wp.array(dtype=wp.vec3), a: wp.vec3, b: wp.vec3, params: wp.vec4, out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = raycast.procedural_albedo(0, 0, x[i], a, b, params)


# ----------------------------------------------------------------------------------------- analytic sphere
@pytest.mark.parametrize("principal", [(0.5, 0.5), (0.3, 0.65)])
def test_sphere_depth_normal_mask_alpha_closed_form(device, principal):
    part = get_preset("sphere").build(None)[0]
    r_in, theta_max = sphere_bounds(part)
    assert 1 - r_in < 2e-3 and theta_max < 0.05  # the preset's mesh is a close approximation
    W, H = 40, 32
    cam = look_at((1.0, -3.2, 1.4), (0.15, 0.1, -0.05), fx=38.0, fy=40.0, cx=principal[0] * W, cy=principal[1] * H,
                  width=W, height=H)
    view = RayCaster([part], device=device).render(cam, supersample=2)
    dirs = pixel_dirs(cam)
    o = cam.center
    t_out, t_in = sphere_depth(o, dirs, 1.0), sphere_depth(o, dirs, r_in)
    inner, outer = np.isfinite(t_in), np.isfinite(t_out)
    mask, depth = view.mask.ravel(), view.depth.ravel().astype(np.float64)
    # Mask: every ray through the inscribed ball hits the mesh; every ray missing the sphere misses it.
    assert inner.sum() > 200 and np.all(mask[inner]) and not np.any(mask[~outer])
    # Depth: the convex mesh lies between the two spheres, so its z-depth lies between theirs.
    assert np.all(depth[inner] >= t_out[inner] - DEPTH_ATOL) and np.all(depth[inner] <= t_in[inner] + DEPTH_ATOL)
    assert np.all(depth[~mask] == 0)
    # Normals: within the largest face-to-radial angle of the closed form (x - c) / r.
    x = o + depth[mask, None] * dirs[mask]
    radial = x / np.linalg.norm(x, axis=1, keepdims=True)
    cos = np.einsum("ki,ki->k", view.normal.reshape(-1, 3)[mask].astype(np.float64), radial)
    assert cos.min() >= np.cos(theta_max) - UNIT_ATOL
    # Alpha: 5 samples (centre + 2x2); the hit count is bracketed by the analytic counts of both spheres.
    offsets = [(0.5, 0.5), (0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75)]
    n_in, n_out = np.zeros(H * W), np.zeros(H * W)
    for du, dv in offsets:
        shifted = Camera(R=cam.R, t=cam.t, fx=cam.fx, fy=cam.fy, cx=cam.cx + 0.5 - du, cy=cam.cy + 0.5 - dv,
                         width=W, height=H)
        d = pixel_dirs(shifted)
        n_in += np.isfinite(sphere_depth(o, d, r_in))
        n_out += np.isfinite(sphere_depth(o, d, 1.0))
    hits = view.rgba[..., 3].ravel() * 5
    assert np.all(hits >= n_in - 1e-4) and np.all(hits <= n_out + 1e-4)
    fractional = (hits > 0.5) & (hits < 4.5)
    assert fractional.sum() > 10 and np.all((n_in[fractional] < 5) & (n_out[fractional] > 0))  # only at the rim
    assert np.all(view.rgba[..., 3].ravel()[inner & (n_in == 5)] == 1.0)


# ----------------------------------------------------------------------------------------- scene files
def _read(folder, split="train"):
    return json.loads((folder / f"transforms_{split}.json").read_text())


def test_blender_round_trip_off_centre(tmp_path):
    preset = with_rig(get_preset("sphere"), principal_offset=(0.12, -0.08))
    out = make_scene(preset, tmp_path / "s", views=3, resolution=(36, 28), seed=5, device="cpu")
    meta = _read(out)
    part = preset.build(None)[0]
    r_in, _ = sphere_bounds(part)
    assert {"camera_angle_x", "fl_x", "fl_y", "cx", "cy", "w", "h", "frames"} <= meta.keys()
    assert (meta["w"], meta["h"]) == (36, 28) and len(meta["frames"]) == 3 and len(_read(out, "test")["frames"]) == 4
    assert meta["cx"] == pytest.approx(36 * 0.62) and meta["cy"] == pytest.approx(28 * 0.42)
    assert meta["fl_x"] == pytest.approx(36 / 2 / np.tan(meta["camera_angle_x"] / 2))
    train, _ = preset.rig.cameras(36, 28, 3, seed=5)
    for frame, expected in zip(meta["frames"], train):
        cam = Camera.from_c2w(frame["transform_matrix"], meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"],
                              meta["w"], meta["h"], opengl=True)
        np.testing.assert_allclose(cam.R, expected.R, atol=1e-12)
        uv, z = cam.project(np.zeros((1, 3)))  # the rig looks at the sphere's centre
        np.testing.assert_allclose(uv[0], [meta["cx"], meta["cy"]], atol=1e-9)
        with Image.open(out / (frame["file_path"] + ".png")) as im:
            assert im.mode == "RGBA" and im.size == (36, 28)
            alpha = np.asarray(im)[..., 3]
        depth = np.load(out / frame["depth_path"])
        normal = np.load(out / frame["normal_path"])
        assert depth.dtype == np.float32 and depth.shape == (28, 36) and normal.shape == (28, 36, 3)
        hit = depth > 0
        assert np.all(alpha[hit] > 0) and np.all(hit[alpha == 255]) and hit.sum() > 50
        # Unprojected z-depth lands on the mesh, which lies between the inner and the outer sphere.
        origin, dirs = cam.pixel_rays()
        radius = np.linalg.norm(origin + depth[hit, None] * dirs[hit], axis=1)
        assert radius.min() > r_in - 1e-4 and radius.max() < 1 + 1e-4
        np.testing.assert_allclose(np.linalg.norm(normal[hit], axis=1), 1, atol=UNIT_ATOL)
    scene = json.loads((out / "scene.json").read_text())
    assert scene["preset"] == "sphere" and scene["seed"] == 5 and scene["resolution"] == [36, 28]
    np.testing.assert_allclose(scene["object_bbox"], [[-1] * 3, [1] * 3], atol=1e-6)


@pytest.mark.parametrize("name", ["default", "background", "garden", "sparse"])
def test_rig_views_distinct_and_inside_band(name):
    rig = get_preset(name).rig
    train, test = rig.cameras(64, 48, seed=3)
    assert (len(train), len(test)) == (rig.n_train, rig.n_test)
    c_train, c_test = (np.stack([c.center for c in cams]) - rig.target for cams in (train, test))
    gap = np.linalg.norm(c_test[:, None] - c_train[None], axis=2).min()
    # no test view repeats a train view (spiral spacing shrinks as 1/sqrt(n): garden has 100 train views)
    assert gap > 0.05 * rig.radius * min(1.0, np.sqrt(40 / rig.n_train))
    for c in np.concatenate([c_train, c_test]):
        assert np.linalg.norm(c) == pytest.approx(rig.radius)
        assert rig.elevation_deg[0] <= np.degrees(np.arcsin(c[2] / rig.radius)) <= rig.elevation_deg[1]
    for cam in train + test:  # every camera looks at the target
        np.testing.assert_allclose(cam.project(np.array([rig.target]))[0][0], [cam.cx, cam.cy], atol=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("name", list_presets())
def test_every_preset_generates(tmp_path, name, shared_data_or_none):
    if name == "spot" and shared_data_or_none is None:
        with pytest.raises(GofError, match="spot"):
            make_scene(name, tmp_path / name, views=2, resolution=TINY, device="cpu")
        pytest.skip("../shared/data is absent: checked the clear error only")
    out = make_scene(name, tmp_path / name, views=2, resolution=TINY, device="cpu")
    mesh = trimesh.load(out / "gt_mesh.ply", process=False)
    parts = get_preset(name).build(None)
    assert len(mesh.faces) == sum(len(p.faces) for p in parts)
    scene = json.loads((out / "scene.json").read_text())
    lo, hi = np.array(scene["object_bbox"])
    assert np.all(hi > lo) and np.all(mesh.bounds[0] <= lo + 1e-6) and np.all(mesh.bounds[1] >= hi - 1e-6)
    if scene["background"] == "geometry":
        obj = trimesh.load(out / "gt_object.ply", process=False)
        np.testing.assert_allclose(obj.bounds, [lo, hi], atol=1e-6)
    alphas = [np.asarray(Image.open(out / (f["file_path"] + ".png")))[..., 3] for f in _read(out)["frames"]]
    assert all(a.max() == 255 for a in alphas)


@pytest.fixture
def shared_data_or_none():
    spot = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "spot"
    return spot if spot.is_dir() else None


def test_spot_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(GofError, match="needs a textured OBJ"):
        make_scene("spot", tmp_path / "o", mesh_path=tmp_path / "nothing_here", resolution=TINY, device="cpu")
    assert not (tmp_path / "o").exists()


def test_deterministic_bytes_and_seed(tmp_path):
    runs = [make_scene("sparse", tmp_path / f"r{k}", resolution=TINY, seed=s, device="cpu")
            for k, s in enumerate((7, 7, 8))]

    def files(d):
        return {p.relative_to(d): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}

    a, b, c = (files(r) for r in runs)
    assert a.keys() == b.keys() and all(a[k] == b[k] for k in a)
    assert a[next(k for k in a if k.suffix == ".png")] != c[next(k for k in c if k.suffix == ".png")]


def test_interrupted_run_leaves_nothing_and_overwrite_rules(tmp_path, monkeypatch):
    from gof_warp.synthetic import writer

    calls = []
    real = writer.write_view

    def failing(*args):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(writer, "write_view", failing)
    with pytest.raises(KeyboardInterrupt):
        make_scene("sphere", tmp_path / "s", views=4, resolution=TINY, device="cpu")
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(writer, "write_view", real)

    (tmp_path / "s").mkdir()  # an empty folder is fine
    make_scene("sphere", tmp_path / "s", views=1, resolution=TINY, device="cpu")
    with pytest.raises(GofError, match="not empty"):
        make_scene("sphere", tmp_path / "s", views=2, resolution=TINY, device="cpu")
    (tmp_path / "s" / "stale.txt").write_text("old")
    make_scene("sphere", tmp_path / "s", views=2, resolution=TINY, device="cpu", force=True)
    assert not (tmp_path / "s" / "stale.txt").exists() and len(_read(tmp_path / "s")["frames"]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]


# ----------------------------------------------------------------------------------------- meshes, CLI
@pytest.mark.parametrize("make, volume", [
    (lambda: M.sphere(radius=0.7, subdivisions=3), 4 / 3 * np.pi * 0.7**3),
    (lambda: M.box(size=(0.3, 0.5, 0.7), rotation=M.rotation_about((1, 2, 3), 0.4)), 0.3 * 0.5 * 0.7),
    (lambda: M.torus(major=0.5, minor=0.1), 2 * np.pi**2 * 0.5 * 0.1**2),
    (lambda: M.cylinder((0, 0, 0), (0.2, 0.3, 0.9), 0.05, sides=64), np.pi * 0.05**2 * np.sqrt(0.94)),
    (lambda: M.torus_knot(), None),
])
def test_meshes_closed_outward(make, volume):
    part = make()
    mesh = trimesh.Trimesh(part.vertices, part.faces, process=False)
    mesh.merge_vertices()
    assert mesh.is_watertight and mesh.volume > 0
    if volume is not None:
        assert mesh.volume == pytest.approx(volume, rel=0.02)
    fn = M.face_normals(part.vertices, part.faces)
    assert np.all(np.einsum("fi,fi->f", fn, part.vertex_normals[part.faces].sum(1)) > 0)


def test_obj_loader_quads_negative_indices_and_mtl(tmp_path):
    Image.fromarray(np.full((4, 4, 3), 200, np.uint8)).save(tmp_path / "t.png")
    (tmp_path / "m.mtl").write_text("newmtl a\nmap_Kd t.png\n")
    (tmp_path / "m.obj").write_text(
        "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f 1/1 2/2 3/3 4/4\nf -4/-4 -2/-2 -1/-1\n")
    m = M.load_textured_obj(tmp_path / "m.obj")
    assert m.faces.tolist() == [[0, 1, 2], [0, 2, 3], [0, 2, 3]]
    np.testing.assert_allclose(m.corner_uvs[1], [[0, 0], [1, 1], [0, 1]])
    assert m.material.kind == "texture" and m.material.texture.shape == (4, 4, 3)
    with pytest.raises(GofError, match="out of range"):
        (tmp_path / "bad.obj").write_text("v 0 0 0\nf 1 2 3\n")
        M.load_textured_obj(tmp_path / "bad.obj")


def test_cli(tmp_path, capsys):
    assert cli_main(["--list"]) == 0
    listing = capsys.readouterr().out
    assert all(name in listing for name in list_presets())
    assert cli_main(["--preset", "nope", "--out", str(tmp_path / "x")]) == 2
    assert "error: unknown synthetic preset" in capsys.readouterr().err
    assert cli_main(["--out", str(tmp_path / "x"), "--resolution", "0", "5"]) == 2
    assert cli_main(["--preset", "sphere", "--out", str(tmp_path / "y"), "--views", "2", "--resolution", "12", "10",
                     "--device", "cpu", "-q"]) == 0
    assert len(_read(tmp_path / "y")["frames"]) == 2 and not (tmp_path / "x").exists()


def test_garden_ground_objects_background_and_exact_depth(tmp_path):
    """The whole-scene preset at a tiny size: scene.json records the ground and the parts, every camera is above
    the ground, the depth maps are the GT mesh's ray cast, and the ground and the far background are both seen."""
    out = make_scene("garden", tmp_path / "g", views=6, resolution=(32, 24), device="cpu")
    scene = json.loads((out / "scene.json").read_text())
    g = scene["ground"]
    assert scene["units"] == "m" and g["height"] == 0.0 and g["extent"] == [[-5.0, -5.0], [5.0, 5.0]]
    roles = {p["name"]: p["role"] for p in scene["parts"]}
    assert roles["ground"] == roles["shell"] == "background"
    assert {"box", "sphere", "torus", "ring", "stand_post", "post0"} <= {n for n, r in roles.items() if r == "object"}
    lift = min(p["bbox"][0][2] for p in scene["parts"] if p["role"] == "object")
    assert lift == pytest.approx(0.005, abs=1e-6)  # objects rest 5 mm above the ground
    thin = [p for p in scene["parts"] if p["name"].startswith("post")]
    assert all(0.019 <= p["bbox"][1][0] - p["bbox"][0][0] <= 0.041 for p in thin)  # 1-2 cm radius
    mesh = trimesh.load(out / "gt_mesh.ply", process=False)
    gt = wp.Mesh(points=wp.array(np.asarray(mesh.vertices, np.float32), dtype=wp.vec3, device="cpu"),
                 indices=wp.array(np.asarray(mesh.faces, np.int32).ravel(), dtype=wp.int32, device="cpu"))
    meta = _read(out)
    parts = get_preset("garden").build(None)
    caster = RayCaster(parts, device="cpu")
    shell = [k for k, p in enumerate(parts) if p.name == "shell"][0]
    ground = [k for k, p in enumerate(parts) if p.name == "ground"][0]
    seen_shell = 0
    for f in meta["frames"]:
        cam = Camera.from_c2w(np.array(f["transform_matrix"]), meta["fl_x"], meta["fl_y"], meta["cx"], meta["cy"],
                              meta["w"], meta["h"], opengl=True)
        assert cam.center[2] > g["height"] + 0.5  # above the ground
        depth = np.load(out / f["depth_path"])
        cast = raycast.cast_pinhole_rays(gt, cam.R, cam.t, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
        np.testing.assert_allclose(depth, cast["depth"].numpy(), atol=1e-4)
        assert (depth > 0).all()  # closed scene: every ray hits something
        hit = caster.face_part[caster.render(cam, 1).face]
        assert (hit == ground).mean() > 0.2
        seen_shell += int((hit == shell).any())
    assert seen_shell >= 1


def test_background_detail_shell_is_the_background_scene_with_a_finer_texture():
    """``background_detail`` is ``background``'s geometry with a shell whose texture varies on the pixel scale: over
    the shell's pixels of the same view its colour gradients are several times larger (which is what lets the
    photos place the shell), everything else is unchanged."""
    plain, detail = get_preset("background"), get_preset("background_detail")
    parts_p, parts_d = plain.build(None), detail.build(None)
    assert [p.name for p in parts_p] == [p.name for p in parts_d]
    for a, b in zip(parts_p, parts_d):
        np.testing.assert_array_equal(a.vertices, b.vertices)
        assert (a.material == b.material) == (a.name != "shell")
    cam = plain.rig.cameras(96, 96, 4, 0)[0][1]
    shell = [k for k, p in enumerate(parts_p) if p.name == "shell"][0]
    energy = []
    for parts in (parts_p, parts_d):
        caster = RayCaster(parts, plain.lighting, device="cpu")
        view = caster.render(cam, 1)
        on_shell = caster.face_part[view.face] == shell
        pair = on_shell[:, 1:] & on_shell[:, :-1]  # horizontal neighbours both on the shell
        assert pair.sum() > 500
        energy.append(float(np.abs(np.diff(view.rgba[..., :3], axis=1))[pair].mean()))
    assert energy[1] > 3.0 * energy[0], energy


def _shell_pixels_below_ground(preset_name: str, n_views: int = 16, size: int = 48) -> tuple[int, int]:
    """``(shell pixels whose hit point lies below the ground's height, shell pixels)`` over the rig's first views."""
    preset = get_preset(preset_name)
    parts = preset.build(None)
    caster = RayCaster(parts, preset.lighting, device="cpu")
    shell = [k for k, p in enumerate(parts) if p.name == "shell"][0]
    ground_z = float(np.median(parts[[p.name for p in parts].index("ground")].vertices[:, 2]))
    below = total = 0
    for cam in preset.rig.cameras(size, size, n_views, 0)[0]:
        view = caster.render(cam, 1)
        origin, rays = cam.pixel_rays()  # camera-space z of 1: the ray parameter is the rendered z-depth
        z = (origin + rays * view.depth[..., None])[..., 2]
        on_shell = caster.face_part[view.face] == shell
        below += int((z[on_shell] < ground_z - 1e-3).sum())
        total += int(on_shell.sum())
    return below, total


def test_background_full_ground_reaches_the_shell():
    """``background_full`` closes the gap between ``background_detail``'s ground square (half-size 4.2) and the
    shell (radius 5.93 at the ground's height): its cameras see no shell below the ground's height, where
    ``background_detail``'s see it through the gap at grazing angles. The ground is cut to the shell and the shell
    to above the ground (nothing hidden behind either); every other part is unchanged."""
    detail, full = get_preset("background_detail").build(None), get_preset("background_full").build(None)
    assert [p.name for p in detail] == [p.name for p in full]
    for a, b in zip(detail, full):
        same = a.vertices.shape == b.vertices.shape and np.array_equal(a.vertices, b.vertices)
        assert same == (a.name not in ("ground", "shell"))
    ground, shell = full[-2], full[-1]
    assert (ground.name, shell.name) == ("ground", "shell")
    # nothing of the ground behind the shell (where no camera sees it but the scored region's margin reaches),
    # and its rim on the shell: the largest radius of every 10-degree sector is the shell's there (5.90-5.93)
    cut = M.clip_to_convex(ground, shell, center=(0, 0, -0.9))
    np.testing.assert_allclose(cut.vertices, ground.vertices, atol=1e-9)
    r = np.linalg.norm(ground.vertices[:, :2], axis=1)
    sector = np.floor((np.degrees(np.arctan2(ground.vertices[:, 1], ground.vertices[:, 0])) + 180) / 10).astype(int)
    rim = np.array([r[sector == k].max() for k in range(36)])
    assert rim.min() > 5.85 and rim.max() < np.sqrt(36 - 0.81) + 1e-9
    assert shell.vertices[np.unique(shell.faces)][:, 2].min() >= -0.9 - 1e-12
    below_detail, shell_detail = _shell_pixels_below_ground("background_detail")
    below_full, shell_full = _shell_pixels_below_ground("background_full")
    assert shell_detail > 1000 and shell_full > 1000
    assert below_detail > 100  # the gap is seen
    assert below_full == 0


def test_clip_to_convex_moves_outside_vertices_onto_the_hull():
    """A 4 x 4 plane at z = 0 cut to a unit-half-size cube (either winding): vertices outside land on the cube's
    side along the line to the centre, faces wholly outside go, faces inside are untouched."""
    plane = M.grid_plane(center=(0, 0, 0), half_size=2.0, cell=0.5)
    for cube in (M.box(size=(2, 2, 2)), M.sphere(radius=1.0, subdivisions=0, inward=True)):
        cut = M.clip_to_convex(plane, cube, center=(0, 0, 0))
        kept_vertices = np.unique(cut.faces)
        assert np.array_equal(kept_vertices, np.arange(len(cut.vertices)))  # no vertex left unused
        if cube.name == "box":
            inside = np.all(np.abs(plane.vertices) <= 1.0 + 1e-12, axis=1)
            kept = inside[plane.faces].any(axis=1)  # faces with a corner inside stay, in order
            assert len(cut.faces) == int(kept.sum()) and 32 < len(cut.faces) < len(plane.faces)
            before, after = plane.vertices[plane.faces[kept]], cut.vertices[cut.faces]  # [F, 3, 3] corners
            corner_in = inside[plane.faces[kept]]
            np.testing.assert_array_equal(after[corner_in], before[corner_in])  # inside: untouched
            moved, was = after[~corner_in], before[~corner_in]
            np.testing.assert_allclose(np.abs(moved[:, :2]).max(axis=1), 1.0, atol=1e-12)  # on the cube's sides
            cos = np.einsum("ij,ij->i", moved, was) / (np.linalg.norm(moved, axis=1) * np.linalg.norm(was, axis=1))
            np.testing.assert_allclose(cos, 1.0, atol=1e-12)  # along the line to the centre
        else:  # an inward-wound icosahedron in the unit sphere (inradius 0.7947): every vertex inside the sphere,
            r = np.linalg.norm(cut.vertices, axis=1)  # the moved ones on the icosahedron, beyond its inradius
            assert np.all(r <= 1.0 + 1e-12) and (r >= 0.79).sum() > 0 and len(cut.faces) < len(plane.faces)
    with pytest.raises(ValueError, match="not inside"):
        M.clip_to_convex(plane, M.box(size=(2, 2, 2)), center=(5, 0, 0))


def test_cut_below_keeps_the_part_above_the_plane():
    """A unit sphere cut at z = 0.3: every vertex at z >= 0.3, the cut rim on the plane and on the sphere's
    faceted surface (each new corner on an original edge), the area that of the faces' parts above the plane
    (a hemisphere-like cap: between the cap of the inscribed and of the circumscribed sphere), winding kept."""
    sphere = M.sphere(radius=1.0, subdivisions=3)
    cut = M.cut_below(sphere, 0.3)
    assert cut.vertices[np.unique(cut.faces)][:, 2].min() >= 0.3 - 1e-12
    rim = cut.vertices[np.isclose(cut.vertices[:, 2], 0.3, rtol=0, atol=1e-12)]  # the new corners, on the plane
    assert len(rim) > 20 and np.array_equal(np.unique(cut.faces), np.arange(len(cut.vertices)))
    assert np.all(np.linalg.norm(rim, axis=1) <= 1.0 + 1e-12) and np.all(np.linalg.norm(rim, axis=1) > 0.98)
    area = np.linalg.norm(M.face_normals(cut.vertices, cut.faces), axis=1).sum() / 2
    assert 2 * np.pi * 0.7 * 0.97 < area < 2 * np.pi * 0.7  # cap area 2*pi*R*h of the unit sphere, faceted
    outward = np.einsum("ij,ij->i", M.face_normals(cut.vertices, cut.faces), cut.vertices[cut.faces].mean(axis=1))
    assert np.all(outward > 0)  # the sphere's outward winding survives the cut
    assert cut.corner_uvs is None and sphere.corner_uvs is None
    tube = M.cylinder((0, 0, 0), (0, 0, 1), 0.5)  # one texture coordinate runs along its length, one around
    tube_cut = M.cut_below(tube, 0.25)
    assert tube_cut.corner_uvs.shape == (len(tube_cut.faces), 3, 2)
    on_rim = np.isclose(tube_cut.vertices[tube_cut.faces][..., 2], 0.25)
    spans = sorted(np.ptp(tube_cut.corner_uvs[on_rim], axis=0))
    assert on_rim.any() and spans[0] < 1e-9 and spans[1] > 0.5  # the cut: one length coordinate all round
    whole = M.cut_below(sphere, -2.0)
    np.testing.assert_array_equal(whole.faces, sphere.faces)
    assert len(M.cut_below(sphere, 2.0).faces) == 0


def test_bench_init_box_reaches_every_background_presets_shell():
    """A bench run of any preset with a shell starts its random points out to the shell (each preset's largest
    vertex radius), not in the ±1.3 box of the object presets."""
    from gof_warp.benchmarking.runs import preset_overrides

    for name in list_presets():
        parts = get_preset(name).build(None) if name != "spot" else []
        shell = [p for p in parts if p.name == "shell"]
        if not shell:
            assert preset_overrides(name) == {}
            continue
        box = preset_overrides(name)["model"]["init_box"]
        assert box[3] >= np.abs(shell[0].vertices).max() - 1e-9, name
