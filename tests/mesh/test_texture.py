"""Textured meshes (gof_warp.mesh.texture): a cube painted with a known colour field, seen by pinhole cameras whose
images are that field ray cast exactly, bakes into a texture that renders back to the images; occlusion, exposure
gains, unseen texels and chart borders; float64 numpy references of the Warp kernels (texel rasterisation
barycentrics, texture lookup, the per-view samples)."""

import numpy as np
import pytest

from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError

xatlas = pytest.importorskip("xatlas", reason="the UV atlas needs the optional xatlas (gof-warp[texture] / [test])")

from gof_warp.mesh import texture as tx  # noqa: E402
from gof_warp.mesh.colour import _bilinear, _cast, _wp_mesh, mesh_render_psnr  # noqa: E402

W = H = 64
SIZE = 128


def paint(p):
    """The surface's true colour at world points ``p [N, 3]`` (smooth, so bilinear sampling is nearly exact)."""
    p = np.asarray(p, np.float64)
    return np.stack([0.5 + 0.35 * np.sin(2.0 * p[:, 0] + 0.5 * p[:, 2]),
                     0.5 + 0.35 * np.cos(1.7 * p[:, 1] - 0.4 * p[:, 0]),
                     0.3 + 0.25 * (p[:, 2] + 1.0)], 1).clip(0, 1)


def cube(n=4):
    """A closed cube ``[-1, 1]^3`` of ``n x n`` cells per side (outward faces)."""
    import trimesh

    m = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    for _ in range(int(np.log2(n))):
        m = m.subdivide()
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def cameras():
    dirs = [(3, 0.4, 0.3), (-3, 0.2, 0.5), (0.3, 3, 0.2), (0.2, -3, 0.4), (0.3, 0.2, 3), (0.4, 0.3, -3),
            (2, 2, 1.5), (-2, -1.5, -2)]
    return [look_at(d, (0, 0, 0), up=(0, 0, 1) if abs(d[2]) < 2 else (0, 1, 0), fx=40.0, width=W, height=H,
                    name=f"c{i}") for i, d in enumerate(dirs)]


def true_image(v, f, cam, background=(0.0, 0.0, 0.0), mesh=None):
    """``paint`` seen by ``cam``: the exact surface point at each pixel centre, coloured; ``(image, hit)``."""
    hits = _cast(mesh if mesh is not None else _wp_mesh(v, f, "cpu"), cam)
    hit = hits["face"] >= 0
    img = np.empty((cam.height, cam.width, 3), np.float32)
    img[:] = background
    fi = f[hits["face"][hit]]
    b = hits["bary"][hit].astype(np.float64)
    p = v[fi[:, 0]] * b[:, :1] + v[fi[:, 1]] * b[:, 1:2] + v[fi[:, 2]] * (1 - b[:, :1] - b[:, 1:2])
    img[hit] = paint(p)
    return img, hit


@pytest.fixture(scope="module")
def baked():
    v, f = cube()
    cams = cameras()
    mesh = _wp_mesh(v, f, "cpu")
    images = [true_image(v, f, c, mesh=mesh)[0] for c in cams]
    atlas = tx.make_atlas(v, f, SIZE)
    return v, f, cams, images, atlas, tx.bake_texture(v, f, cams, images, atlas=atlas, device="cpu")


def test_texture_side_rule():
    assert tx.texture_side(10) == tx.MIN_SIDE and tx.texture_side(10**9) == tx.MAX_SIDE
    s = tx.texture_side(200_000)
    assert s % 4 == 0 and s * s * tx.ATLAS_FILL >= 200_000 * tx.TEXELS_PER_FACE > (s - 4) ** 2 * tx.ATLAS_FILL
    with pytest.raises(GofError, match="texture size"):
        tx.check_side(8)


def test_atlas_keeps_faces_and_fills_unit_square(baked):
    v, f, _, _, atlas, _ = baked
    assert np.array_equal(atlas.vmap[atlas.faces], f)
    assert atlas.uv.min() >= 0 and atlas.uv.max() <= 1 and atlas.uv.max() > 0.9


def test_texels_hold_the_paint_and_render_back(baked):
    v, f, cams, images, atlas, t = baked
    assert t.texture.shape == (SIZE, SIZE, 3) and t.info["unseen_texels"] < 0.03 * t.info["texels"]  # at the edges
    texels = tx.rasterise_atlas(v, f, atlas, device="cpu")
    on = texels.covered
    got = t.texture[texels.xy[on, 1], texels.xy[on, 0]]
    assert np.abs(got - paint(texels.points[on])).mean() < 0.01
    m = tx.textured_render_psnr(t, cams, images, device="cpu")
    assert m["psnr_masked"] > 35 and m["views"] == len(cams)
    # the same cube with vertex colours: textures keep the detail vertices cannot
    from gof_warp.mesh.colour import colours_from_images
    mv = mesh_render_psnr(v, f, colours_from_images(v, f, cams, images, device="cpu"), cams, images, device="cpu")
    assert m["psnr_masked"] > mv["psnr_masked"] + 3


