"""Loss terms read back in batches: the values, the order, the NaN stop and the spike monitor are as if each
iteration were read at once, and a training step itself reads nothing back from the device."""

import math

import pytest
import torch

from gof_warp.core.config import merge
from gof_warp.data import load_scene
from gof_warp.training.loss_monitor import LossSpikeMonitor
from gof_warp.training.optim import OptimConfig
from gof_warp.training.step_scalars import IterationScalars, PendingScalars
from gof_warp.synthetic import make_scene
from gof_warp.training.trainer import TrainConfig, Trainer, TrainingError

TINY = {"iterations": 24, "checkpoint_every": 0, "log_every": 10,  # test_trainer's compressed schedule
        "model": {"sh_degree": 1, "init": "random", "random_init_points": 300},
        "optim": {"means_lr_max_steps": 24},
        "densify": {"start_iter": 3, "stop_iter": 20, "interval": 4, "opacity_reset_interval": 16,
                    "sh_degree_interval": 8, "filter_3d_interval": 4, "filter_3d_until_iter": 22,
                    "prune_big_after": 10, "grad_threshold": 1e-6, "max_gaussians": 2000},
        "loss": {"regularization_from_iter": 8}}


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    path = make_scene("default", tmp_path_factory.mktemp("scene") / "s", views=5, resolution=(32, 32), device="cpu")
    return load_scene(path)


def _record(it, view="v"):
    return IterationScalars(it, view, 10, False, 0.0, {})


def test_flush_returns_every_record_in_order_with_its_own_terms():
    pending = PendingScalars()
    pending.add(_record(1), {"l1": torch.tensor(0.5), "total": torch.tensor(0.75)})
    pending.add(_record(2), {})
    pending.add(_record(3), {"l1": torch.tensor(0.25), "normal": torch.tensor(2.0), "total": torch.tensor(1.0)})
    out = pending.flush()
    assert [r.iteration for r in out] == [1, 2, 3] and len(pending) == 0
    assert out[0].values == {"l1": 0.5, "total": 0.75} and out[1].values == {}
    assert out[2].values == {"l1": 0.25, "normal": 2.0, "total": 1.0}
    assert pending.flush() == []


@pytest.mark.slow
def test_a_training_step_reads_nothing_back_from_the_device(tiny_scene, tmp_path, monkeypatch):
    # fused Adam, as on CUDA (the CPU's loop Adam reads its step count back, which costs nothing there)
    cfg = merge(TrainConfig(), {**TINY, "performance": {"adam": "torch-fused"}, "appearance": True})
    trainer = Trainer(tiny_scene, cfg, tmp_path / "r", "cpu")
    trainer.iteration = 9  # regularisers on, statistics gathered (densification steps, every 4th, do read back)

    def refuse(*_a, **_k):
        raise AssertionError("a tensor was read back to the host inside the training step")

    for name in ("item", "__bool__", "__float__", "__int__", "tolist"):
        monkeypatch.setattr(torch.Tensor, name, refuse)
    record, terms = trainer._step()
    monkeypatch.undo()
    assert record.iteration == 10 and {"l1", "dssim", "distortion", "normal", "total", "psnr"} <= set(terms)


@pytest.mark.slow
def test_deferred_loop_matches_reading_each_iteration(tiny_scene, tmp_path):
    """The loop (read back every few iterations) and step() (read back at once) give the same history,
    spike record and parameters."""
    cfg = merge(TrainConfig(), TINY)
    looped = Trainer(tiny_scene, cfg, tmp_path / "a", "cpu")
    looped.spikes = LossSpikeMonitor(window=10, warmup=0, min_history=2)
    looped.run()
    stepped = Trainer(tiny_scene, cfg, tmp_path / "b", "cpu")
    stepped.spikes = LossSpikeMonitor(window=10, warmup=0, min_history=2)
    for _ in range(cfg.iterations):
        stepped.step()
    strip = lambda h: [{k: v for k, v in e.items() if k != "elapsed_s"} for e in h]  # noqa: E731
    assert strip(looped.history) == strip(stepped.history) and len(looped.history) == 3  # 10, 20, 24
    assert looped.spikes.state_dict() == stepped.spikes.state_dict()
    for name, p in looped.gaussians.params.items():
        assert torch.equal(p, stepped.gaussians.params[name]), name


@pytest.mark.slow
def test_a_nan_loss_in_the_loop_names_its_iteration(tiny_scene, tmp_path):
    trainer = Trainer(tiny_scene, merge(TrainConfig(), TINY), tmp_path / "n", "cpu")
    for _ in range(3):
        trainer.step()
    for image in trainer.images:
        image[:] = float("nan")
    with pytest.raises(TrainingError, match="loss became nan at iteration 4 "):
        trainer.run()


def test_fused_adam_only_where_asked():
    assert OptimConfig().adam_kwargs("cpu")["fused"] is False
    assert OptimConfig().adam_kwargs("cuda")["fused"] is True
    assert OptimConfig(fused=False).adam_kwargs("cuda")["fused"] is False
    assert math.isclose(OptimConfig().adam_kwargs("cpu")["eps"], 1e-15)
