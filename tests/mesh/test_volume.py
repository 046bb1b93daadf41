"""The opacity field baked into a sparse Warp volume (gof_warp.mesh.volume): exact at the voxels, within the trilinear
bound between them on a smooth field, second-order convergent, sparse, bounded by its budgets, saved and
loaded as .nvdb, and clear errors for bad inputs. The measured errors on a sharp scene are printed (pytest -s)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import warp as wp

from gof_warp.core.camera import look_at
from gof_warp.core.errors import GofError
from gof_warp.core.model import Gaussians
from gof_warp.rendering.opacity_field import opacity_field
from gof_warp.rendering.render import RenderConfig
from gof_warp.mesh.volume import (VolumeConfig, bake_opacity_volume, bake_run, derive_voxel_size, load_volume,
                             sample_volume, save_volume)

# One isotropic Gaussian: its field is smooth on the scale σ, so trilinear interpolation obeys the textbook bound.
SIGMA, ALPHA = 0.2, 0.9
R_LEVEL = SIGMA * np.sqrt(2 * np.log(2 * ALPHA))  # radius of the 0.5 level of α·exp(−r²/2σ²)
FLOAT32_NODE_TOL = 1e-5  # at voxel centres the volume stores the float32 field itself

# The ground-and-sphere scene (shared with test_warp_examples_volume.py): a ground plane z = 0 (a layer of flat
# Gaussians below it) and a sphere (a shell of flat Gaussians inside it); the field's 0.5 level lies within
# LEVEL_TOL of both (measured: z ≈ +0.005, r ≈ 0.305).
SPHERE_C, SPHERE_R, GROUND_HALF, LEVEL_TOL = np.array([0.0, 0.0, 0.45]), 0.3, 1.0, 0.012


def _normal_to_quat(n: np.ndarray) -> np.ndarray:
    """wxyz quaternions rotating +z onto the unit normals ``n`` [K, 3] (n ≠ −z)."""
    q = np.stack([1.0 + n[:, 2], -n[:, 1], n[:, 0], np.zeros(len(n))], 1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def ground_and_sphere(device="cpu") -> Gaussians:
    """1,241 opaque flat Gaussians: a ground layer under z = 0 over [−1, 1]² and a shell inside the sphere."""
    xs = np.arange(-GROUND_HALF, GROUND_HALF + 1e-9, 0.07)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    ground = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, -0.03)], 1)
    k = 400
    i = np.arange(k) + 0.5
    phi, theta = np.arccos(1 - 2 * i / k), np.pi * (1 + 5 ** 0.5) * i  # Fibonacci sphere
    n = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
    means = np.concatenate([ground, SPHERE_C + (SPHERE_R - 0.05) * n])
    quats = np.concatenate([np.tile([1.0, 0, 0, 0], (len(ground), 1)), _normal_to_quat(n)])
    scales = np.tile([0.05, 0.05, 0.02], (len(means), 1))
    return Gaussians.from_activated(means, quats, scales, np.full(len(means), 0.98), np.full((len(means), 3), 0.6),
                                    device=device)


def scene_cameras(n: int = 8, size: int = 48):
    """``n`` cameras on a ring above the ground, looking at the sphere's foot."""
    cams = []
    for a in range(n):
        ang = 2 * np.pi * a / n
        eye = [2.6 * np.cos(ang), 2.6 * np.sin(ang), 1.2 + 0.6 * (a % 2)]
        cams.append(look_at(eye, [0, 0, 0.1], fx=0.9 * size, width=size, height=size, name=f"v{a:02d}"))
    return cams


def inside_ground_truth(points: np.ndarray, tol: float) -> np.ndarray:
    """``[M]`` bool: deeper than ``tol`` below the ground or inside the sphere."""
    return (points[:, 2] < -tol) | (np.linalg.norm(points - SPHERE_C, axis=1) < SPHERE_R - tol)


def _ring(n=8, size=48):
    cams = []
    for a in range(n):
        ang = 2 * np.pi * a / n
        cams.append(look_at([2.0 * np.cos(ang), 2.0 * np.sin(ang), 0.9 * np.sin(3 * ang)], [0, 0, 0], fx=1.25 * size,
                            width=size, height=size, name=f"c{a:02d}"))
    return cams


def _one_gaussian():
    return Gaussians.from_activated(np.zeros((1, 3)), [[1.0, 0, 0, 0]], np.full((1, 3), SIGMA), [ALPHA], device="cpu")


RC_SMOOTH = RenderConfig(alpha_min=0.0, k_max=10.0)


def _near_sphere(rng, n, radius, width):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * (radius + rng.uniform(-width, width, size=(n, 1)))


