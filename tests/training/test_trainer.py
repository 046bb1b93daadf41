"""Training loop: runs end to end, resumes bit-for-bit, stops cleanly on NaN, CLI errors before training."""

import json
import subprocess
import sys

import pytest
import torch

from gof_warp.training.checkpoint import list_checkpoints, load_checkpoint
from gof_warp.core.config import merge
from gof_warp.data import load_scene
from gof_warp.core.errors import GofError
from gof_warp.synthetic import make_scene
from gof_warp.training.trainer import TrainConfig, Trainer, TrainingError

# A schedule compressed so that every mechanism (densify, prune, opacity reset, SH increase, 3D filter,
# regularisers, checkpoints) happens within a few dozen iterations on 32x32 images.
TINY = {
    "iterations": 24,
    "checkpoint_every": 12,
    "log_every": 4,
    "model": {"sh_degree": 1, "init": "random", "random_init_points": 300},
    "optim": {"means_lr_max_steps": 24},
    "densify": {"start_iter": 3, "stop_iter": 20, "interval": 4, "opacity_reset_interval": 16,
                "sh_degree_interval": 8, "filter_3d_interval": 4, "filter_3d_until_iter": 22,
                "prune_big_after": 10, "grad_threshold": 1e-6, "max_gaussians": 2000},
    "loss": {"regularization_from_iter": 8},
}


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    path = make_scene("default", tmp_path_factory.mktemp("scene") / "s", views=6, resolution=(32, 32), device="cpu")
    return load_scene(path)


def _config(**top):
    return merge(merge(TrainConfig(), TINY), top)


@pytest.fixture(scope="module")
def straight_run(tiny_scene, tmp_path_factory):
    """``(trainer, run folder, Gaussians at the start, metrics)`` of one uninterrupted TINY run (24 iterations): the
    run whose outputs test_training_runs_and_writes_outputs checks, and the reference that the resumed and the
    snapshotting runs must equal bit for bit (the tests only read it; the same run was trained three times)."""
    run = tmp_path_factory.mktemp("straight") / "run"
    trainer = Trainer(tiny_scene, _config(), run, "cpu")
    n0 = len(trainer.gaussians)
    metrics = trainer.run()
    return trainer, run, n0, metrics


@pytest.mark.slow
def test_training_runs_and_writes_outputs(tiny_scene, straight_run):
    trainer, run, n0, metrics = straight_run
    for name in ("point_cloud.ply", "metrics.json", "config.yaml", "cameras.json"):
        assert (run / name).is_file(), name
    saved = json.loads((run / "metrics.json").read_text())
    assert saved["iterations"] == 24 and saved["num_gaussians"] == len(trainer.gaussians)
    assert saved["test"]["views"] == len(tiny_scene.test) and saved["test"]["psnr"] > 5
    assert [h["iteration"] for h in saved["history"]] == list(range(4, 25, 4))
    assert saved["history"][-1]["num_gaussians"] == len(trainer.gaussians)
    assert len(trainer.gaussians) != n0, "densification never changed the model"
    assert trainer.gaussians.active_sh_degree == 1
    assert trainer.gaussians.filter_3d is not None and torch.isfinite(trainer.gaussians.filter_3d).all()
    assert "distortion" in trainer.history[-1] and "normal" in trainer.history[-1]
    assert metrics["test"]["psnr"] == saved["test"]["psnr"]
    assert saved["init"] == {"init": "random", "source": "random", "points": 300, "random_min_views": 2,
                             "unseen_prune": {"min_views": 2}}
    spikes = saved["loss_spikes"]  # 24 iterations: all inside the 1,000-iteration warm-up, nothing checked
    assert spikes["after_iteration"] == 1000 and spikes["iterations_checked"] == 0 and spikes["max_ratio"] is None


