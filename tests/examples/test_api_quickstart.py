"""The README's Python API example (examples/api_quickstart.py) trains, extracts and scores on the CPU."""

import importlib.util
import math
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "api_quickstart.py"


def _example():
    spec = importlib.util.spec_from_file_location("api_quickstart", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_api_quickstart_trains_extracts_and_scores(tmp_path, capsys):
    # smaller than the example's defaults (and a coarser scoring sample) to keep the test short; the same code path
    result = _example().main(["--out", str(tmp_path), "--iterations", "100", "--views", "8", "--size", "32",
                              "--device", "cpu", "--eval-density", "0.02"])
    assert (tmp_path / "run" / "point_cloud.ply").is_file() and (tmp_path / "run" / "metrics.json").is_file()
    assert (tmp_path / "scene" / "gt_mesh.ply").is_file()
    assert result["gaussians"] > 0 and result["image_shape"] == (32, 32, 3)
    assert result["faces"] > 100, result
    for key in ("test_psnr", "chamfer", "fscore"):
        assert result[key] is not None and math.isfinite(result[key]), result
    assert result["test_psnr"] > 10, result  # a trained model, not noise
    assert 0 <= result["fscore"] <= 1 and result["fscore"] > 0, result  # some of the mesh lies on the true surface
    assert result["chamfer"] < 0.5, result  # the scene is ~3 units across: the mesh is near the objects
    out = capsys.readouterr().out
    assert "test PSNR" in out and "Chamfer" in out