def test_one_gaussian_exact_at_voxels_within_trilinear_bound_and_second_order():
    """At voxel centres the volume is the field; between them the error obeys
    |e| ≤ h²/8 · Σ|∂ᵢᵢf| ≤ 3αh²/(8σ²) and halves twice when h halves (second order)."""
    g, cams = _one_gaussian(), _ring()
    rng = np.random.default_rng(0)
    max_err = {}
    for h in (0.06, 0.03):
        vol, info = bake_opacity_volume(g, cams, voxel_size=h, render_config=RC_SMOOTH)
        assert info["voxel_size"] == h and info["active_voxels"] == info["fine_samples"]
        if h == 0.03:  # small voxels: the band of 8³ bricks around the sphere is a fraction of the box
            assert info["active_voxels"] < 0.4 * info["dense_voxels"], info
        ijk = vol.get_voxels().numpy()[rng.choice(info["active_voxels"], 4000, replace=False)]
        nodes = np.asarray(info["origin"]) + h * ijk
        exact = opacity_field(g, cams, nodes, render_config=RC_SMOOTH).numpy()
        np.testing.assert_allclose(sample_volume(vol, nodes), exact, atol=FLOAT32_NODE_TOL)
        pts = _near_sphere(rng, 20000, R_LEVEL, 3 * h)
        err = np.abs(sample_volume(vol, pts) - opacity_field(g, cams, pts, render_config=RC_SMOOTH).numpy())
        bound = 3 * ALPHA * h * h / (8 * SIGMA ** 2)
        print(f"one Gaussian, h={h}: error mean {err.mean():.2e} p95 {np.percentile(err, 95):.2e} "
              f"max {err.max():.2e} (bound {bound:.2e}); {info['active_voxels']} voxels, {info['bytes']} B")
        assert err.max() <= bound, (err.max(), bound)
        max_err[h] = err.max()
    assert max_err[0.06] / max_err[0.03] > 3.0, max_err  # h² convergence (4 in the limit)


@pytest.fixture(scope="module")
def baked_scene():
    g, cams = ground_and_sphere(), scene_cameras()
    vol, info = bake_opacity_volume(g, cams)  # the derived voxel size
    return g, cams, vol, info


# Measured on this scene at the derived h = 0.0375 (about 2σ of the Gaussians' thin axis, a sharp field):
# mean 0.04, p95 0.18, max 0.25 within 3 voxels of the surface; the 0.5 level moves by < 0.2 h.
SHARP_MEAN_TOL, SHARP_P95_TOL, SHARP_MAX_TOL, LEVEL_SHIFT_TOL = 0.06, 0.25, 0.35, 0.35


def test_ground_and_sphere_volume_is_sparse_and_near_the_exact_field(baked_scene):
    g, cams, vol, info = baked_scene
    h = info["voxel_size"]
    assert h == pytest.approx(derive_voxel_size(g))  # 3 · 0.05 / 4: within the default budgets
    assert info["active_voxels"] < info["dense_voxels"], info
    rng = np.random.default_rng(1)
    ground = np.c_[rng.uniform(-0.8, 0.8, (6000, 2)), rng.uniform(-3 * h, 3 * h, 6000)]
    ground = ground[np.linalg.norm(ground - SPHERE_C, axis=1) > SPHERE_R + 3 * h]
    sphere = SPHERE_C + _near_sphere(rng, 6000, SPHERE_R, 3 * h)
    pts = np.concatenate([ground, sphere[sphere[:, 2] > 3 * h]])
    err = np.abs(sample_volume(vol, pts) - opacity_field(g, cams, pts).numpy())
    print(f"ground+sphere, h={h:.4f}: error mean {err.mean():.3f} p95 {np.percentile(err, 95):.3f} max "
          f"{err.max():.3f}; {info['active_voxels']} voxels, {info['bytes'] / 1e6:.2f} MB, "
          f"{info['time_s']['total']:.1f} s")
    assert err.mean() < SHARP_MEAN_TOL and np.percentile(err, 95) < SHARP_P95_TOL and err.max() < SHARP_MAX_TOL
    # where the 0.5 level sits: along rays out of the sphere's centre, volume vs exact field
    dirs = _near_sphere(rng, 64, 1.0, 0.0)
    dirs = dirs[dirs[:, 2] > -0.5]
    r = np.linspace(SPHERE_R - 3 * h, SPHERE_R + 3 * h, 121)
    ray_pts = (SPHERE_C + dirs[:, None, :] * r[None, :, None]).reshape(-1, 3)
    crossings = []
    for f in (sample_volume(vol, ray_pts), opacity_field(g, cams, ray_pts).numpy()):
        f = f.reshape(len(dirs), len(r))
        crossings.append(r[np.argmax(f < 0.5, axis=1)])  # first sample below the level, going outwards
    shift = np.abs(crossings[0] - crossings[1])
    print(f"0.5 level shift along {len(dirs)} rays: mean {shift.mean() / h:.2f} h, max {shift.max() / h:.2f} h")
    assert shift.max() <= LEVEL_SHIFT_TOL * h + (r[1] - r[0]), shift.max() / h
    assert np.all(np.abs(crossings[1] - SPHERE_R) < LEVEL_TOL)  # the scene's stated ground truth holds
    far = np.array([[0.0, 0.0, 5.0], [9.0, 9.0, 9.0]])
    np.testing.assert_array_equal(sample_volume(vol, far), 0.0)  # background: empty


