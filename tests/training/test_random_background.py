"""Training on a random background colour per view (``TrainConfig.random_background``; the ``unbounded`` preset)."""

import dataclasses

import numpy as np
import pytest
import torch

import gof_warp.training.trainer as trainer_module
from gof_warp.core.config import merge
from gof_warp.data import load_scene
from gof_warp.synthetic import make_scene
from gof_warp.training.trainer import TrainConfig, Trainer
from test_trainer import TINY


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    path = make_scene("default", tmp_path_factory.mktemp("scene") / "s", views=6, resolution=(32, 32), device="cpu")
    return load_scene(path)


def _config(**top):
    return merge(merge(TrainConfig(), TINY), {"random_background": True, **top})


def test_only_the_unbounded_preset_trains_on_random_backgrounds():
    from gof_warp.cli.train import resolve_config

    assert resolve_config("unbounded", [], None).random_background is True
    for name in ("blender", "dtu", "mipnerf360", "quick"):
        assert resolve_config(name, [], None).random_background is False, name


def test_alpha_targets_are_composited_again_on_the_drawn_colour(scene, tmp_path):
    views = list(scene.train)
    mask = np.full((32, 32), 255, np.uint8)
    mask[:, :16] = 0  # the left half transparent, the right half opaque
    mask[0, 16] = 128
    views[0] = dataclasses.replace(views[0], mask=mask)
    views[1] = dataclasses.replace(views[1], mask=None)  # an opaque photo
    blender = dataclasses.replace(scene, train=views, format="blender", background=(0.25, 0.5, 0.75))
    t = Trainer(blender, _config(seed=3), tmp_path / "run", "cpu")
    gt = t.images[0]
    config, target = t._random_background(0, 7, gt)
    drawn = np.random.default_rng([3, 7, 0]).random(3)
    assert config.background == pytest.approx(tuple(drawn))
    shift = torch.tensor(drawn - np.array([0.25, 0.5, 0.75]), dtype=torch.float32)
    assert torch.allclose(target[:, :16], gt[:, :16] + shift, atol=1e-6)  # transparent: the full shift
    assert torch.equal(target[1:, 16:], gt[1:, 16:])  # opaque: the photo itself
    assert torch.allclose(target[0, 16], gt[0, 16] + (1 - 128 / 255) * shift, atol=1e-6)
    again, target_again = t._random_background(0, 7, gt)  # a function of (seed, iteration, view): resumable
    assert again.background == config.background and torch.equal(target_again, target)
    other, _ = t._random_background(0, 8, gt)
    assert other.background != config.background
    # a view without alpha, or an image format whose masks are object masks (DTU), keeps its photo
    _, plain = t._random_background(1, 7, t.images[1])
    assert torch.equal(plain, t.images[1])
    dtu = Trainer(dataclasses.replace(blender, format="dtu"), _config(seed=3), tmp_path / "dtu", "cpu")
    _, kept = dtu._random_background(0, 7, dtu.images[0])
    assert torch.equal(kept, dtu.images[0])


@pytest.mark.slow
def test_each_iteration_renders_on_its_own_colour(scene, tmp_path, monkeypatch):
    seen = []
    real = trainer_module.render

    def spy(gaussians, camera, *, config, **kw):
        seen.append(config.background)
        return real(gaussians, camera, config=config, **kw)

    monkeypatch.setattr(trainer_module, "render", spy)
    Trainer(scene, _config(iterations=4, checkpoint_every=0), tmp_path / "on", "cpu").run()
    training = seen[:4]
    assert len(set(training)) == 4 and all(0.0 <= c <= 1.0 for bg in training for c in bg)
    assert tuple(scene.background) not in training
    seen.clear()
    Trainer(scene, _config(iterations=4, checkpoint_every=0, random_background=False), tmp_path / "off", "cpu").run()
    assert set(seen[:4]) == {tuple(float(c) for c in scene.background)}


@pytest.mark.slow
def test_resume_reproduces_the_uninterrupted_run(scene, tmp_path):
    straight = Trainer(scene, _config(), tmp_path / "a", "cpu")
    straight.run()
    first = Trainer(scene, _config(iterations=12), tmp_path / "b", "cpu")
    first.run()
    second = Trainer(scene, _config(), tmp_path / "b", "cpu")
    assert second.resume() == 12
    second.run()
    for name, value in straight.gaussians.params.items():
        assert torch.equal(value, second.gaussians.params[name]), f"{name} differs after resume"