def test_chart_borders_do_not_bleed_background(baked):
    """Texels off the charts take the nearest chart colour: a render that hits only chart borders (bilinear
    lookups reaching past them) shows no black, and no texel of the texture is background."""
    v, f, cams, images, atlas, t = baked
    assert t.texture.min() > 0.05  # the paint is >= 0.15 everywhere; black would be background bleeding in
    texels = tx.rasterise_atlas(v, f, atlas, device="cpu")
    border = texels.face_map < 0
    assert border.any() and np.abs(t.texture[border]).min() > 0.05


def test_occluded_texels_take_nothing_from_the_blocking_view():
    """A small quad behind a big one: from the front camera it is hidden; its texels come from the back view
    (blue) only, while the front quad takes the gradient."""
    from tests.mesh.test_colour import grid_quad

    fv, ff = grid_quad(0.0, 1.5)
    bv, bf = grid_quad(-1.0, 0.5, n=3)
    v = np.concatenate([fv, bv])
    f = np.concatenate([ff, bf + len(fv)])
    front = look_at((0, 0, 5), (0, 0, 0), up=(0, 1, 0), fx=60.0, width=W, height=H)
    back = look_at((0, 0, -6), (0, 0, 0), up=(0, 1, 0), fx=60.0, width=W, height=H)
    red = np.zeros((H, W, 3), np.float32)
    red[..., 0] = 1.0
    blue = np.zeros((H, W, 3), np.float32)
    blue[..., 2] = 1.0
    atlas = tx.make_atlas(v, f, 64)
    t = tx.bake_texture(v, f, [front, back], [red, blue], atlas=atlas, exposure=False, device="cpu")
    texels = tx.rasterise_atlas(v, f, atlas, device="cpu")
    on_back = texels.covered & (texels.face >= len(ff))
    on_front = texels.covered & (texels.face < len(ff)) & (np.abs(texels.points[:, :2]).max(1) < 0.45)
    col = t.texture[texels.xy[:, 1], texels.xy[:, 0]]
    np.testing.assert_allclose(col[on_back], np.tile([0, 0, 1.0], (on_back.sum(), 1)), atol=1e-6)
    # where both views see the front quad, it mixes red (front, heavier: closer) and blue; never pure blue
    assert (col[on_front, 0] > 0.5).all()


def test_exposure_gain_recovers_a_darkened_view(baked):
    v, f, cams, images, atlas, truth = baked
    dark = [img * (0.5 if i == 2 else 1.0) for i, img in enumerate(images)]
    with_gain = tx.bake_texture(v, f, cams, dark, atlas=atlas, device="cpu")
    without = tx.bake_texture(v, f, cams, dark, atlas=atlas, exposure=False, device="cpu")
    gains = np.array(with_gain.info["gains"])
    # the gains are as exact as the 64-pixel images' bilinear samples of the paint (a few per cent)
    np.testing.assert_allclose(gains[2], 0.5, atol=0.04)
    np.testing.assert_allclose(np.delete(gains, 2, 0), 1.0, atol=0.04)
    err_gain = np.abs(with_gain.texture - truth.texture)
    err_none = np.abs(without.texture - truth.texture)
    assert err_gain.mean() < 0.01 and err_gain.max() < 0.06
    assert err_none.mean() > 3 * err_gain.mean() and err_none.max() > 0.15


def test_unseen_texels_take_the_nearest_seen_colour():
    """A second cube far out of every view: all its texels are unseen and filled from the seen cube, not grey."""
    v, f = cube(2)
    v2 = np.concatenate([v, v + [100.0, 0, 0]])
    f2 = np.concatenate([f, f + len(v)])
    cams = cameras()[:6]
    mesh = _wp_mesh(v, f, "cpu")
    images = [true_image(v, f, c, mesh=mesh)[0] for c in cams]
    atlas = tx.make_atlas(v2, f2, 128)
    t = tx.bake_texture(v2, f2, cams, images, atlas=atlas, device="cpu")
    texels = tx.rasterise_atlas(v2, f2, atlas, device="cpu")
    far = texels.covered & (texels.face >= len(f))
    assert t.info["unseen_texels"] >= far.sum() > 0  # (and a few at the seen cube's edges)
    col = t.texture[texels.xy[far, 1], texels.xy[far, 0]]
    seen = t.texture[texels.xy[~far & texels.covered, 1], texels.xy[~far & texels.covered, 0]]
    assert not np.allclose(col, tx.UNSEEN_GREY)
    # each far colour is some seen texel's colour (the nearest one's)
    d = np.abs(col[:, None, :] - seen[None, ::7, :]).sum(-1).min(1)
    assert np.median(d) < 0.05


