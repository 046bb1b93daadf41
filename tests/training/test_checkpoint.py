"""Checkpoints: plain data loaded with ``weights_only=True`` (a malicious file cannot run code), resume falls
back past a corrupt newest checkpoint, and Ctrl-C stops training cleanly (exit code 130) and resumes."""

import contextlib
import json
import logging
import os
import pickle
import shlex
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from gof_warp.training.checkpoint import CheckpointError, CheckpointWriter, load_checkpoint, list_checkpoints, save_checkpoint
from gof_warp.data import load_scene
from gof_warp.core.errors import GofError
from gof_warp.training.loss_monitor import LossSpikeMonitor
from gof_warp.synthetic import make_scene
from gof_warp.training.trainer import Trainer, TrainingInterrupted
from _processes import signal_after_first_checkpoint
from test_trainer import _config


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    path = make_scene("default", tmp_path_factory.mktemp("scene") / "s", views=6, resolution=(32, 32), device="cpu")
    return load_scene(path)


class _Payload:
    """Unpickling this creates ``marker``: what a malicious checkpoint's ``__reduce__`` could do, harmlessly."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


_PLAIN = (torch.Tensor, bool, int, float, str, type(None))


def _non_plain_leaves(obj, path="state"):
    """Every entry of ``obj`` that is not a tensor, number, string, None, list, tuple or dict (with such keys)."""
    if isinstance(obj, dict):
        bad = [f"{path} key {k!r}" for k in obj if type(k) not in (str, int)]
        return bad + [p for k, v in obj.items() for p in _non_plain_leaves(v, f"{path}[{k!r}]")]
    if type(obj) in (list, tuple):
        return [p for i, v in enumerate(obj) for p in _non_plain_leaves(v, f"{path}[{i}]")]
    return [] if type(obj) in _PLAIN or type(obj) is torch.Tensor else [f"{path}: {type(obj)}"]


def _params_equal(a: Trainer, b: Trainer):
    for name, value in a.gaussians.params.items():
        assert torch.equal(value, b.gaussians.params[name]), f"{name} differs"


# ---------------------------------------------------------------------------------------------- safe to load
@pytest.mark.slow
def test_every_piece_of_the_state_is_plain_data_and_loads_weights_only(tiny_scene, tmp_path):
    """Each component with state is exercised (appearance model and its optimizer, densifier sampler and
    statistics, loss-spike record, snapshots, history, RNGs), then the whole state is walked."""
    trainer = Trainer(tiny_scene, _config(iterations=12, appearance=True, snapshot_iterations=[4], checkpoint_every=0),
                      tmp_path / "r", "cpu")
    trainer.spikes = LossSpikeMonitor(window=10, warmup=0, min_history=2)
    trainer.run()
    state = trainer.state_dict()
    assert state["appearance"] is not None and state["appearance_optimizer"]["state"]
    assert state["densifier"]["generator"] is not None and state["densifier"]["stats"] is not None
    assert state["loss_spikes"]["worst"] is not None and state["snapshots"] and state["history"]
    assert _non_plain_leaves(state) == []
    loaded = torch.load(list_checkpoints(tmp_path / "r")[-1][1], weights_only=True)
    assert _non_plain_leaves(loaded) == []
    assert loaded["view_rng"] == state["view_rng"] and loaded["loss_spikes"] == state["loss_spikes"]
    assert loaded["snapshots"] == state["snapshots"] and loaded["history"] == state["history"]
    again = Trainer(tiny_scene, _config(iterations=12, appearance=True, snapshot_iterations=[4], checkpoint_every=0),
                    tmp_path / "r", "cpu")
    assert again.resume() == 12
    assert again._rng.bit_generator.state == trainer._rng.bit_generator.state
    assert torch.equal(again.densifier.generator.get_state(), trainer.densifier.generator.get_state())
    _params_equal(trainer, again)


def test_save_converts_numpy_and_refuses_other_objects(tmp_path):
    rng = np.random.Generator(np.random.MT19937(3)).bit_generator.state  # holds a NumPy array (the key)
    path = save_checkpoint(tmp_path, 1, {"iteration": np.int64(1), "loss": np.float32(0.5), "rng": rng})
    state = load_checkpoint(path)
    assert type(state["iteration"]) is int and state["iteration"] == 1 and type(state["loss"]) is float
    assert isinstance(state["rng"]["state"]["key"], torch.Tensor)
    assert np.array_equal(state["rng"]["state"]["key"].numpy(), rng["state"]["key"])
    with pytest.raises(TypeError, match=r"state\['bad'\]\[0\].*_Payload.*not plain data"):
        save_checkpoint(tmp_path, 2, {"iteration": 2, "bad": [_Payload(tmp_path / "x")]})
    assert [it for it, _ in list_checkpoints(tmp_path)] == [1]
    assert not list((tmp_path / "checkpoints").glob(".*"))  # no temporary file left behind


def test_background_writer_saves_a_snapshot_and_reports_a_failed_write(tmp_path, monkeypatch):
    writer = CheckpointWriter()
    moments = torch.arange(6, dtype=torch.float32)
    path = writer.submit(tmp_path, 5, {"iteration": 5, "m": moments, "nested": [{"m": moments}]}, keep=2)
    moments.mul_(-1.0)  # the training goes on changing its tensors in place while the file is written
    writer.wait()
    state = load_checkpoint(path)
    assert torch.equal(state["m"], torch.arange(6, dtype=torch.float32))
    assert torch.equal(state["nested"][0]["m"], torch.arange(6, dtype=torch.float32))
    with pytest.raises(TypeError, match="not plain data"):  # checked in the caller's thread, nothing started
        writer.submit(tmp_path, 6, {"bad": _Payload(tmp_path / "x")})
    assert not writer.busy

    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(torch, "save", disk_full)
    writer.submit(tmp_path, 7, {"iteration": 7})
    with pytest.raises(CheckpointError, match="ckpt_0000007.pt failed.*No space left"):
        writer.wait()
    writer.wait()  # reported once
    assert [it for it, _ in list_checkpoints(tmp_path)] == [5]
    assert not list((tmp_path / "checkpoints").glob(".*"))  # no temporary file left behind


@pytest.mark.parametrize("fmt", ["torch.save", "pickle"])
def test_a_checkpoint_that_would_run_code_is_refused(tmp_path, fmt):
    marker = tmp_path / "MARKER"
    path = tmp_path / "run" / "checkpoints" / "ckpt_0000099.pt"
    path.parent.mkdir(parents=True)
    evil = {"iteration": 99, "params": _Payload(marker)}
    if fmt == "torch.save":
        torch.save(evil, path)
    else:
        path.write_bytes(pickle.dumps(evil, protocol=2))
    for source in (path, tmp_path / "run"):
        with pytest.raises(GofError, match=r"ckpt_0000099.pt was refused.*could run code \(Unsupported global.*io.open"):
            load_checkpoint(source)
        assert not marker.exists(), "loading the checkpoint ran its code"
    with contextlib.suppress(Exception):  # the payload is live: an unsafe load runs it (then may fail)
        torch.load(path, weights_only=False)
    assert marker.exists()


# ---------------------------------------------------------------------------------------------- resume falls back
@pytest.mark.slow
def test_resume_falls_back_past_a_truncated_checkpoint(tiny_scene, tmp_path, caplog):
    cfg = _config(iterations=12, checkpoint_every=4, checkpoint_keep=3)
    first = Trainer(tiny_scene, cfg, tmp_path / "r", "cpu")
    first.run()
    found = list_checkpoints(tmp_path / "r")
    assert [it for it, _ in found] == [4, 8, 12]
    newest = found[-1][1]
    truncated = newest.read_bytes()[: newest.stat().st_size // 2]
    newest.write_bytes(truncated)
    second = Trainer(tiny_scene, cfg, tmp_path / "r", "cpu")
    with caplog.at_level(logging.WARNING, logger="gof_warp.training.checkpoint"):
        assert second.resume() == 8
    assert second.resumed_from == found[1][1]
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1
    assert "ckpt_0000012.pt is unreadable or corrupt" in warnings[0] and "ckpt_0000008.pt" in warnings[0]
    assert "renamed it to ckpt_0000012.pt.corrupt" in warnings[0]
    aside = newest.with_name("ckpt_0000012.pt.corrupt")
    assert aside.read_bytes() == truncated and not newest.exists()  # kept, not deleted
    second.run()  # iterations 9..12 again, from the older checkpoint: the same model bit for bit
    _params_equal(first, second)
    assert [it for it, _ in list_checkpoints(tmp_path / "r")] == [4, 8, 12] and aside.is_file()


@pytest.mark.slow
def test_resume_with_no_usable_checkpoint_is_a_clear_error(tiny_scene, tmp_path):
    cfg = _config(iterations=8, checkpoint_every=4)
    Trainer(tiny_scene, cfg, tmp_path / "r", "cpu").run()
    found = list_checkpoints(tmp_path / "r")
    found[-1][1].write_bytes(found[-1][1].read_bytes()[:100])
    torch.save({"iteration": 4, "x": _Payload(tmp_path / "MARKER")}, found[0][1])
    with pytest.raises(GofError, match="no usable checkpoint.*ckpt_0000008.pt is unreadable.*ckpt_0000004.pt was refused"):
        Trainer(tiny_scene, cfg, tmp_path / "r", "cpu").resume()
    assert list_checkpoints(tmp_path / "r") == found  # nothing renamed or deleted
    assert not (tmp_path / "MARKER").exists()


# ---------------------------------------------------------------------------------------------- Ctrl-C
@pytest.fixture
def python_sigint_handler():
    """Python's own SIGINT handler, as in a command (a test runner may have installed another)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.slow
