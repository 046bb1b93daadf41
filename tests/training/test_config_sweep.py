"""One bad value per section of TrainConfig through the real ``train`` entry: exit code 2, one ``error:`` line that
names the dotted key, no traceback. Old keys still load, moved with a warning; one seed drives densification."""

import warnings

import pytest
import torch

from gof_warp.cli import train
from gof_warp.core.config import combine_overrides, dump_yaml, from_dict, load_yaml, merge, to_dict
from gof_warp.training.settings import ConfigDeprecationWarning, run_render_config
from gof_warp.training.trainer import TrainConfig

BAD = [  # (override, the key the error must name)
    ("iterations=0", "iterations"),
    ("seed=-1", "seed"),
    ("views_per_step=-1", "views_per_step"),
    ("data.downscale=0.5", "data.downscale"),
    ("model.init=nowhere", "model.init"),
    ("render.near=-1", "render.near"),
    ("render.alpha_max=1.5", "render.alpha_max"),
    ("loss.lambda_dssim=2", "loss.lambda_dssim"),
    ("optim.means_lr_max_steps=0", "optim.means_lr_max_steps"),
    ("densify.interval=0", "densify.interval"),
    ("performance.tile_list_margin=0.5", "performance.tile_list_margin"),
    ("performance.adam=sgd", "performance.adam"),
    ("experimental.multiview.patch=4", "experimental.multiview.patch"),
    ("experimental.densify_metric=other", "experimental.densify_metric"),
    ("experimental.distortion_linear_from=0.1", "experimental.distortion_linear_from"),
    ("experimental.normal_form=other", "experimental.normal_form"),
]


@pytest.mark.parametrize("override,key", BAD, ids=[k for _, k in BAD])
def test_bad_value_is_one_error_line_naming_the_key(override, key, tmp_path, capsys):
    # a scene folder that does not exist: a bad override is named before the scene is read
    rc = train.main([str(tmp_path / "no_scene"), override, "--out", str(tmp_path / "run"), "--iterations", "1",
                     "--quiet", "--no-pictures"] + (["--iterations", "0"] if key == "iterations" else []))
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.startswith("error: ")]
    assert len(lines) == 1 and key in lines[0], err


OLD_RUN_CONFIG = {  # keys as runs written before the experimental/performance sections have them
    "iterations": 50, "compile_loss": "off", "tile_list_margin": 0, "cudnn_benchmark": True, "checksum_every": 10,
    "render": {"tile_cull": False, "distortion_linear_from": 5.0, "near": 0.2},
    "loss": {"normal_form": "gof", "multiview": {"weight": 0.15, "patch": 5}},
    "optim": {"fused": False, "adam": "torch", "means_lr_delay_steps": 10},
    "densify": {"metric": "paper", "seed": 0},
    "model": {"background_points": 7},
}


def test_old_keys_load_moved_with_a_warning(tmp_path):
    path = tmp_path / "config.yaml"
    import yaml

    path.write_text(yaml.safe_dump(OLD_RUN_CONFIG))
    with pytest.warns(ConfigDeprecationWarning, match=r"loss\.multiview -> experimental\.multiview"):
        cfg = from_dict(TrainConfig, load_yaml(path), str(path))
    e, p = cfg.experimental, cfg.performance
    assert (e.tile_cull, e.distortion_linear_from, e.normal_form, e.multiview.weight, e.multiview.patch) == \
        (False, 5.0, "gof", 0.15, 5)
    assert (e.means_lr_delay_steps, e.densify_metric, e.background_points) == (10, "paper", 7)
    assert (p.compile_loss, p.tile_list_margin, p.checksum_every, p.adam) == ("off", 0, 10, "torch-loop")
    # the stage configs the code reads carry the same values as before
    assert (cfg.render.tile_cull, cfg.render.distortion_linear_from, cfg.loss.normal_form) == (False, 5.0, "gof")
    assert (cfg.loss.multiview.weight, cfg.optim.fused, cfg.optim.adam, cfg.densify.metric) == (0.15, False, "torch",
                                                                                                "paper")
    assert (cfg.optim.means_lr_delay_steps, cfg.model.background_points) == (10, 7)
    # an old override on the command line too, and the new file round-trips without warnings
    with pytest.warns(ConfigDeprecationWarning):
        again = merge(TrainConfig(), combine_overrides(["loss.multiview.weight=0.15", "optim.fused=false"]))
    assert again.experimental.multiview.weight == 0.15 and again.performance.adam == "torch-loop"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert dump_yaml(from_dict(TrainConfig, yaml.safe_load(dump_yaml(cfg)))) == dump_yaml(cfg)
    # extract's and pictures' view of a run folder: the render settings, old file or new
    with pytest.warns(ConfigDeprecationWarning):
        old_render = run_render_config(OLD_RUN_CONFIG, "old")
    new_render = run_render_config(yaml.safe_load(dump_yaml(cfg)), "new")
    assert to_dict(old_render) == to_dict(new_render) and new_render.tile_cull is False and new_render.distortion_linear_from == 5.0


def test_presets_load_without_warnings():
    from gof_warp.training.presets import PRESETS, resolve_config

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in PRESETS:
            if name != "auto":
                resolve_config(name, [], None)


def _children(seed: int) -> torch.Tensor:
    """The means of the children the densifier (built as the trainer builds it) samples for three Gaussians."""
    import numpy as np

    from gof_warp.core.model import Gaussians
    from gof_warp.training.densify import Densifier, sample_children

    cfg = merge(TrainConfig(), {"seed": seed})
    means = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    g = Gaussians.from_activated(means, np.tile([1.0, 0, 0, 0], (3, 1)), np.full((3, 3), 0.3), np.full(3, 0.5),
                                 np.full((3, 3), 0.5), device="cpu")
    densifier = Densifier(cfg.densify)
    return sample_children(g, torch.arange(3), 2, densifier._generator(torch.device("cpu")))["means"]


def test_seed_reaches_densification():
    assert TrainConfig().densify.seed == 0  # the default run samples as it always did
    assert torch.equal(_children(0), _children(0))
    assert torch.equal(_children(5), _children(5))
    assert not torch.equal(_children(0), _children(5))
