"""cameras_inside_surfaces: a camera inside a closed shell is reported; cameras outside it (an orbit) or all inside it
(a room) are not; the own/other split of the views equals the field over the matching subsets of views."""

import numpy as np
import torch

from gof_warp.core.camera import look_at
from gof_warp.core.model import Gaussians
from gof_warp.rendering.opacity_field import (_owned_slices, _view_inputs, cameras_inside_surfaces,
                                              opacity_field)
from gof_warp.rendering.render import RenderConfig

SIZE = 32


def _shell(n=1500, radius=1.0, seed=0):
    """Flat opaque discs tangent to a sphere: a closed surface seen from outside and from inside."""
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    # the quaternion turning +z onto the normal (w, x, y, z)
    axis = np.cross([0.0, 0.0, 1.0], normal)
    half = np.arccos(np.clip(normal[:, 2], -1, 1)) / 2
    norm = np.linalg.norm(axis, axis=1, keepdims=True)
    axis = np.where(norm > 1e-9, axis / np.maximum(norm, 1e-12), [1.0, 0.0, 0.0])
    quats = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * axis], 1)
    scales = np.tile([0.07, 0.07, 0.004], (n, 1))
    return Gaussians.from_activated(radius * normal, quats, scales, np.full(n, 0.95), np.full((n, 3), 0.5),
                                    device="cpu")


def _orbit(n=8, distance=3.0):
    return [look_at([distance * np.cos(a), distance * np.sin(a), 0.8 * (-1) ** k], [0, 0, 0], fx=0.9 * SIZE,
                    width=SIZE, height=SIZE, name=f"o{k}")
            for k, a in enumerate(2 * np.pi * np.arange(n) / n)]


def _room(n=6):
    dirs = [[1, 0, 0.1], [-1, 0, 0.1], [0, 1, 0.1], [0, -1, 0.1], [0.1, 0.1, 1], [0.1, 0.1, -1]][:n]
    eyes = 0.3 * np.asarray(dirs, float)
    return [look_at(e, 2 * e, fx=0.9 * SIZE, width=SIZE, height=SIZE, name=f"r{k}") for k, e in enumerate(eyes)]


def test_a_camera_inside_a_closed_shell_is_reported_and_none_outside():
    cams = _orbit() + [look_at([0, 0, 0], [1, 0, 0.1], fx=0.9 * SIZE, width=SIZE, height=SIZE, name="inside")]
    found = cameras_inside_surfaces(_shell(), cams)
    assert [c.name for c in found] == ["inside"]
    assert found[0].index == len(cams) - 1 and found[0].solid_fraction > 0.9 and found[0].tested >= 8


def test_cameras_all_inside_a_room_are_not_reported():
    assert cameras_inside_surfaces(_shell(), _room()) == []


def test_an_orbit_with_no_camera_inside_reports_none():
    assert cameras_inside_surfaces(_shell(radius=1.4), _orbit(12, distance=3.0)) == []


def test_fewer_than_two_cameras_or_no_gaussians_report_none():
    g = _shell()
    assert cameras_inside_surfaces(g, _orbit()[:1]) == []
    empty = Gaussians.from_activated(np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0),
                                     np.zeros((0, 3)), device="cpu")
    assert cameras_inside_surfaces(empty, _orbit()) == []


def test_own_and_other_views_equal_the_field_over_those_views():
    g, cams = _shell(400), _orbit(5)
    rng = np.random.default_rng(3)
    pts = torch.as_tensor(rng.uniform(-2, 2, (5 * 40, 3)), dtype=torch.float32)
    bounds = np.arange(6) * 40
    cfg = RenderConfig()
    arrays, views = _view_inputs(g, cams, cfg)
    for own in (True, False):
        field = torch.ones(len(pts))
        seen = torch.zeros(len(pts), dtype=torch.int32)
        _owned_slices(views, pts, bounds, field, seen, arrays, own=own)
        for j in range(5):
            sl = slice(bounds[j], bounds[j + 1])
            subset = [cams[j]] if own else cams[:j] + cams[j + 1:]
            f, s = opacity_field(g, subset, pts[sl], render_config=cfg, return_seen=True)
            assert torch.equal(s, seen[sl])
            assert torch.equal(torch.where(s > 0, f, torch.ones_like(f)), field[sl])


def test_extract_warns_once_per_model_when_the_grid_is_shared(caplog):
    from gof_warp.mesh.extraction import MeshConfig, StageTimer, extract_mesh

    g = _shell()  # closed: with a third of the discs the inside camera sees out through the gaps (and is not reported)
    cams = _orbit() + [look_at([0, 0, 0], [1, 0, 0.1], fx=0.9 * SIZE, width=SIZE, height=SIZE, name="inside")]
    cache, timers = {}, []
    with caplog.at_level("WARNING", logger="gof_warp.mesh.extraction"):
        for steps in (0, 2):
            timers.append(StageTimer("cpu"))
            extract_mesh(g, cams, MeshConfig(binary_steps=steps), grid_cache=cache, timer=timers[-1])
    assert caplog.text.count("inside what the other views see as solid") == 1 and "inside (" in caplog.text
    assert timers[0].stages["cameras_inside"]["cameras"] == ["inside"] and "cameras_inside" not in timers[1].stages
