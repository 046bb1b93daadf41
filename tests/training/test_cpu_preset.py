"""The ``cpu`` preset: its schedule compressed to the run's length (golden numbers of the rule in
``gof_warp.training.schedule``), its image size chosen from the scene, and ``--downscale`` on the commands."""

import pytest

from _scene_fixtures import make_ingp_scene
from gof_warp.cli import inspect_scene, train
from gof_warp.core.config import ConfigError, load_yaml
from gof_warp.core.errors import GofError
from gof_warp.training.presets import PRESETS, preset_path, resolve_config
from gof_warp.training.schedule import (MIN_ITERATIONS, compress_schedule, cpu_downscale, eta_from_pace,
                                        expected_train_seconds)
from gof_warp.training.trainer import TrainConfig


def test_compress_schedule_golden_numbers():
    """u = round(N / 12): 1,500 → 125; 1,200 → 100 (the quick preset's unit)."""
    s = compress_schedule(1500)
    assert s["densify"] == {"start_iter": 125, "interval": 125, "stop_iter": 1125, "opacity_reset_interval": 15000,
                            "prune_big_after": 150, "sh_degree_interval": 125, "filter_3d_until_iter": 1375,
                            "late_prune_interval": 125, "hidden_prune_iters": [1250, 1375]}
    assert s["loss"] == {"regularization_from_iter": 750} and s["optim"] == {"means_lr_max_steps": 1500}
    q = compress_schedule(1200)["densify"]
    assert (q["start_iter"], q["stop_iter"], q["filter_3d_until_iter"]) == (100, 900, 1100)  # quick.yaml's
    odd = compress_schedule(1000)  # u = round(83.3) = 83
    assert odd["densify"]["stop_iter"] == 747 and odd["loss"]["regularization_from_iter"] == 498


@pytest.mark.parametrize("n", [MIN_ITERATIONS, 131, 999, 30_000])
def test_compressed_schedule_is_a_valid_ordered_config(n):
    cfg = TrainConfig()
    from gof_warp.core.config import merge

    cfg = merge(cfg, compress_schedule(n))
    d = cfg.densify
    assert 0 < d.start_iter < cfg.loss.regularization_from_iter < d.stop_iter < d.filter_3d_until_iter < n
    assert d.hidden_prune_iters[-1] < n and d.opacity_reset_interval > n


@pytest.mark.parametrize("bad", [MIN_ITERATIONS - 1, 0, 1.5e3, True])
def test_compress_schedule_refuses_short_or_non_integer_runs(bad):
    with pytest.raises(ConfigError, match="compressed schedule"):
        compress_schedule(bad)


@pytest.mark.parametrize("size, d", [((540, 960), 3), ((128, 128), 1), ((4000, 3000), 14), ((320, 200), 1),
                                      ((321, 200), 2)])
def test_cpu_downscale_golden(size, d):
    """The smallest integer d with round(W/d)·round(H/d) <= 64,000."""
    assert cpu_downscale(*size) == d


def test_cpu_yaml_holds_the_rule_for_its_own_length():
    """configs/cpu.yaml's schedule is compress_schedule(its iterations): the file reads as what a run gets."""
    data = load_yaml(preset_path("cpu"))
    want = compress_schedule(data["iterations"])
    for section in ("densify", "loss", "optim"):
        for k, v in want[section].items():
            assert data[section][k] == v, f"{section}.{k}"


def test_cpu_preset_loads_and_is_for_real_captures():
    assert "cpu" in PRESETS
    cfg = resolve_config("cpu", [], None)
    assert cfg.iterations == 1500 and cfg.model.init == "auto" and cfg.random_background
    assert cfg.loss.lambda_distortion == 100.0 and cfg.data.test_every == 8 and cfg.data.downscale == 1.0


def test_cpu_preset_rescales_its_schedule_and_overrides_win():
    cfg = resolve_config("cpu", ["densify.stop_iter=500"], 600)
    assert cfg.iterations == 600 and cfg.densify.interval == 50 and cfg.optim.means_lr_max_steps == 600
    assert cfg.densify.stop_iter == 500  # the override, not 9u = 450
    assert resolve_config("cpu", ["iterations=2400"], None).densify.start_iter == 200
    with pytest.raises(ConfigError, match="compressed schedule"):
        resolve_config("cpu", [], 50)


def test_other_presets_are_not_rescaled():
    assert resolve_config("quick", [], 600).densify.stop_iter == 900
    assert resolve_config("unbounded", [], 600).densify.stop_iter == 15_000