def test_ctrl_c_stops_at_the_end_of_the_iteration_and_resumes_bit_for_bit(tiny_scene, tmp_path, python_sigint_handler):
    straight = Trainer(tiny_scene, _config(), tmp_path / "a", "cpu")
    straight.run()

    def press_ctrl_c_at(at, times=1):
        def progress(it, info):
            if it == at:
                for _ in range(times):
                    os.kill(os.getpid(), signal.SIGINT)
        return progress

    cut = Trainer(tiny_scene, _config(), tmp_path / "b", "cpu")
    with pytest.raises(TrainingInterrupted) as info:
        cut.run(progress=press_ctrl_c_at(7))
    assert (info.value.iteration, info.value.total) == (7, 24) and cut.iteration == 7
    assert info.value.checkpoint == list_checkpoints(tmp_path / "b")[-1][1] and "ckpt_0000007" in str(info.value.checkpoint)
    assert not (tmp_path / "b" / "point_cloud.ply").exists() and not (tmp_path / "b" / "metrics.json").exists()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handler restored
    resumed = Trainer(tiny_scene, _config(), tmp_path / "b", "cpu")
    assert resumed.resume() == 7
    resumed.run()
    _params_equal(straight, resumed)

    # a second Ctrl-C does not wait for the end of the iteration
    hurry = Trainer(tiny_scene, _config(), tmp_path / "c", "cpu")
    with pytest.raises(KeyboardInterrupt) as info:
        hurry.run(progress=press_ctrl_c_at(2, times=2))
    assert not isinstance(info.value, TrainingInterrupted) and hurry.iteration == 2
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.slow
def test_cli_ctrl_c_exits_130_keeps_the_checkpoint_and_resumes(tiny_scene, tmp_path, cli_in_process, caplog,
                                                               monkeypatch):
    run = tmp_path / "run"
    # checkpoint_every=10: Ctrl-C soon after the first checkpoint (50 waited ~40 more iterations for the same path)
    cmd = [sys.executable, "-m", "gof_warp.train", tiny_scene.source, "--out", str(run), "--config", "quick",
           "--device", "cpu", "iterations=400", "checkpoint_every=10", "model.random_init_points=300", "--no-pictures"]
    proc, err = signal_after_first_checkpoint(cmd, tmp_path, run, signal.SIGINT, timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted: training stopped at iteration "), last
    reached = int(last.split("iteration ")[1].split()[0])
    assert 10 <= reached < 400 and f"of 400, saved in {run / 'checkpoints' / f'ckpt_{reached:07d}.pt'}" in last
    assert list_checkpoints(run)[-1][0] == reached and load_checkpoint(run)["iteration"] == reached
    assert not (run / "point_cloud.ply").exists() and not (run / "metrics.json").exists()
    assert not [p.name for p in (run / "checkpoints").iterdir() if p.name.startswith(".")]  # nothing half-written

    # the command the message gives continues from that checkpoint (a few more iterations to keep this short); its
    # arguments run in this process (the real process, its Ctrl-C and exit code are the part above)
    from gof_warp.cli.train import main

    words = shlex.split(last.split("continue with: ")[1])
    assert words[:3] == ["python", "-m", "gof_warp.train"] and words[-1] == "--resume"
    monkeypatch.chdir(tmp_path)
    with caplog.at_level(logging.INFO, logger="gof_warp.cli.train"):
        rc, err = cli_in_process(main, *words[3:], "--iterations", str(reached + 3))
    assert rc == 0, err
    assert any(f"resuming from iteration {reached} (" in r.getMessage() for r in caplog.records), caplog.text
    assert json.loads((run / "metrics.json").read_text())["iterations"] == reached + 3