@pytest.mark.slow
def test_resume_reproduces_the_uninterrupted_run(tiny_scene, straight_run, tmp_path):
    straight = straight_run[0]
    first = Trainer(tiny_scene, _config(iterations=12), tmp_path / "b", "cpu")
    first.run()
    assert [it for it, _ in list_checkpoints(tmp_path / "b")] == [12]
    second = Trainer(tiny_scene, _config(), tmp_path / "b", "cpu")
    assert second.resume() == 12
    second.run()
    for name, value in straight.gaussians.params.items():
        assert torch.equal(value, second.gaussians.params[name]), f"{name} differs after resume"
    assert torch.equal(straight.gaussians.filter_3d, second.gaussians.filter_3d)


@pytest.mark.slow
def test_resume_refuses_a_different_config(tiny_scene, tmp_path):
    Trainer(tiny_scene, _config(iterations=4, checkpoint_every=0), tmp_path / "r", "cpu").run()
    other = Trainer(tiny_scene, merge(_config(), {"loss": {"lambda_normal": 0.5}}), tmp_path / "r", "cpu")
    with pytest.raises(GofError, match="different config"):
        other.resume()


@pytest.mark.slow
def test_nan_loss_stops_and_keeps_the_last_good_checkpoint(tiny_scene, tmp_path):
    trainer = Trainer(tiny_scene, _config(iterations=4), tmp_path / "n", "cpu")
    trainer.run()
    ckpt = list_checkpoints(tmp_path / "n")[-1][1]
    before = ckpt.read_bytes()
    for image in trainer.images:  # a corrupt input image makes the loss NaN
        image[:] = float("nan")
    with pytest.raises(TrainingError, match="loss became nan at iteration 5"):
        trainer.step()
    with torch.no_grad():
        trainer.gaussians.params["means"][0, 0] = float("nan")
    with pytest.raises(TrainingError, match="checkpoint not written"):
        trainer.save_checkpoint()
    assert ckpt.read_bytes() == before
    assert load_checkpoint(tmp_path / "n")["iteration"] == 4


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "gof_warp.train", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


@pytest.mark.slow
def test_cli_reports_bad_input_before_training(tmp_path, cli_in_process):
    from gof_warp.cli.train import main

    proc = _cli(str(tmp_path / "no_such_scene"), "--out", str(tmp_path / "o"), cwd=tmp_path)  # the real process
    assert proc.returncode == 2 and "error:" in proc.stderr and "no_such_scene" in proc.stderr
    assert "Traceback" not in proc.stderr
    blocker = tmp_path / "file"
    blocker.write_text("x")
    rc, err = cli_in_process(main, str(tmp_path), "--out", str(blocker / "run"))
    assert rc == 2 and "cannot create output folder" in err
    rc, err = cli_in_process(main, str(tmp_path), "--out", str(tmp_path / "o2"), "loss.lambda_nromal=1")
    assert rc == 2 and "lambda_nromal" in err
    rc, err = cli_in_process(main, str(tmp_path), "--out", str(tmp_path / "o3"), "--config", "nope")
    assert rc == 2 and "unknown config preset 'nope'" in err


@pytest.mark.slow
def test_cli_refuses_to_overwrite_a_run_without_resume(tiny_scene, tmp_path, cli_in_process):
    """In this process (the real process's exit path: test_cli_reports_bad_input_before_training)."""
    from gof_warp.cli.train import main

    Trainer(tiny_scene, _config(iterations=2, checkpoint_every=0), tmp_path / "run", "cpu").run()
    # --iterations 2: were the run not refused, the command would train briefly and exit 0, not for minutes
    rc, err = cli_in_process(main, tiny_scene.source, "--out", str(tmp_path / "run"), "--iterations", "2")
    assert rc == 2 and "--resume" in err


