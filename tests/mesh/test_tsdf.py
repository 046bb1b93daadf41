"""TSDF fusion baseline: a sphere of surface-aligned Gaussians fuses into a sphere mesh."""

import numpy as np
import pytest

from gof_warp.core.camera import look_at
from gof_warp.core.model import Gaussians
from gof_warp.core.scene import View
from gof_warp.mesh.tsdf import TSDFConfig, extract_tsdf_mesh, fuse_tsdf

RADIUS = 0.5


def _sphere_of_discs(n=1500, seed=0):
    """Flat Gaussians tangent to a sphere (normal = local z axis), opaque: a clean surface."""
    rng = np.random.default_rng(seed)
    i = np.arange(n) + 0.5
    phi, theta = np.arccos(1 - 2 * i / n), np.pi * (1 + 5**0.5) * i  # Fibonacci sphere
    normals = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], 1)
    # quaternion rotating +z onto the normal
    z = np.array([0, 0, 1.0])
    axis = np.cross(z, normals)
    s = np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.arctan2(s[:, 0], normals @ z)
    axis = np.where(s > 1e-9, axis / np.maximum(s, 1e-12), [1.0, 0, 0])
    quats = np.concatenate([np.cos(angle / 2)[:, None], np.sin(angle / 2)[:, None] * axis], 1)
    spacing = np.sqrt(4 * np.pi * RADIUS**2 / n)
    scales = np.tile([spacing * 0.8, spacing * 0.8, spacing * 0.02], (n, 1))
    colors = rng.random((n, 3))
    return Gaussians.from_activated(RADIUS * normals, quats, scales, np.full(n, 0.99), colors, device="cpu")


def _views(k=12):
    views = []
    for a in range(k):
        ang = 2 * np.pi * a / k
        eye = [2.0 * np.cos(ang), 2.0 * np.sin(ang), 0.8 * (-1) ** a]
        cam = look_at(eye, [0, 0, 0], fx=60, width=48, height=48, name=f"v{a}")
        views.append(View(camera=cam, image=np.zeros((48, 48, 3), np.uint8), name=cam.name))
    return views


@pytest.mark.parametrize("binary_steps", [0, 4])
def test_tsdf_of_a_sphere_is_a_sphere(binary_steps):
    g = _sphere_of_discs()
    cfg = TSDFConfig(resolution=48, trunc_voxels=4.0, bounds=(-0.75, -0.75, -0.75, 0.75, 0.75, 0.75))
    vol = fuse_tsdf(g, _views(), cfg, device="cpu")
    assert (vol.weight > 0).mean() > 0.3
    verts, faces, colours = extract_tsdf_mesh(vol, binary_steps=binary_steps, device="cpu")
    assert len(faces) > 500 and colours.shape == verts.shape
    r = np.linalg.norm(verts, axis=1)
    voxel = vol.voxel_size
    # The fused surface is the rendered median depth: within ~1.5 voxels of the true sphere.
    assert np.abs(np.median(r) - RADIUS) < 0.75 * voxel, (np.median(r), voxel)
    assert np.percentile(np.abs(r - RADIUS), 95) < 2.0 * voxel
    # No second surface behind the truncation band (an interior shell would put vertices near r - trunc).
    assert (r < RADIUS - 3 * voxel).mean() < 0.01
