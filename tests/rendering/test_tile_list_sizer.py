"""Tile lists sized without a host–device synchronisation (``kernels.binning.TileListSizer``).

A training loop's renders size their (Gaussian, tile) lists from earlier renders' counts instead of reading each
render's count back (which makes the host wait for the GPU). Checked here on the CPU, where the same padded path
runs: renders and gradients through a sizer are bitwise those of exact sizing; the padding owns no tile; the first
render of a number of Gaussians measures unless its view was rendered before (each view keeps its latest count); a
render whose lists outgrow the planned size is counted as an overflow and the size grows; bad margins are errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from gof_warp.core.config import ConfigError
from gof_warp.kernels.binning import TileListSizer
from gof_warp.kernels.renderer import prepare_view
from gof_warp.kernels.render_types import camera_params_from
from gof_warp.rendering.render import RenderConfig, raster_settings_for, rasterize
from gof_warp.training.settings import PerformanceConfig

NAMES = ("means", "quats", "scales", "opacities", "sh")


def _scene_and_cameras():
    from reference_render import make_camera, random_scene

    cam = make_camera(width=97, height=71, fx=90.0, fy=80.0)
    close = make_camera(width=194, height=142, fx=180.0, fy=160.0)  # twice the resolution: ~2.6x the entries
    scene = random_scene(cam, 300, 2, seed=11, n_behind=3, n_near=8, spread=1.5)
    return {k: scene[k].float() for k in NAMES}, cam, close


def _render_and_grads(scene, cam, tile_lists):
    leaves = [scene[k].clone().requires_grad_(True) for k in NAMES]
    out = rasterize(*leaves, cam, config=RenderConfig(), tile_lists=tile_lists)
    w = torch.Generator().manual_seed(1)
    loss = sum((out[k] * torch.randn(out[k].shape, generator=w)).sum() for k in sorted(out) if out[k].is_floating_point())
    loss.backward()
    return {**{k: v.detach() for k, v in out.items()}, **{f"grad_{k}": l.grad for k, l in zip(NAMES, leaves)}}


def _assert_equal(a, b):
    for key in a:
        assert torch.equal(a[key], b[key]), key


def test_sized_renders_equal_exact_renders_bit_for_bit():
    scene, cam, _ = _scene_and_cameras()
    exact = _render_and_grads(scene, cam, None)
    sizer = TileListSizer(margin=1.5)
    for _ in range(3):  # the first measures; the next two run padded (1.5x the count)
        _assert_equal(_render_and_grads(scene, cam, sizer), exact)
    assert sizer.stats()["calls"] == 3 and sizer.measured == 1 and sizer.overflows == 0
    assert float(exact["alpha"].mean()) > 0.3  # the scene covers the image


def test_padding_owns_no_tile():
    scene, cam, _ = _scene_and_cameras()
    args = [wp.from_torch(scene[k].contiguous(), dtype=t) for k, t in
            zip(NAMES, (wp.vec3, wp.vec4, wp.vec3, wp.float32, wp.vec3))]
    cp, settings = camera_params_from(cam), raster_settings_for(cam, RenderConfig())
    _, exact, count = prepare_view(*args, 2, cp, settings)
    sizer = TileListSizer(margin=2.0)
    prepare_view(*args, 2, cp, settings, sizer=sizer)  # measures
    _, padded, allocated = prepare_view(*args, 2, cp, settings, sizer=sizer)
    assert allocated == sizer.size >= 2 * count - 1 and count > 100
    assert (sizer.entries_allocated, sizer.entries_needed) == (allocated, count)  # the padded call's, read at once
    np.testing.assert_array_equal(padded.range_start.numpy(), exact.range_start.numpy())
    np.testing.assert_array_equal(padded.range_end.numpy(), exact.range_end.numpy())
    np.testing.assert_array_equal(padded.values.numpy()[:count], exact.values.numpy())
    assert exact.range_end.numpy().max() == count  # the last real entry ends a range; none reaches the padding


def test_overflow_is_counted_and_the_size_grows():
    scene, cam, close = _scene_and_cameras()
    sizer = TileListSizer(margin=1.0)
    _render_and_grads(scene, cam, sizer)  # measures the far view: size = its count
    size_far = sizer.size
    _render_and_grads(scene, close, sizer)  # the close view needs more entries: dropped, counted
    assert sizer.overflows == 1 and sizer.size > size_far
    _assert_equal(_render_and_grads(scene, close, sizer), _render_and_grads(scene, close, None))
    assert sizer.overflows == 1
    # fewer Gaussians (a prune): a view rendered before keeps its count (not scaled down), nothing is measured
    fewer = {k: v[:200] for k, v in scene.items()}
    _assert_equal(_render_and_grads(fewer, cam, sizer), _render_and_grads(fewer, cam, None))
    assert sizer.measured == 1 and sizer.num_gaussians == 200 and sizer.overflows == 1
    # another number of Gaussians: a view rendered before is not measured; one never rendered is
    other = {k: v[:150] for k, v in scene.items()}
    _render_and_grads(other, close, sizer)
    assert sizer.measured == 1 and sizer.overflows == 1
    _render_and_grads({k: v[:120] for k, v in scene.items()}, make_shifted(close), sizer)
    assert sizer.measured == 2 and sizer.overflows == 1


def make_shifted(cam):
    """``cam`` moved a little sideways: another view (another pose), seeing about as much."""
    from reference_render import make_camera

    return make_camera(width=cam.width, height=cam.height, fx=cam.fx, fy=cam.fy, eye=(0.45, -2.6, 0.9))


def test_views_keep_their_counts_across_a_densification():
    """One size for all views made the first views after each change in the number of Gaussians overflow whenever
    they needed more than the one view measured first; each view's own count, scaled by the growth, sizes it. Doubling
    every Gaussian (an exact copy: every view's count exactly doubles) with no margin: the old rule measured the far
    view and dropped the close view's entries; now neither is measured nor overflows, and both render bit for bit."""
    scene, cam, close = _scene_and_cameras()
    sizer = TileListSizer(margin=1.0)
    _render_and_grads(scene, cam, sizer)  # measured
    _render_and_grads(scene, close, sizer)  # overflow: the close view needs ~2.6x the far view's entries
    assert (sizer.measured, sizer.overflows) == (1, 1)
    doubled = {k: torch.cat([v, v]) for k, v in scene.items()}
    for view in (cam, close):
        _assert_equal(_render_and_grads(doubled, view, sizer), _render_and_grads(doubled, view, None))
    assert (sizer.measured, sizer.overflows, sizer.num_gaussians) == (1, 1, 600)


def test_bad_margins_are_errors():
    with pytest.raises(ValueError, match="margin"):
        TileListSizer(margin=0.9)
    with pytest.raises(ConfigError, match="tile_list_margin"):
        PerformanceConfig(tile_list_margin=0.5)
    assert PerformanceConfig(tile_list_margin=0).tile_list_margin == 0  # 0: exact sizing
    scene, cam, _ = _scene_and_cameras()
    with pytest.raises(TypeError, match="tile_lists"):
        rasterize(*[scene[k] for k in NAMES], cam, tile_lists=1.25)


def test_counters_survive_a_checkpoint():
    sizer = TileListSizer()
    sizer.calls, sizer.measured, sizer.overflows, sizer.size = 40, 3, 1, 1000
    sizer.entries_allocated, sizer.entries_needed = 5000, 4000
    again = TileListSizer()
    again.load_state_dict(sizer.state_dict())
    assert again.stats() == {"calls": 40, "measured": 3, "overflows": 1, "entries_allocated": 5000,
                             "entries_needed": 4000, "size": 0}  # the size is measured again
    older = TileListSizer()  # a checkpoint from before the entry counters
    older.load_state_dict({"calls": 40, "measured": 3, "overflows": 1})
    assert (older.calls, older.entries_allocated, older.entries_needed) == (40, 0, 0)


def test_counts_that_arrive_later_are_filed_under_their_view():
    """The CUDA path's bookkeeping, without a GPU: counts copied to pinned slots arrive a render or two later and are
    taken in order, each with the view and the allocation of its own render (the CPU path reads them at once)."""

    class Arrived:
        is_complete = True

    sizer = TileListSizer(margin=1.0)
    assert sizer.plan(10, b"far") == 0  # nothing known: measure
    sizer.measure(6, 10, b"far")
    sizer._host = wp.array([7, 30, 0, 0, 0, 0, 0, 0], dtype=wp.int32, device="cpu")
    sizer._pending = [(0, 6, 10, b"far", Arrived()), (1, 6, 10, b"close", Arrived())]
    # planning takes what has arrived, in order: far's 7 and close's 30, both over their allocation of 6
    assert sizer.plan(10, b"close") == 30
    assert sizer._pending == [] and sizer.overflows == 2
    assert (sizer.entries_allocated, sizer.entries_needed) == (12, 37)
    assert sizer.plan(10, b"far") == 30  # the largest since the change covers far
    assert sizer.plan(20, b"far") == 14 and sizer.plan(20, b"close") == 60  # doubled Gaussians: scaled up
    assert sizer.plan(20, b"new") == 0  # no count yet for 20 Gaussians, and a view never seen: measure