@pytest.fixture(scope="module")
def big_scene(tmp_path_factory):
    """instant-ngp images of 400×300 = 120,000 pixels: the cpu preset halves them (200×150)."""
    return make_ingp_scene(tmp_path_factory.mktemp("big") / "ingp", n=3, size=(400, 300))


def test_cpu_preset_downscale_from_the_scene(big_scene):
    assert resolve_config("cpu", [], None, scene=big_scene).data.downscale == 2.0
    assert resolve_config("cpu", ["data.downscale=3"], None, scene=big_scene).data.downscale == 3.0
    assert resolve_config("unbounded", [], None, scene=big_scene).data.downscale == 1.0


def _resolved(monkeypatch, argv) -> TrainConfig:
    """The config ``train.main(argv)`` resolves (the command stops right after it)."""
    got = {}

    def capture(*args, **kwargs):
        got["cfg"] = resolve_config(*args, **kwargs)
        raise GofError("stopped by the test")

    monkeypatch.setattr(train, "resolve_config", capture)
    assert train.main(argv) == 2
    return got["cfg"]


def test_downscale_flag_reaches_the_config(big_scene, tmp_path, monkeypatch):
    cfg = _resolved(monkeypatch, [str(big_scene), "--out", str(tmp_path / "r"), "--config", "cpu", "--downscale",
                                  "4", "--quiet"])
    assert cfg.data.downscale == 4.0
    cfg = _resolved(monkeypatch, [str(big_scene), "--out", str(tmp_path / "r"), "--config", "unbounded",
                                  "data.downscale=3", "--downscale", "2", "--quiet"])
    assert cfg.data.downscale == 2.0  # the flag wins over the override


@pytest.mark.parametrize("bad", ["0", "-2", "1.5", "two"])
@pytest.mark.parametrize("command", [train, inspect_scene])
def test_bad_downscale_is_exit_2_with_a_named_error(command, bad, big_scene, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        command.main([str(big_scene), "--out", str(tmp_path / "r"), f"--downscale={bad}"] if command is train
                     else [str(big_scene), f"--downscale={bad}"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "argument --downscale: must be an integer >= 1" in err and repr(bad) in err
    assert not (tmp_path / "r").exists()


def test_inspect_downscale(big_scene, capsys):
    assert inspect_scene.main([str(big_scene), "--downscale", "2", "--json"]) == 0
    assert '"200x150' in capsys.readouterr().out


def test_expected_time_model():
    """CPU: iterations × 24 s per megapixel; CUDA: 10 ms an iteration; unknown devices: no estimate."""
    assert expected_train_seconds(1500, 57_600, "cpu") == pytest.approx(1500 * 24.0 * 0.0576)
    assert expected_train_seconds(1000, 10**6, "cuda:0") == pytest.approx(10.0)
    assert expected_train_seconds(10, 10, "mps") is None
    assert eta_from_pace(0.5, 100, "cpu") == pytest.approx(90.0) and eta_from_pace(0.5, 100, "cuda") == 50.0


def test_train_plan_line(big_scene):
    from gof_warp.data import DataConfig, load_scene

    cfg = resolve_config("cpu", [], None, scene=big_scene)
    scene = load_scene(big_scene, cfg.data, device="cpu")
    line = train.plan_line("cpu", cfg, scene, "cpu")
    assert line.startswith("plan: preset cpu, 1500 iterations, training views 200x150 px (data.downscale 2)")
    assert "roughly 18:00" in line  # 1500 × 24 s × 0.03 MP = 1080 s
    assert "no time model" in train.plan_line("cpu", cfg, load_scene(big_scene, DataConfig(), device="cpu"), "mps")


def test_pace_line_after_the_first_iterations(caplog):
    """One log line after ETA_AFTER_ITERATIONS iterations past the first: their pace, and the time left × 1.8."""
    import logging

    from gof_warp.core.progress import format_seconds
    from gof_warp.training.schedule import ETA_AFTER_ITERATIONS as n

    seen = []
    pace = train._Pace(lambda it, info: seen.append(it), start=10, total=500, device="cpu", quiet=False)
    now = {"it": 0}
    pace.clock = lambda: 2.0 * now["it"]  # 2 s an iteration
    with caplog.at_level(logging.INFO, logger="gof_warp.cli.train"):
        for it in range(11, 11 + n + 5):
            now["it"] = it
            pace(it, {})
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("pace")]
    left = 500 - (11 + n)
    assert seen == list(range(11, 11 + n + 5))
    assert lines == [f"pace after {n} iterations: 2.000 s an iteration; about "
                     f"{format_seconds(left * 2.0 * 1.8)} of "
                     "training left (rough: later iterations draw more Gaussians)"]
