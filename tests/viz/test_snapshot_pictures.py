"""Snapshot pictures: training writes RUN/pictures/views_it<N>.png (the panels of views.png) for the model at
each of ``snapshot_iterations``; ``--no-pictures`` writes none; a failure to draw only warns."""

import json
import logging
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from gof_warp.viz import pictures



def _train(scene, run, overrides, *extra):
    from gof_warp.cli import train

    return train.main([str(scene), "--out", str(run), "--config", "quick", "--iterations", "4", "--device", "cpu",
                       "--quiet", *extra, *overrides, "snapshot_iterations=[2]"])


@pytest.mark.slow
def test_a_snapshot_writes_its_views_picture_unless_no_pictures(tiny_train_scene, tiny_train_overrides, tmp_path):
    run = tmp_path / "run"
    assert _train(tiny_train_scene, run, tiny_train_overrides) == 0
    snap = run / "pictures" / "views_it2.png"
    assert snap.is_file()
    with Image.open(snap) as im:
        im.verify()  # a valid PNG
    with Image.open(snap) as im, Image.open(run / "pictures" / "views.png") as end:
        assert im.format == "PNG" and im.size == end.size  # the same views and panels as views.png
        img = np.asarray(im.convert("RGB"))
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20, "the picture is (nearly) uniform"
    assert sorted(p.name for p in (run / "pictures").iterdir()) == ["curves.png", "views.png", "views_it2.png"]
    assert [s["iteration"] for s in json.loads((run / "metrics.json").read_text())["snapshots"]] == [2]

    quiet = tmp_path / "quiet"
    assert _train(tiny_train_scene, quiet, tiny_train_overrides, "--no-pictures") == 0
    assert (quiet / "snapshots" / "iter_2" / "point_cloud.ply").is_file()
    assert not (quiet / "pictures").exists()
    # drawing the snapshot does not change the run
    assert (run / "point_cloud.ply").read_bytes() == (quiet / "point_cloud.ply").read_bytes()


def test_a_snapshot_picture_failure_only_warns(tmp_path, caplog):
    broken = SimpleNamespace(out_dir=tmp_path, iteration=7, gaussians=None, scene=None, render_config=None)
    with caplog.at_level(logging.WARNING):
        assert pictures.snapshot_pictures_or_warning(broken, {"iteration": 7}) == []
    assert "could not write the picture of the snapshot at iteration 7" in caplog.text
    assert not (tmp_path / "pictures" / "views_it7.png").exists()


@pytest.mark.slow
def test_training_goes_on_when_a_snapshot_picture_fails(tiny_train_scene, tiny_train_overrides, tmp_path, monkeypatch, caplog):
    def fail(*args, **kwargs):
        raise RuntimeError("no drawing today")

    monkeypatch.setattr(pictures, "write_model_views", fail)
    run = tmp_path / "run"
    with caplog.at_level(logging.WARNING, logger="gof_warp.viz.pictures"):
        assert _train(tiny_train_scene, run, tiny_train_overrides) == 0
    assert "could not write the picture of the snapshot at iteration 2: no drawing today" in caplog.text
    assert (run / "point_cloud.ply").is_file() and (run / "snapshots" / "iter_2" / "snapshot.json").is_file()
    assert (run / "pictures" / "views.png").is_file() and not (run / "pictures" / "views_it2.png").exists()
