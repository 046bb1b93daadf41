"""The Warp-user examples on a baked opacity volume, run as a user runs them: a scene with exact ground truth
(a ground plane and a sphere of opaque Gaussians) is baked to .nvdb by gof_warp.mesh.volume, then
examples/warp_query_volume.py and examples/warp_particles_on_scene.py run in a fresh interpreter that never
imports torch; no particle may end inside the ground-truth solids."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_volume import LEVEL_TOL, SPHERE_C, SPHERE_R, ground_and_sphere, inside_ground_truth, scene_cameras

from gof_warp.mesh.volume import bake_opacity_volume, save_volume

pytestmark = pytest.mark.slow  # bakes a scene, runs the examples in fresh interpreters

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
# Resting particles sit on the volume's 0.5 level: within 0.35 h of the exact level (test_volume), which is
# within LEVEL_TOL of the ground truth; half a voxel more covers the last step's Newton projection.
REST_TOL_VOXELS = 0.5


def _run_example(name: str, args: list[str], cwd: Path) -> str:
    """Run ``examples/NAME`` in a subprocess; fail if it exits non-zero or torch entered ``sys.modules``."""
    path = str(EXAMPLES / name)
    code = ("import runpy, sys; sys.argv = [sys.argv[1], *sys.argv[2:]]; "
            "runpy.run_path(sys.argv[0], run_name='__main__'); "
            "assert 'torch' not in sys.modules, 'the example imported torch'; print('NO-TORCH-OK')")
    proc = subprocess.run([sys.executable, "-c", code, path, *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    assert proc.returncode == 0, f"{name} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    assert "NO-TORCH-OK" in proc.stdout and "torch imported: False" in proc.stdout, proc.stdout
    return proc.stdout


@pytest.fixture(scope="module")
def scene_nvdb(tmp_path_factory):
    vol, info = bake_opacity_volume(ground_and_sphere(), scene_cameras())
    path = save_volume(vol, tmp_path_factory.mktemp("volume") / "scene.nvdb")
    return path, info


def test_query_example_on_baked_scene(scene_nvdb, tmp_path):
    path, info = scene_nvdb
    out = _run_example("warp_query_volume.py", ["--device", "cpu", "--nvdb", str(path), "--points", "100000"],
                       tmp_path)
    m = re.search(r"throughput: ([0-9.e+]+) points/s", out)
    assert m and float(m.group(1)) > 0, out
    assert f"{info['active_voxels']:,} voxels" in out, out  # it read the volume we baked
    inside = float(re.search(r"([0-9.]+)% inside", out).group(1))
    assert 1.0 < inside < 60.0, out  # the box holds both empty space and the solids' band


def test_particles_example_rest_on_the_scene_and_never_inside_it(scene_nvdb, tmp_path):
    path, info = scene_nvdb
    h = info["voxel_size"]
    out = _run_example("warp_particles_on_scene.py", ["--device", "cpu", "--nvdb", str(path), "--particles", "1500",
                                                      "--steps", "900", "--out", str(tmp_path)], tmp_path)
    assert "throughput:" in out, out
    res = np.load(tmp_path / "particles_on_scene.npz")
    x, fell = res["positions"], res["fell"]
    assert (tmp_path / "particles_on_scene.png").stat().st_size > 1000
    assert not fell.any(), f"{fell.sum()} particles left the volume's box"
    tol = LEVEL_TOL + REST_TOL_VOXELS * h
    bad = inside_ground_truth(x, tol)
    assert not bad.any(), f"{bad.sum()} particles inside the ground truth, e.g. {x[bad][:3]}"
    on_ground = np.abs(x[:, 2]) < tol
    on_sphere = np.abs(np.linalg.norm(x - SPHERE_C, axis=1) - SPHERE_R) < tol
    assert np.mean(on_ground | on_sphere) > 0.97, out  # they came to rest on the surfaces
    assert on_sphere.sum() > 0 and on_ground.sum() > 0.5 * len(x)
    # the check can fail: the same particles pushed 2 tolerances down are all inside the ground truth
    assert inside_ground_truth(x - [0, 0, 2 * tol + 1e-3], tol)[on_ground].all()