def test_save_and_load_nvdb_roundtrip(baked_scene, tmp_path):
    _, _, vol, info = baked_scene
    path = save_volume(vol, tmp_path / "sub" / "scene.nvdb")
    assert path.is_file() and [p.name for p in path.parent.iterdir()] == ["scene.nvdb"]  # no temporary left
    loaded = load_volume(path, device="cpu")
    with open(path, "rb") as f:
        plain = wp.Volume.load_from_nvdb(f)  # what a Warp user does
    pts = np.random.default_rng(2).uniform(info["bounds_min"], info["bounds_max"], size=(5000, 3))
    ref = sample_volume(vol, pts)
    np.testing.assert_array_equal(sample_volume(loaded, pts), ref)
    np.testing.assert_array_equal(sample_volume(plain, pts), ref)
    assert loaded.get_voxel_count() == info["active_voxels"]
    save_volume(vol.array().numpy().tobytes(), tmp_path / "bytes.nvdb")  # grid bytes are accepted too
    np.testing.assert_array_equal(sample_volume(load_volume(tmp_path / "bytes.nvdb"), pts), ref)
    (tmp_path / "bad.nvdb").write_bytes(b"not a volume at all, not even close")
    with pytest.raises(GofError, match="not a NanoVDB"):
        load_volume(tmp_path / "bad.nvdb")
    with pytest.raises(GofError, match="cannot read"):
        load_volume(tmp_path / "missing.nvdb")
    with pytest.raises(GofError, match="wp.Volume"):
        save_volume([1, 2, 3], tmp_path / "x.nvdb")


def test_budget_enlarges_a_derived_voxel_size_and_rejects_a_given_one():
    g, cams = _one_gaussian(), _ring(n=4, size=32)
    small = VolumeConfig(voxels_per_extent=32.0, max_voxels=150 * 512)  # the rule alone needs 275 bricks
    vol, info = bake_opacity_volume(g, cams, config=small, render_config=RC_SMOOTH)
    assert info["voxel_size"] > info["voxel_size_rule"] and info["active_voxels"] <= small.max_voxels
    with pytest.raises(GofError, match="larger voxel size"):
        bake_opacity_volume(g, cams, voxel_size=0.01, config=small, render_config=RC_SMOOTH)


@pytest.mark.parametrize("kwargs, match", [
    (dict(voxel_size=0.0), "voxel_size"), (dict(voxel_size=float("nan")), "voxel_size"),
    (dict(band=-1), "band"), (dict(config=VolumeConfig(coarse_step=3)), "coarse_step"),
    (dict(config=VolumeConfig(level=1.5)), "level"),
])
def test_bad_arguments_are_clear_errors(kwargs, match):
    with pytest.raises(GofError, match=match):
        bake_opacity_volume(_one_gaussian(), _ring(n=2, size=16), **kwargs)


def test_no_cameras_no_gaussians_nothing_seen_are_clear_errors():
    g = _one_gaussian()
    with pytest.raises(GofError, match="camera"):
        bake_opacity_volume(g, [])
    with pytest.raises(GofError, match="no Gaussians"):
        bake_opacity_volume(g.subset(np.zeros(1, dtype=bool)), _ring(n=2))
    away = [look_at([0, 0, 3.0], [0, 0, 6.0], fx=20, width=16, height=16)]  # looks away from the Gaussian
    with pytest.raises(GofError, match="nothing to bake"):
        bake_opacity_volume(g, away, render_config=RC_SMOOTH)


def test_bake_run_writes_nvdb_and_info(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    _one_gaussian().save_ply(run / "point_cloud.ply")
    cams = _ring(n=4, size=32)
    (run / "cameras.json").write_text(json.dumps({"train": [c.to_dict() for c in cams], "test": []}))
    info = bake_run(run, voxel_size=0.08, device="cpu")
    nvdb = run / "opacity_volume.nvdb"
    assert info["nvdb"] == str(nvdb) and info["file_bytes"] == nvdb.stat().st_size
    assert json.loads(nvdb.with_suffix(".json").read_text())["active_voxels"] == info["active_voxels"] > 0
    assert load_volume(nvdb).get_voxel_count() == info["active_voxels"]
    with pytest.raises(GofError):
        bake_run(tmp_path / "nowhere")


@pytest.mark.slow
def test_extract_cli_bakes_a_volume(tmp_path):
    """``python -m gof_warp.extract RUN --volume --voxel-size H`` writes RUN/opacity_volume.nvdb and its JSON."""
    import subprocess
    import sys

    run = tmp_path / "run"
    run.mkdir()
    _one_gaussian().save_ply(run / "point_cloud.ply")
    (run / "cameras.json").write_text(json.dumps({"train": [c.to_dict() for c in _ring(n=4, size=32)], "test": []}))
    p = subprocess.run([sys.executable, "-m", "gof_warp.extract", str(run), "--volume", "--voxel-size", "0.08",
                        "--device", "cpu"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert "opacity_volume.nvdb" in p.stdout and (run / "opacity_volume.nvdb").stat().st_size > 0
    assert json.loads((run / "opacity_volume.json").read_text())["active_voxels"] > 0
