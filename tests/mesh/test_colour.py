"""Vertex colours from images (gof_warp.mesh.colour): a quad facing a camera whose photo is a known gradient takes the
photo's colour at each vertex's projection; a vertex behind another quad takes nothing from that view; the coloured
mesh rendered back by ray casting matches the photo."""

import numpy as np
import pytest

from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError
from gof_warp.mesh.colour import colours_from_images, mesh_colours, mesh_render_psnr, render_vertex_colours

W, H = 64, 48


def grid_quad(z, half, n=5):
    """An ``n x n`` grid of vertices on the square ``|x|, |y| <= half`` at height ``z``, two triangles per cell."""
    xs = np.linspace(-half, half, n)
    xx, yy = np.meshgrid(xs, xs, indexing="xy")
    v = np.stack([xx.ravel(), yy.ravel(), np.full(n * n, z)], 1)
    f = []
    for j in range(n - 1):
        for i in range(n - 1):
            a = j * n + i
            f += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return v, np.array(f)


def gradient_photo():
    """``R = u / W``, ``G = v / H`` at the pixel centres, ``B = 0.25`` (float, so the expectation is exact)."""
    u = (np.arange(W) + 0.5) / W
    v = (np.arange(H) + 0.5) / H
    img = np.zeros((H, W, 3), np.float32)
    img[..., 0] = u[None, :]
    img[..., 1] = v[:, None]
    img[..., 2] = 0.25
    return img


def front_camera():
    return look_at((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fx=60.0, width=W, height=H, name="front")


def back_camera():
    return look_at((0.0, 0.0, -6.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fx=60.0, width=W, height=H, name="back")


def test_quad_takes_the_photo_colour_at_each_vertex():
    v, f = grid_quad(0.0, 1.0)
    cam = front_camera()
    photo = gradient_photo()
    colours, seen = colours_from_images(v, f, [cam], [photo], device="cpu", return_seen=True)
    uv, _ = cam.project(v)
    expect = np.stack([uv[:, 0] / W, uv[:, 1] / H, np.full(len(v), 0.25)], 1)
    assert (seen == 1).all()
    np.testing.assert_allclose(colours, expect, atol=1e-5)


def test_uint8_photo_within_one_level():
    v, f = grid_quad(0.0, 1.0)
    cam = front_camera()
    photo = gradient_photo()
    photo8 = np.round(photo * 255).astype(np.uint8)
    a = colours_from_images(v, f, [cam], [photo], device="cpu")
    b = colours_from_images(v, f, [cam], [photo8], device="cpu")
    assert np.abs(a - b).max() <= 1.0 / 255.0


def test_occluded_vertex_does_not_take_the_front_colour():
    front_v, front_f = grid_quad(0.0, 1.5)
    back_v, back_f = grid_quad(-1.0, 0.5, n=3)
    v = np.concatenate([front_v, back_v])
    f = np.concatenate([front_f, back_f + len(front_v)])
    blue = np.zeros((H, W, 3), np.float32)
    blue[..., 2] = 1.0
    colours, seen = colours_from_images(v, f, [front_camera(), back_camera()], [gradient_photo(), blue],
                                        device="cpu", return_seen=True)
    back = slice(len(front_v), None)
    assert (seen[back] == 1).all()  # the front camera's view of them is blocked by the front quad
    np.testing.assert_allclose(colours[back], np.tile([0.0, 0.0, 1.0], (len(back_v), 1)), atol=1e-6)


def test_unseen_vertex_takes_the_nearest_seen_colour():
    v, f = grid_quad(0.0, 1.0)
    v2 = v + np.array([100.0, 0.0, 0.0])  # out of every view
    verts = np.concatenate([v, v2])
    faces = np.concatenate([f, f + len(v)])
    colours, seen = colours_from_images(verts, faces, [front_camera()], [gradient_photo()], device="cpu",
                                        return_seen=True)
    assert (seen[len(v):] == 0).all()
    right = np.argmax(v[:, 0] + 1e-3 * v[:, 1])  # nearest seen vertices lie on the right edge
    assert np.isclose(colours[len(v):, 0], colours[right, 0], atol=1e-6).all()


def test_render_back_matches_the_photo_where_hit():
    v, f = grid_quad(0.0, 1.0, n=9)
    cam = front_camera()
    photo = gradient_photo()
    colours = colours_from_images(v, f, [cam], [photo], device="cpu")
    rgb, hit = render_vertex_colours(v, f, colours, cam, device="cpu")
    assert hit.sum() > 100 and not hit.all()
    np.testing.assert_allclose(rgb[hit], photo[hit], atol=1e-4)  # linear colour: interpolation is exact
    assert (rgb[~hit] == 0).all()
    m = mesh_render_psnr(v, f, colours, [cam], [photo], device="cpu")
    assert m["psnr_masked"] > 60 and m["psnr"] < m["psnr_masked"] and 0 < m["coverage"] < 1 and m["views"] == 1


def test_wrong_inputs():
    v, f = grid_quad(0.0, 1.0)
    with pytest.raises(GofError, match="expected"):
        colours_from_images(v, f, [front_camera()], [np.zeros((3, 3, 3))], device="cpu")
    with pytest.raises(GofError, match="source"):
        mesh_colours("paint", v, f, [front_camera()])
    with pytest.raises(GofError, match="photos"):
        mesh_colours("photos", v, f, [front_camera()])
