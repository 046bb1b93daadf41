"""``data.scale``: a scene far from the trainer's working range of extents is refused with the scale that fixes it,
and the scale moves every camera centre and scene point (issue 56: a scene at 1e-6 scale trained to NaN)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from _scene_fixtures import make_colmap_scene, make_ingp_scene
from gof_warp.core.config import ConfigError
from gof_warp.core.errors import SceneError
from gof_warp.data import DataConfig, load_scene
from gof_warp.data.plan import EXTENT_MAX, EXTENT_MIN


def _shrink_ingp(root, factor):
    path = root / "transforms.json"
    meta = json.loads(path.read_text())
    for f in meta["frames"]:
        for r in range(3):
            f["transform_matrix"][r][3] *= factor
    path.write_text(json.dumps(meta))


@pytest.mark.parametrize("factor", [1e-6, 1e6])
def test_extent_out_of_range_names_the_fixing_scale(tmp_path, factor):
    root = make_ingp_scene(tmp_path / "s")
    extent = load_scene(root).extent
    _shrink_ingp(root, factor)
    with pytest.raises(SceneError, match="data.scale=") as e:
        load_scene(root)
    fix = float(str(e.value).split("data.scale=")[1].split()[0])
    scaled = load_scene(root, DataConfig(scale=fix))  # the named scale is accepted and lands in 1..10
    assert 1.0 <= scaled.extent <= 10.0
    np.testing.assert_allclose(scaled.extent, extent * factor * fix, rtol=1e-9)
    assert EXTENT_MIN <= scaled.extent <= EXTENT_MAX


def test_scale_moves_centres_and_points_not_rotations(tmp_path):
    root = make_colmap_scene(tmp_path / "c", n=8)
    a = load_scene(root, DataConfig(test_every=0))
    b = load_scene(root, DataConfig(test_every=0, scale=3.0))
    for va, vb in zip(a.train, b.train):
        np.testing.assert_allclose(vb.camera.R, va.camera.R)
        np.testing.assert_allclose(vb.camera.center, 3.0 * va.camera.center, atol=1e-12)
        assert (vb.camera.fx, vb.camera.cx, vb.camera.width) == (va.camera.fx, va.camera.cx, va.camera.width)
        np.testing.assert_array_equal(vb.image, va.image)
    np.testing.assert_allclose(b.points, 3.0 * a.points)
    np.testing.assert_allclose(b.extent, 3.0 * a.extent)
    # every point projects to the same pixel in the scaled world, at 3x the depth
    uv_a, z_a = a.train[0].camera.project(a.points)
    uv_b, z_b = b.train[0].camera.project(b.points)
    np.testing.assert_allclose(uv_b, uv_a, atol=1e-9)
    np.testing.assert_allclose(z_b, 3.0 * z_a, rtol=1e-12)


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), float("inf"), True, "x"])
def test_bad_scale_is_a_config_error(bad):
    with pytest.raises(ConfigError, match="data.scale"):
        DataConfig(scale=bad)
