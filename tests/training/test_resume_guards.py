"""Resume sanity: the scene fingerprint, a checkpoint beyond the run's iterations, one without an entry."""

import pytest
import torch

from gof_warp.core.config import merge
from gof_warp.core.errors import GofError
from gof_warp.data import load_scene
from gof_warp.synthetic import make_scene
from gof_warp.training.checkpoint import CheckpointError, list_checkpoints
from gof_warp.training.trainer import TrainConfig, Trainer

TINY = {"iterations": 2, "checkpoint_every": 0, "log_every": 1,
        "model": {"sh_degree": 0, "init": "random", "random_init_points": 200},
        "optim": {"means_lr_max_steps": 2},
        "densify": {"start_iter": 100, "stop_iter": 100, "filter_3d_until_iter": 0},
        "loss": {"regularization_from_iter": 100}}


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("scenes")
    a = load_scene(make_scene("default", root / "a", views=4, resolution=(24, 24), device="cpu"))
    b = load_scene(make_scene("default", root / "b", views=5, resolution=(24, 24), seed=1, device="cpu"))
    return a, b


@pytest.fixture(scope="module")
def trained(scenes, tmp_path_factory):
    run = tmp_path_factory.mktemp("run") / "run"
    Trainer(scenes[0], merge(TrainConfig(), TINY), run, "cpu").run()
    return run, list_checkpoints(run)[-1][1]


def _resume(scene, run):
    return Trainer(scene, merge(TrainConfig(), TINY), run, "cpu").resume()


def test_resume_refuses_another_scene(scenes, trained):
    run, _ = trained
    assert _resume(scenes[0], run) == 2  # the same scene resumes
    with pytest.raises(GofError, match="trained on another scene"):
        _resume(scenes[1], run)


@pytest.mark.parametrize("change, message", [
    (lambda s: s.update(iteration=10**12), "at iteration 1000000000000, beyond this run's 2 iterations"),
    (lambda s: s.pop("optimizer"), "lacks the entry 'optimizer'"),
])
def test_resume_refuses_an_unusable_checkpoint(scenes, trained, tmp_path, change, message):
    run, ckpt = trained
    copy = tmp_path / "run"
    (copy / "checkpoints").mkdir(parents=True)
    state = torch.load(ckpt, weights_only=True)
    change(state)
    torch.save(state, copy / "checkpoints" / ckpt.name)
    with pytest.raises(GofError, match=message) as info:
        _resume(scenes[0], copy)
    assert str(copy / "checkpoints" / ckpt.name) in str(info.value)
    if "optimizer" in message:
        assert isinstance(info.value, CheckpointError)