@pytest.mark.slow
def test_decoupled_appearance_trains_and_stays_out_of_the_render(tiny_scene, tmp_path):
    from gof_warp.training.appearance import AppearanceModel

    trainer = Trainer(tiny_scene, _config(iterations=6, appearance=True, checkpoint_every=0), tmp_path / "app", "cpu")
    before = {k: v.clone() for k, v in trainer.appearance.state_dict().items()}
    trainer.run()
    after = trainer.appearance.state_dict()
    assert any(not torch.equal(before[k], after[k]) for k in before), "the appearance model never trained"
    # the gain covers the centre crop whose sides are multiples of 32 and lies in (0, 1)
    render = torch.rand(3, 70, 45)
    gain = trainer.appearance.gain(render, 0)
    assert gain.shape == (3, 64, 32) and bool(((gain > 0) & (gain < 1)).all())
    assert AppearanceModel.crop(render).shape == (3, 64, 32)
    assert trainer.appearance.gain(torch.rand(3, 20, 20), 0).numel() == 0  # below 32 px: no crop, no gain


@pytest.mark.slow
@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA graphs need a GPU")
def test_loss_as_cuda_graphs_trains_with_appearance_and_several_views(tmp_path):
    """``loss_cuda_graphs``: the warm-up builds both graphs, two views a step accumulate the appearance's gradients
    across replays (which reuse the graph's memory), and the run's losses match the compiled loss without graphs."""
    cfg = dict(iterations=16, appearance=True, checkpoint_every=0, views_per_step=2, compile_loss="on")
    scene = load_scene(make_scene("default", tmp_path / "s", views=6, resolution=(32, 32), device="cuda"))
    plain = Trainer(scene, _config(**cfg, loss_cuda_graphs=False), tmp_path / "plain", "cuda")
    plain_metrics = plain.run()
    graphs = Trainer(scene, _config(**cfg, loss_cuda_graphs=True), tmp_path / "graphs", "cuda")
    metrics = graphs.run()
    assert graphs.loss.cuda_graphs and graphs.loss.compiled is not None and graphs.loss.fallback_reason is None
    assert metrics["num_gaussians"] > 0
    assert abs(metrics["final_train_psnr"] - plain_metrics["final_train_psnr"]) <= 0.5


@pytest.mark.slow
def test_snapshots_are_written_and_do_not_change_the_run(tiny_scene, straight_run, tmp_path):
    from gof_warp.core.model import Gaussians

    plain = straight_run[0]
    short = Trainer(tiny_scene, _config(iterations=8, checkpoint_every=0), tmp_path / "short", "cpu")
    short.run()  # the first 8 iterations of the same schedule (TINY's schedule does not depend on iterations)
    snap = Trainer(tiny_scene, _config(snapshot_iterations=[8, 16]), tmp_path / "snap", "cpu")
    metrics = snap.run()
    for name, value in plain.gaussians.params.items():
        assert torch.equal(value, snap.gaussians.params[name]), f"{name}: writing snapshots changed the run"
    assert [s["iteration"] for s in metrics["snapshots"]] == [8, 16]
    assert json.loads((tmp_path / "snap" / "metrics.json").read_text())["snapshots"] == metrics["snapshots"]
    history = {h["iteration"]: h for h in metrics["history"]}
    for rec in metrics["snapshots"]:
        folder = tmp_path / "snap" / "snapshots" / f"iter_{rec['iteration']}"
        assert json.loads((folder / "snapshot.json").read_text()) == rec
        assert (tmp_path / "snap" / rec["path"]) == folder / "point_cloud.ply"
        assert rec["num_gaussians"] == history[rec["iteration"]]["num_gaussians"]
        assert 0 < rec["train_time_s"] < metrics["train_time_s"]
        assert rec["test"]["views"] == len(tiny_scene.test) and rec["test"]["psnr"] > 5
    at8 = Gaussians.load_ply(tmp_path / "snap" / metrics["snapshots"][0]["path"], device="cpu")
    for name in ("means", "opacity_logits", "log_scales"):  # the model as it was at iteration 8
        assert torch.equal(at8.params[name], short.gaussians.params[name]), name
    assert metrics["snapshots"][0]["test"]["psnr"] == short.evaluate()["psnr"]


@pytest.mark.parametrize("bad", [[0], [24], [30], [16, 8], [8, 8], [2.5]])
def test_snapshot_iterations_are_validated(bad):
    from gof_warp.core.config import ConfigError

    with pytest.raises(ConfigError, match="snapshot_iterations"):
        _config(snapshot_iterations=bad)
    assert _config(snapshot_iterations=[1, 23]).snapshot_iterations == [1, 23]


