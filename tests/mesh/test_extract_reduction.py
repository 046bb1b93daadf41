"""Point reductions of the tetrahedral grid keep the mesh; the Warp TSDF sampler equals numpy's trilinear."""

import dataclasses

import numpy as np
import pytest
import warp as wp

from gof_warp.eval.geometry_metrics import point_mesh_distance, sample_surface
from gof_warp.mesh.marching import marching_tetrahedra
from gof_warp.mesh.tetra import TetraConfig, tetrahedral_grid
from gof_warp.mesh.tsdf import GridSampler, TSDFVolume

# float32 vs float64: (point − origin) / voxel rounds to ~1e-6 voxels, times slopes up to 2 per voxel,
# plus seven float32 lerps of values in [-1, 1] (measured max 3e-6).
SAMPLER_TOL = 1e-5
# Reduced vs full mesh, both searched 8 steps on the same field: 95 % of the surface samples of each lie
# within a sixth of the shell Gaussians' σ (0.12) of the other mesh (measured: 0.005–0.010).
MESH_DISTANCE_TOL = 0.02
SURFACE_SAMPLES = 5000
RADIUS, SIGMA_BIG, SIGMA_SMALL = 0.5, 0.12, 0.01


def _unit_quats(n):
    return np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))


def _scene(seed=0):
    """A shell of 80 large opaque Gaussians, 60 tiny opaque ones on it, 80 faint floaters away from it."""
    rng = np.random.default_rng(seed)
    i = np.arange(80) + 0.5
    phi, theta = np.arccos(1 - 2 * i / 80), np.pi * (1 + 5**0.5) * i
    shell = RADIUS * np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
    tiny = rng.normal(size=(60, 3))
    tiny = RADIUS * tiny / np.linalg.norm(tiny, axis=1, keepdims=True)
    faint = rng.normal(size=(80, 3))
    faint *= rng.uniform(1.1, 1.4, size=(80, 1)) / np.linalg.norm(faint, axis=1, keepdims=True)
    means = np.concatenate([shell, tiny, faint])
    sigma = np.concatenate([np.full(80, SIGMA_BIG), np.full(60, SIGMA_SMALL), np.full(80, 0.05)])
    opacity = np.concatenate([np.full(80, 0.9), np.full(60, 0.95), np.full(80, 0.03)])
    return means, np.repeat(sigma[:, None], 3, 1), opacity


def _opacity_field(means, scales, opacity):
    """Brute force ``1 − Π(1 − α_k G_k(x))`` over all (isotropic) Gaussians, float64."""
    def field(x):
        d2 = ((np.asarray(x, np.float64)[:, None, :] - means[None]) ** 2).sum(-1) / scales[None, :, 0] ** 2
        return (1.0 - np.prod(1.0 - opacity[None] * np.exp(-0.5 * d2), axis=1)).astype(np.float32)
    return field


def _mesh(means, scales, opacity, config):
    """Tetra grid (cell filter off: in this toy the filter drops shell–floater tets of the full grid and
    with them surface, which would hide the reductions' own effect) → marching tetrahedra, 8 steps."""
    config = dataclasses.replace(config, filter_cells=False)
    stats = {}
    points, tets, _, _ = tetrahedral_grid(means, _unit_quats(len(means)), scales, opacity, config=config, stats=stats)
    field = _opacity_field(means, scales, opacity)
    (verts, faces), = marching_tetrahedra(points, tets, field(points), field, levels=(0.5,), binary_steps=8,
                                          device="cpu")
    return len(points), verts, faces, stats


@pytest.mark.slow
@pytest.mark.parametrize("config", [TetraConfig(opacity_min=0.1), TetraConfig(corner_min_extent=0.1),
                                    TetraConfig(opacity_min=0.1, corner_min_extent=0.1), TetraConfig.fast()],
                         ids=["opacity_min", "corner_min_extent", "both", "fast"])
def test_point_reduction_keeps_the_mesh(config):
    means, scales, opacity = _scene()
    n_full, v_full, f_full, stats = _mesh(means, scales, opacity, TetraConfig())
    n_red, v_red, f_red, _ = _mesh(means, scales, opacity, config)
    assert set(stats) == {"tetra_points", "delaunay", "filter_cells"}
    assert n_red < 0.8 * n_full  # the reduction did something
    assert len(f_full) > 200 and len(f_red) > 0.3 * len(f_full)
    d_red = point_mesh_distance(sample_surface((v_red, f_red), count=SURFACE_SAMPLES), v_full, f_full)
    d_full = point_mesh_distance(sample_surface((v_full, f_full), count=SURFACE_SAMPLES), v_red, f_red)
    # Both meshes approximate the same level set: each one's surface is close to the other's.
    assert np.percentile(d_red, 95) < MESH_DISTANCE_TOL and np.percentile(d_full, 95) < MESH_DISTANCE_TOL
    assert max(d_red.max(), d_full.max()) < 0.5 * SIGMA_BIG  # no piece of surface appears or vanishes


def test_warp_grid_sampler_matches_numpy_trilinear():
    rng = np.random.default_rng(1)
    grid = rng.uniform(-1, 1, size=(7, 5, 9)).astype(np.float32)
    origin, voxel = np.array([0.3, -0.2, 1.0]), 0.25
    vol = TSDFVolume(grid, np.ones_like(grid), np.zeros(grid.shape + (3,), np.float32), origin, voxel)
    upper = origin + voxel * (np.array(grid.shape) - 1)
    pts = rng.uniform(origin - 0.3, upper + 0.3, size=(4000, 3))  # some outside: clamped onto the grid
    nodes = origin + voxel * np.stack(np.meshgrid(*(np.arange(s) for s in grid.shape), indexing="ij"), -1).reshape(-1, 3)
    pts = np.concatenate([pts, nodes]).astype(np.float32)
    ref = vol.sample(pts.astype(np.float64), grid.astype(np.float64))
    sampler = GridSampler(grid, origin, voxel, "cpu")
    got = sampler(wp.array(pts, dtype=wp.vec3, device="cpu")).numpy()
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, atol=SAMPLER_TOL, rtol=0)
    np.testing.assert_allclose(got[-len(nodes):], grid.reshape(-1), atol=SAMPLER_TOL, rtol=0)


def test_grid_sampler_rejects_a_flat_grid():
    from gof_warp.core.errors import GofError

    with pytest.raises(GofError, match="every side >= 2"):
        GridSampler(np.zeros((4, 1, 4)), np.zeros(3), 1.0, "cpu")
