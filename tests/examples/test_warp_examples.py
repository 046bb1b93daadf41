"""The pure-Warp examples run on the CPU in a fresh process that never imports torch, and do what they say.

* ``warp_marching_gyroid``: vertices on the analytic surface (float64 reference), watertight and outward,
  enclosed volume = the solid's volume (float64 Monte Carlo), bisection far better than interpolation.
* ``warp_fit_gaussians``: the loss falls by a clear factor and PSNR rises.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # runs the examples in fresh interpreters

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
RUNNER = """
import importlib, json, sys
sys.path.insert(0, {examples!r})
module = importlib.import_module({name!r})
results = [module.main(args) for args in {arg_sets!r}]
assert "torch" not in sys.modules, "torch was imported"
print("RESULTS " + json.dumps(results))
"""


def run_example(name: str, arg_sets: list, tmp_path: Path) -> list:
    """Run ``examples/<name>.py``'s ``main(args)`` for each argument list in one fresh process (no torch)."""
    code = RUNNER.format(examples=str(EXAMPLES), name=name, arg_sets=arg_sets)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULTS ")][-1]
    return json.loads(line[len("RESULTS "):])


def gyroid_np(x, k, r):
    """float64: ``min(gyroid(k x), k (r − |x|))`` and its gradient (of the active branch)."""
    q = k * x
    s, c = np.sin(q), np.cos(q)
    g = s[:, 0] * c[:, 1] + s[:, 1] * c[:, 2] + s[:, 2] * c[:, 0]
    dg = k * np.stack([c[:, 0] * c[:, 1] - s[:, 2] * s[:, 0],
                       -s[:, 0] * s[:, 1] + c[:, 1] * c[:, 2],
                       -s[:, 1] * s[:, 2] + c[:, 2] * c[:, 0]], 1)
    norm = np.linalg.norm(x, axis=1)
    ball = k * (r - norm)
    dball = -k * x / np.maximum(norm, 1e-12)[:, None]
    use_g = g <= ball
    return np.where(use_g, g, ball), np.where(use_g[:, None], dg, dball)


def test_gyroid_surface_is_on_the_analytic_level_set_and_closed(tmp_path):
    out = tmp_path / "gyroid"
    searched, linear = run_example("warp_marching_gyroid", [["--resolution", "32", "--out", str(out)],
                                                            ["--resolution", "32", "--steps", "0"]], tmp_path)
    mesh = np.load(out / "mesh.npz")
    v, f = mesh["vertices"].astype(np.float64), mesh["faces"]
    k, r, h = float(mesh["frequency"]), float(mesh["radius"]), float(mesh["spacing"])
    assert searched["faces"] == f.shape[0] > 1000 and searched["watertight"]

    # distance to the surface, to first order |f| / |∇f|: within the final bracket (cube diagonal / 2⁸)
    value, grad = gyroid_np(v, k, r)
    distance = np.abs(value) / np.linalg.norm(grad, axis=1)
    bracket = np.sqrt(3) * h / 2**8
    assert distance.max() < bracket, (distance.max(), bracket)
    assert linear["max_abs_field"] > 100 * searched["max_abs_field"], "bisection must beat interpolation"

    # watertight and consistently wound: every directed edge once, every undirected edge twice
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    _, n_dir = np.unique(directed, axis=0, return_counts=True)
    _, n_und = np.unique(np.sort(directed, 1), axis=0, return_counts=True)
    assert np.all(n_dir == 1) and np.all(n_und == 2)

    # normals point outwards (from f >= 0 to f < 0): enclosed volume is positive and matches the solid's
    volume = np.einsum("ij,ij->i", np.cross(v[f[:, 0]], v[f[:, 1]]), v[f[:, 2]]).sum() / 6
    rng = np.random.default_rng(0)
    samples = rng.uniform(-r, r, (400_000, 3))
    inside = gyroid_np(samples, k, r)[0] >= 0
    mc_volume = inside.mean() * (2 * r) ** 3  # standard error ≈ 0.3 % here
    assert volume > 0 and abs(volume / mc_volume - 1) < 0.03, (volume, mc_volume)


def test_fit_gaussians_reduces_the_loss(tmp_path):
    result, = run_example("warp_fit_gaussians", [["--iterations", "60", "--num", "80"]], tmp_path)
    assert result["mse_last"] < result["mse_first"] / 5, result
    assert result["psnr_last"] > result["psnr_first"] + 7.0, result


@pytest.mark.parametrize("name", ["warp_fit_gaussians", "warp_marching_gyroid", "warp_tape_render"])
def test_warp_examples_import_no_torch(name):
    """Static guard beside the run-time one: the example's source names no torch import."""
    source = (EXAMPLES / f"{name}.py").read_text()
    assert "import torch" not in source and "from torch" not in source