# ---------------------------------------------------------------- float64 references of the Warp kernels


def test_texel_barycentrics_match_float64(baked):
    v, f, _, _, atlas, _ = baked
    texels = tx.rasterise_atlas(v, f, atlas, device="cpu")
    px = atlas.uv.astype(np.float64) * atlas.size
    tri = px[atlas.faces[texels.face]]  # [N, 3, 2]
    p = texels.xy.astype(np.float64) + 0.5
    e1, e2, q = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], p - tri[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    l1 = (q[:, 0] * e2[:, 1] - q[:, 1] * e2[:, 0]) / det
    l2 = (e1[:, 0] * q[:, 1] - e1[:, 1] * q[:, 0]) / det
    ref = np.stack([1 - l1 - l2, l1, l2], 1)
    np.testing.assert_allclose(texels.bary, ref, atol=2e-4)
    assert (ref[texels.covered] >= -1e-4).all()  # covered texel centres lie in their face
    assert (ref[~texels.covered].min(1) < 1e-3).all()  # ring texels: extrapolated
    pts = np.einsum("nk,nkd->nd", ref, v[atlas.vmap][atlas.faces[texels.face]])
    np.testing.assert_allclose(texels.points, pts, atol=1e-4)
    # every texel whose centre lies strictly inside some face's UV triangle is covered
    rng = np.random.default_rng(0)
    for fi in rng.choice(len(f), 20, replace=False):
        t = px[atlas.faces[fi]]
        xs, ys = np.meshgrid(np.arange(atlas.size), np.arange(atlas.size))
        c = np.stack([xs.ravel() + 0.5, ys.ravel() + 0.5], 1)
        a, b = t[1] - t[0], t[2] - t[0]
        dd = a[0] * b[1] - a[1] * b[0]
        qq = c - t[0]
        m1 = (qq[:, 0] * b[1] - qq[:, 1] * b[0]) / dd
        m2 = (a[0] * qq[:, 1] - a[1] * qq[:, 0]) / dd
        inside = (m1 > 1e-4) & (m2 > 1e-4) & (1 - m1 - m2 > 1e-4)
        assert (texels.face_map.ravel()[inside] == fi).all()


def test_texture_lookup_matches_float64(baked):
    _, _, cams, _, _, t = baked
    import warp as wp

    rng = np.random.default_rng(1)
    n = 500
    face = rng.integers(0, len(t.faces), n).astype(np.int32)
    b = rng.dirichlet([1, 1, 1], n)[:, :2].astype(np.float32)
    out = wp.empty(n, dtype=wp.vec3, device="cpu")
    wp.launch(tx._lookup, dim=n, inputs=[wp.array(face, dtype=wp.int32, device="cpu"),
                                         wp.array(b, dtype=wp.vec2, device="cpu"),
                                         wp.array(t.faces.astype(np.int32), dtype=wp.int32, device="cpu"),
                                         wp.array(t.uv, dtype=wp.vec2, device="cpu"),
                                         wp.array(t.texture, dtype=wp.vec3, device="cpu"), out], device="cpu")
    bb = b.astype(np.float64)
    uv = t.uv.astype(np.float64)[t.faces[face]]
    uvp = uv[:, 0] * bb[:, :1] + uv[:, 1] * bb[:, 1:] + uv[:, 2] * (1 - bb.sum(1, keepdims=True))
    np.testing.assert_allclose(out.numpy(), tx.sample_texture_np(t.texture, uvp), atol=1e-5)
    # and the renderer is that lookup at the ray cast's hits
    rgb, hit = tx.render_textured(t, cams[0], device="cpu")
    assert hit.sum() > 300 and (rgb[~hit] == 0).all()


def test_view_samples_match_float64(baked):
    """The per-view kernel against numpy: projection, bilinear sample, weight |cos| (f/z)^2, visibility."""
    import warp as wp

    from gof_warp.mesh.colour import points_unblocked, visibility_tolerance

    v, f, cams, images, _, _ = baked
    cam, img = cams[6], images[6]
    rng = np.random.default_rng(2)
    fi = rng.integers(0, len(f), 400)
    bc = rng.dirichlet([1, 1, 1], 400)
    pts = np.einsum("nk,nkd->nd", bc, v[f[fi]])
    nrm = np.cross(v[f[fi, 1]] - v[f[fi, 0]], v[f[fi, 2]] - v[f[fi, 0]])
    mesh = _wp_mesh(v, f, "cpu")
    w = wp.empty(len(pts), dtype=float, device="cpu")
    c = wp.empty(len(pts), dtype=wp.vec3, device="cpu")
    tol = visibility_tolerance(cam)
    edge = tx.edge_tolerance(cam)
    depth = _cast(mesh, cam)["depth"].astype(np.float64)
    wp.launch(tx._view_samples, dim=len(pts), inputs=[
        mesh.id, wp.array(pts.astype(np.float32), dtype=wp.vec3, device="cpu"),
        wp.array(nrm.astype(np.float32), dtype=wp.vec3, device="cpu"), wp.mat33(*cam.R.astype(np.float32).ravel()),
        wp.vec3(*cam.t.astype(np.float32)), wp.vec3(*cam.center.astype(np.float32)), float(cam.fx), float(cam.fy),
        float(cam.cx), float(cam.cy), float(tol), wp.array(img, dtype=wp.vec3, device="cpu"),
        wp.array(depth.astype(np.float32), dtype=float, device="cpu"), float(edge), w, c], device="cpu")
    uv, z, inside = cam.in_image(pts)
    # the four pixels of each bilinear sample see the mesh within edge * z of the point's depth
    x0 = np.clip(np.floor(np.clip(uv[:, 0] - 0.5, 0, W - 1)).astype(int), 0, W - 1)
    y0 = np.clip(np.floor(np.clip(uv[:, 1] - 0.5, 0, H - 1)).astype(int), 0, H - 1)
    x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
    near = np.ones(len(pts), bool)
    for yy, xx in ((y0, x0), (y0, x1), (y1, x0), (y1, x1)):
        near &= np.abs(depth[yy, xx] - z) <= edge * z
    vis = inside & points_unblocked(mesh, pts, cam.center, tol) & near
    assert (inside & ~near).sum() > 5  # the silhouette test leaves some out
    ray = (pts - cam.center) / np.linalg.norm(pts - cam.center, axis=1, keepdims=True)
    cos = np.abs(np.einsum("ij,ij->i", ray, nrm / np.linalg.norm(nrm, axis=1, keepdims=True)))
    ref_w = np.where(vis, cos * (np.sqrt(cam.fx * cam.fy) / z) ** 2, 0.0)
    assert 50 < vis.sum() < len(pts)
    np.testing.assert_allclose(w.numpy(), ref_w, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(c.numpy()[vis], _bilinear(img.astype(np.float64), uv[vis, 0], uv[vis, 1]), atol=1e-5)


def test_exposure_gains_least_squares():
    rng = np.random.default_rng(3)
    albedo = rng.uniform(0.2, 0.8, (50, 3))
    true_g = np.array([[1.0, 1.0, 1.0], [0.6, 0.7, 0.8], [1.0, 1.0, 1.0], [1.3, 1.2, 1.1]])
    samples = [(k, np.arange(50), albedo * true_g[k], np.ones(50)) for k in range(4)]
    np.testing.assert_allclose(tx.exposure_gains(samples, 5)[:4], true_g, atol=1e-6)
    assert (tx.exposure_gains(samples, 5)[4] == 1).all()  # a view without samples keeps gain 1


def test_wrong_inputs(baked):
    v, f, cams, images, atlas, _ = baked
    with pytest.raises(GofError, match="images"):
        tx.bake_texture(v, f, cams, images[:2], atlas=atlas, device="cpu")
    with pytest.raises(GofError, match="source"):
        tx.mesh_texture("paint", v, f, cams)
    with pytest.raises(GofError, match="no faces"):
        tx.make_atlas(v, np.zeros((0, 3), np.int64), 64)


# ---------------------------------------------------------------- files


@pytest.mark.parametrize("fmt", ["glb", "obj"])
def test_textured_file_loads_back_in_trimesh(baked, tmp_path, fmt):
    import trimesh

    from gof_warp.mesh.export import save_textured_mesh, textured_companions

    _, _, _, _, _, t = baked
    path = tmp_path / f"mesh.{fmt}"
    assert save_textured_mesh(path, t) == fmt
    assert all(p.is_file() for p in textured_companions(path)) and len(textured_companions(path)) == (fmt == "obj") * 2
    m = trimesh.load(path, process=False, force="mesh")
    assert len(m.faces) == len(t.faces) and m.visual.uv.shape == t.uv.shape
    img = np.asarray(m.visual.material.baseColorTexture if hasattr(m.visual.material, "baseColorTexture")
                     else m.visual.material.image)
    assert img.shape[:2] == t.texture.shape[:2]
    # a few known points: the loaded texture sampled at the loaded UVs (OpenGL convention, v up) of some vertices
    # gives the baked texture at those vertices
    rng = np.random.default_rng(4)
    pick = rng.choice(len(m.vertices), 30, replace=False)
    # match loaded vertices to the written ones by position and UV (the loaders may reorder or merge)
    key = np.concatenate([np.asarray(m.vertices)[pick], np.asarray(m.visual.uv)[pick]], 1)
    ours = np.concatenate([t.vertices, np.stack([t.uv[:, 0], 1 - t.uv[:, 1]], 1)], 1)
    d = np.abs(key[:, None, :] - ours[None, :, :]).max(-1)
    match = d.argmin(1)
    assert d.min(1).max() < 1e-5
    loaded_uv = np.asarray(m.visual.uv)[pick]
    got = tx.sample_texture_np(img[..., :3].astype(np.float64) / 255.0,
                               np.stack([loaded_uv[:, 0], 1 - loaded_uv[:, 1]], 1))
    want = tx.sample_texture_np(t.texture_uint8().astype(np.float64) / 255.0, t.uv[match])
    np.testing.assert_allclose(got, want, atol=1e-6)
    np.testing.assert_allclose(want, tx.sample_texture_np(t.texture, t.uv[match]), atol=0.5 / 255 + 1e-6)


def test_textured_ply_keeps_vertex_colours(baked, tmp_path):
    import trimesh

    from gof_warp.mesh.export import save_textured_mesh

    v, f, _, _, _, t = baked
    save_textured_mesh(tmp_path / "mesh.ply", t)
    m = trimesh.load(tmp_path / "mesh.ply", process=False, force="mesh")
    assert np.array_equal(np.asarray(m.faces), f) and np.allclose(m.vertices, v, atol=1e-6)
    expect = np.round(t.vertex_colours() * 255)
    np.testing.assert_allclose(np.asarray(m.visual.vertex_colors)[:, :3], expect, atol=1)


def test_keep_best_and_blend_match_numpy():
    """Top-K by weight over views fed one at a time, then the gain-corrected weighted mean, against numpy."""
    import warp as wp

    rng = np.random.default_rng(5)
    n, views, k = 300, 7, 3
    w = rng.uniform(0, 1, (views, n)) * (rng.uniform(0, 1, (views, n)) > 0.3)  # some views do not see a texel
    c = rng.uniform(0, 1, (views, n, 3))
    gains = rng.uniform(0.5, 1.5, (views, 3))
    bw = wp.zeros((n, k), dtype=float, device="cpu")
    bc = wp.zeros((n, k), dtype=wp.vec3, device="cpu")
    bv = wp.zeros((n, k), dtype=wp.int32, device="cpu")
    for view in range(views):
        wp.launch(tx._keep_best, dim=n, inputs=[wp.array(w[view].astype(np.float32), dtype=float, device="cpu"),
                                                wp.array(c[view].astype(np.float32), dtype=wp.vec3, device="cpu"),
                                                view, bw, bc, bv], device="cpu")
    out = wp.empty(n, dtype=wp.vec3, device="cpu")
    total = wp.empty(n, dtype=float, device="cpu")
    wp.launch(tx._blend, dim=n, inputs=[bw, bc, bv, wp.array(gains.astype(np.float32), dtype=wp.vec3, device="cpu"),
                                        out, total], device="cpu")
    w32 = w.astype(np.float32).astype(np.float64)
    order = np.argsort(-w32, axis=0, kind="stable")[:k]  # the k heaviest views per texel
    top_w = np.take_along_axis(w32, order, 0)
    top_c = c[order, np.arange(n)[None, :]] / gains[order]
    ref_total = top_w.sum(0)
    ref = (top_w[..., None] * top_c).sum(0) / np.maximum(ref_total, 1e-30)[:, None]
    np.testing.assert_allclose(total.numpy(), ref_total, rtol=1e-5)
    seen = ref_total > 0
    assert 0 < seen.sum() < n or seen.all()
    np.testing.assert_allclose(out.numpy()[seen], ref[seen], atol=1e-5)
    assert set(np.unique(bv.numpy()[bw.numpy() > 0])) <= set(range(views))
