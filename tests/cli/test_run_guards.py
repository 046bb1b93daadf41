"""Run-folder guards of the commands: outputs checked before work, the run folder's lock, --overwrite, the
built-in scene folder, SIGTERM, a full disk, no empty folder left by a failed train."""

import errno
import io
import signal
import subprocess
import sys
import time

import pytest

from _processes import signal_after_first_checkpoint
from gof_warp.training.checkpoint import list_checkpoints


def _fake_run(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "point_cloud.ply").write_bytes(b"the model")
    (run / "cameras.json").write_text('{"train": []}')
    return run


def _no_work(*args, **kwargs):
    raise AssertionError("the command started its work before checking its outputs")


def test_extract_checks_its_outputs_before_work(tmp_path, cli_in_process, monkeypatch):
    from gof_warp.cli import extract

    run = _fake_run(tmp_path)
    monkeypatch.setattr(extract, "load_run", _no_work)
    folder = tmp_path / "folder"
    folder.mkdir()
    for out, message in ((run / "point_cloud.ply", "refusing to write"), (run / "cameras.ply", "cameras.json"),
                         (run / "checkpoints" / "m.ply", "refusing to write"), (folder, "is a folder"),
                         ("/dev/null", "character device")):
        rc, err = cli_in_process(extract.main, str(run), "--out", str(out), "--device", "cpu", "--quiet")
        assert rc == 2 and message in err, (out, err)
    assert (run / "point_cloud.ply").read_bytes() == b"the model" and folder.is_dir()


def test_view_refuses_a_screenshot_over_the_model(tmp_path, cli_in_process, monkeypatch):
    from gof_warp.cli import view
    import gof_warp.viz.viewer as viewer

    run = _fake_run(tmp_path)
    monkeypatch.setattr(viewer, "open_run", _no_work)
    rc, err = cli_in_process(view.main, str(run), "--screenshot", str(run / "point_cloud.ply"), "--device", "cpu")
    assert rc == 2 and "refusing to write" in err and "point_cloud.ply" in err
    assert (run / "point_cloud.ply").read_bytes() == b"the model"


def _train(*args):
    return [sys.executable, "-m", "gof_warp.train", *args]


def test_train_locks_its_run_folder(tiny_train_scene, tiny_train_overrides, tmp_path, cli_in_process):
    from gof_warp.cli.train import main

    run = tmp_path / "run"
    run.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, sys, time; f = open(sys.argv[1], 'w'); "
                               "fcntl.flock(f, fcntl.LOCK_EX); print('locked', flush=True); time.sleep(60)",
                               str(run / ".lock")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        rc, err = cli_in_process(main, str(tiny_train_scene), "--out", str(run), "--device", "cpu", "--iterations",
                                 "2", "--no-pictures", "--quiet", *tiny_train_overrides)
    finally:
        holder.kill()
        holder.wait()
    assert rc == 2 and "in use by another training" in err, err
    assert not (run / "point_cloud.ply").exists()


def test_train_over_a_finished_run_needs_overwrite(tiny_train_scene, tiny_train_overrides, tmp_path, cli_in_process):
    from gof_warp.cli.train import main

    run = tmp_path / "run"
    args = [str(tiny_train_scene), "--out", str(run), "--device", "cpu", "--iterations", "2", "--no-pictures",
            "--quiet", *tiny_train_overrides]
    run.mkdir()
    (run / "point_cloud.ply").write_bytes(b"an older model")  # a finished run without checkpoints
    (run / "mesh_tetra.ply").write_bytes(b"its mesh")
    rc, err = cli_in_process(main, *args)
    assert rc == 2 and "--overwrite" in err and "--resume" in err, err
    assert (run / "point_cloud.ply").read_bytes() == b"an older model"
    rc, err = cli_in_process(main, *args, "--overwrite")
    assert rc == 0, err
    assert (run / "point_cloud.ply").read_bytes() != b"an older model"
    assert not (run / "mesh_tetra.ply").exists()  # no stale mesh beside the new model
    rc, err = cli_in_process(main, *args, "--overwrite", "--resume")
    assert rc == 2 and "give one of them" in err


def test_failed_train_leaves_no_empty_run_folder(tiny_train_scene, tmp_path, cli_in_process):
    from gof_warp.cli.train import main

    rc, err = cli_in_process(main, str(tiny_train_scene), "--out", str(tmp_path / "new"), "loss.lambda_nromal=1")
    assert rc == 2 and "lambda_nromal" in err
    assert not (tmp_path / "new").exists()
    (tmp_path / "old").mkdir()  # a folder the command did not create stays
    rc, err = cli_in_process(main, str(tiny_train_scene), "--out", str(tmp_path / "old"), "loss.lambda_nromal=1")
    assert rc == 2 and (tmp_path / "old").is_dir()


def test_train_never_replaces_a_scene_folder_it_did_not_generate(tmp_path, cli_in_process):
    from gof_warp.cli.train import main
    from gof_warp.core.errors import GofError
    from gof_warp.synthetic import make_scene

    mine = tmp_path / "run" / "scene"
    mine.mkdir(parents=True)
    (mine / "my_photo.jpg").write_bytes(b"irreplaceable")
    rc, err = cli_in_process(main, "--out", str(tmp_path / "run"), "--device", "cpu", "--iterations", "1", "--quiet")
    assert rc == 2 and "not a synthetic scene gof_warp generated" in err, err
    assert (mine / "my_photo.jpg").read_bytes() == b"irreplaceable"
    with pytest.raises(GofError, match="refusing to replace it"):
        make_scene("sphere", mine, views=1, resolution=(8, 8), device="cpu", force=True)
    assert sorted(p.name for p in mine.iterdir()) == ["my_photo.jpg"]


def test_full_disk_while_training_is_a_clear_error(tiny_train_scene, tiny_train_overrides, tmp_path, cli_in_process,
                                                    monkeypatch):
    import gof_warp.core.ply as ply
    from gof_warp.cli.train import main

    class FullDisk(io.BufferedWriter):
        def write(self, data):
            super().write(bytes(data)[:10])
            self.flush()
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(ply, "open", lambda path, mode: FullDisk(io.FileIO(path, "w")), raising=False)
    run = tmp_path / "run"
    rc, err = cli_in_process(main, str(tiny_train_scene), "--out", str(run), "--device", "cpu", "--iterations", "2",
                             "--no-pictures", "--quiet", *tiny_train_overrides)
    assert rc == 2 and f"no space left on device writing {run / 'point_cloud.ply'}" in err, err
    assert "Traceback" not in err
    assert not (run / "point_cloud.ply").exists() and not [p for p in run.iterdir() if p.name.endswith(".tmp")]


def test_sigterm_checkpoints_and_names_the_resume_command(tiny_train_scene, tmp_path):
    run = tmp_path / "run"
    cmd = _train(str(tiny_train_scene), "--out", str(run), "--config", "quick", "--device", "cpu", "iterations=400",
                 "checkpoint_every=2", "model.random_init_points=300", "--no-pictures")
    proc, err = signal_after_first_checkpoint(cmd, tmp_path, run, signal.SIGTERM, timeout=180)
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("interrupted: training stopped at iteration ") and last.endswith("--resume"), last
    reached = int(last.split("iteration ")[1].split()[0])
    assert 2 <= reached < 400 and f"saved in {run / 'checkpoints' / f'ckpt_{reached:07d}.pt'}" in last
    assert list_checkpoints(run)[-1][0] == reached
    assert not (run / "point_cloud.ply").exists()
