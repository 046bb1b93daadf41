"""evaluate --photos: a coloured mesh rendered from a run's test views and scored against their photos, checked
against PSNRs computed here from the photos alone (a mesh no ray hits shows the background; a sphere around
everything shows its one colour)."""

import json

import numpy as np
import pytest
import trimesh

from gof_warp.cli import evaluate
from gof_warp.core.errors import GofError
from gof_warp.viz.photo_fidelity import mesh_photo_fidelity
from gof_warp.training.run_folder import cameras_from_json
from gof_warp.viz.pictures import run_photos

TINY = {
    "iterations": 8,
    "checkpoint_every": 100,
    "log_every": 4,
    "model": {"sh_degree": 0, "init": "random", "random_init_points": 300},
    "optim": {"means_lr_max_steps": 8},
    "densify": {"start_iter": 100, "stop_iter": 100, "filter_3d_until_iter": 0},
    "loss": {"regularization_from_iter": 100},
    "data": {"test_every": 3},
}


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from gof_warp.core.config import merge
    from gof_warp.data import load_scene
    from gof_warp.synthetic import make_scene
    from gof_warp.training.trainer import TrainConfig, Trainer

    cfg = merge(TrainConfig(), TINY)
    run = tmp_path_factory.mktemp("photometric") / "run"
    make_scene("default", run / "scene", views=6, resolution=(32, 24), device="cpu")
    Trainer(load_scene(run / "scene", cfg.data), cfg, run, "cpu").run()
    return run


def _psnr(images, photos):
    """Mean over views of each view's PSNR (as the image metrics take it), from uint8 photos."""
    out = []
    for x, y in zip(images, photos):
        mse = np.mean((np.asarray(x, np.float64) - np.asarray(y, np.float64) / 255.0) ** 2)
        out.append(10 * np.log10(1.0 / mse))
    return float(np.mean(out))


def _coloured(mesh, rgb, path):
    mesh.visual.vertex_colors = np.tile([*rgb, 255], (len(mesh.vertices), 1)).astype(np.uint8)
    mesh.export(path)
    return path


def test_a_mesh_no_view_sees_scores_as_the_background_and_a_sphere_around_all_as_its_colour(run, tmp_path):
    cams = cameras_from_json(run / "cameras.json", "test")
    photos = run_photos(run, cams, "cpu")
    assert cams and photos is not None
    far = trimesh.creation.icosphere(subdivisions=1, radius=0.01)
    far.apply_translation([1e4, 1e4, 1e4])
    r = mesh_photo_fidelity(run, _coloured(far, (200, 30, 30), tmp_path / "far.ply"), device="cpu")
    black = [np.zeros((c.height, c.width, 3)) for c in cams]  # the run's background (the default scene's: black)
    assert r["mesh"]["coverage"] == 0.0 and r["views"] == len(cams)
    assert r["mesh"]["psnr"] == pytest.approx(_psnr(black, photos), abs=1e-3)
    colour = np.array([90, 140, 200])
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1e3)
    r = mesh_photo_fidelity(run, _coloured(sphere, colour, tmp_path / "sphere.ply"), device="cpu")
    flat = [np.broadcast_to(colour / 255.0, (c.height, c.width, 3)) for c in cams]
    assert r["mesh"]["coverage"] == 1.0
    assert r["mesh"]["psnr"] == pytest.approx(_psnr(flat, photos), abs=1e-3)
    assert 5.0 < r["gaussians"]["psnr"] < 60.0 and r["appearance"] == "vertex"


def test_evaluate_with_photos_only_prints_and_writes_the_scores(run, tmp_path, capsys):
    mesh = _coloured(trimesh.creation.icosphere(subdivisions=2, radius=0.5), (120, 120, 120), tmp_path / "m.ply")
    out = tmp_path / "r.json"
    assert evaluate.main(["--mesh", str(mesh), "--photos", str(run), "--json", str(out), "--device", "cpu"]) == 0
    text = capsys.readouterr().out
    assert "mesh       PSNR" in text and "Gaussians  PSNR" in text
    report = json.loads(out.read_text())["photometric"]
    assert report["split"] == "test" and 0.0 < report["mesh"]["coverage"] < 1.0


def test_a_mesh_without_colours_a_folder_that_is_no_run_and_no_reference_are_clear_errors(run, tmp_path, capsys):
    plain = tmp_path / "plain.ply"
    trimesh.creation.icosphere(subdivisions=1).export(plain)
    with pytest.raises(GofError, match="has no colours"):
        mesh_photo_fidelity(run, plain, device="cpu")
    with pytest.raises(GofError, match="not a training run folder"):
        mesh_photo_fidelity(tmp_path, plain, device="cpu")
    assert evaluate.main(["--mesh", str(plain)]) == 2
    assert "nothing to score against" in capsys.readouterr().err


def test_photos_of_one_view_are_decoded_without_the_scenes_pose_warnings(run, caplog):
    cams = cameras_from_json(run / "cameras.json", "train")[:1]
    with caplog.at_level("WARNING"):
        photos = run_photos(run, cams, "cpu")
    assert len(photos) == 1 and photos[0].shape == (cams[0].height, cams[0].width, 3)
    assert "training view" not in caplog.text
