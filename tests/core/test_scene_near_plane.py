"""The default near plane follows the scene's size: a scene of size 1e-6 is not culled by a 0.2 plane (issue 56)."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
import yaml

from _scene_fixtures import make_blender_scene
from gof_warp.core.config import merge
from gof_warp.core.errors import SceneError
from gof_warp.data import load_scene
from gof_warp.rendering.render import DEFAULT_NEAR, scene_near
from gof_warp.training.trainer import TrainConfig, Trainer, _scene_near_plane

SCALE = 1e-6
TRAIN_SCALE = 1e-3  # trained: a scene at 1e-6 is refused (DataConfig.scale)
TINY = {"iterations": 4, "checkpoint_every": 0, "log_every": 2,
        "model": {"sh_degree": 0, "init": "random", "random_init_points": 200},
        "optim": {"means_lr_max_steps": 4}, "loss": {"regularization_from_iter": 100},
        "densify": {"start_iter": 100, "stop_iter": 100, "filter_3d_until_iter": 4}}


def _scaled_scene(root, scale):
    make_blender_scene(root, n_train=5, n_test=1, size=(24, 18))
    for split in ("train", "test"):
        path = root / f"transforms_{split}.json"
        d = json.loads(path.read_text())
        for f in d["frames"]:
            m = np.array(f["transform_matrix"])
            m[:3, 3] *= scale
            f["transform_matrix"] = m.tolist()
        path.write_text(json.dumps(d))
    return load_scene(root)


def test_a_tiny_scene_trains_with_a_near_plane_below_its_size(tmp_path):
    scene = _scaled_scene(tmp_path / "tiny", TRAIN_SCALE)
    assert scene.extent < 0.2
    trainer = Trainer(scene, merge(TrainConfig(), TINY), tmp_path / "run", "cpu")
    near = trainer.render_config.near
    assert 0 < near < scene.extent and near == trainer.config.render.near
    metrics = trainer.run()
    assert metrics["num_gaussians"] > 0 and np.isfinite(metrics["test"]["psnr"])
    saved = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())
    assert saved["render"]["near"] == near  # extraction reads the plane the run used


def test_a_normal_scene_keeps_exactly_0_2(tmp_path):
    scene = _scaled_scene(tmp_path / "normal", 1.0)
    config = merge(TrainConfig(), TINY)
    trainer = Trainer(scene, config, tmp_path / "run", "cpu")
    assert trainer.render_config.near == DEFAULT_NEAR == 0.2 and trainer.config is config


def test_a_1e_6_scene_is_refused_and_the_near_plane_follows_a_small_one(tmp_path, caplog):
    with pytest.raises(SceneError, match="data.scale="):  # float32 training has other limits at 1e-6 (DataConfig.scale)
        _scaled_scene(tmp_path / "micro", SCALE)
    scene = _scaled_scene(tmp_path / "tiny", TRAIN_SCALE)
    assert scene.extent < 0.01
    assert 0 < _scene_near_plane(merge(TrainConfig(), TINY), scene).render.near < scene.extent
    with caplog.at_level(logging.WARNING):
        config = _scene_near_plane(merge(TrainConfig(), {**TINY, "render": {"near": 0.01}}), scene)
    assert config.render.near == 0.01
    assert any("render.near = 0.01 is larger than the scene" in r.getMessage() for r in caplog.records)
    assert scene_near(0.01, 100.0) == (0.01, None) and scene_near(DEFAULT_NEAR, 0.5) == (0.1, None)