@pytest.mark.slow
def test_resume_keeps_snapshots(tiny_scene, tmp_path):
    first = Trainer(tiny_scene, _config(iterations=12, snapshot_iterations=[4]), tmp_path / "r", "cpu")
    before = first.run()["snapshots"]
    ply = tmp_path / "r" / before[0]["path"]
    written = ply.read_bytes()
    second = Trainer(tiny_scene, _config(snapshot_iterations=[4, 16]), tmp_path / "r", "cpu")
    assert second.resume() == 12
    after = second.run()["snapshots"]
    assert after[0] == before[0] and [s["iteration"] for s in after] == [4, 16]
    assert ply.read_bytes() == written and (tmp_path / "r" / after[1]["path"]).is_file()


@pytest.mark.slow
def test_warm_up_pass_changes_nothing_that_training_reads(tiny_scene, tmp_path, monkeypatch):
    """The throw-away pass before the clock starts (Trainer._warm_up) leaves the run bitwise as without it."""
    warm = Trainer(tiny_scene, _config(iterations=10, appearance=True, checkpoint_every=0), tmp_path / "w", "cpu")
    metrics = warm.run()
    assert metrics["warmup_s"] > 0
    monkeypatch.setattr(Trainer, "_warm_up", lambda self: None)
    cold = Trainer(tiny_scene, _config(iterations=10, appearance=True, checkpoint_every=0), tmp_path / "c", "cpu")
    cold.run()
    for name, value in warm.gaussians.params.items():
        assert torch.equal(value, cold.gaussians.params[name]), name
    for a, b in zip(warm.appearance.parameters(), cold.appearance.parameters()):
        assert torch.equal(a, b)
    assert warm._rng.bit_generator.state == cold._rng.bit_generator.state


@pytest.mark.slow
def test_render_scratch_changes_nothing_that_training_reads(tiny_scene, straight_run, tmp_path):
    """The trainer's RenderScratch (scratch arrays, structs and stream wrappers kept from one render to the next) leaves
    the run bitwise as with every render's arrays made anew: through densification, pruning, the SH degree's
    increase and the opacity reset (straight_run), and with two views per step."""
    trainer = straight_run[0]
    assert trainer.render_scratch.nbytes() > 0  # the straight run rendered through it
    plain = Trainer(tiny_scene, _config(), tmp_path / "plain", "cpu")
    plain.render_scratch = None
    plain.run()
    for name, value in trainer.gaussians.params.items():
        assert torch.equal(value, plain.gaussians.params[name]), name
    runs = [Trainer(tiny_scene, _config(iterations=12, views_per_step=2, checkpoint_every=0), tmp_path / str(i), "cpu")
            for i in range(2)]
    runs[1].render_scratch = None
    for run in runs:
        run.run()
    assert len(runs[0].gaussians) != straight_run[2]  # densified
    for name, value in runs[0].gaussians.params.items():
        assert torch.equal(value, runs[1].gaussians.params[name]), name


@pytest.mark.slow
def test_overflowed_tile_lists_are_reported(straight_run, caplog):
    """Renders that dropped tile-list entries (a GPU run's sizer; none on the CPU) are said at the end of training,
    not only counted in metrics.json."""
    from gof_warp.kernels.binning import TileListSizer

    trainer = straight_run[0]
    kept = trainer.tile_lists
    try:
        trainer.tile_lists = TileListSizer(1.25)
        trainer.tile_lists.calls = 40
        with caplog.at_level("WARNING", logger="gof_warp.training.trainer"):
            trainer._warn_about_overflows()
        assert not caplog.records
        trainer.tile_lists.overflows = 3
        with caplog.at_level("WARNING", logger="gof_warp.training.trainer"):
            trainer._warn_about_overflows()
        assert "3 of 40 training renders overflowed" in caplog.text and "tile_list_margin (now 1.25)" in caplog.text
    finally:
        trainer.tile_lists = kept
