"""TSDF fusion of rendered depth maps: the mesh baseline 2DGS and 3DGS use (and GOF's DTU numbers).

Each training view is rendered; its median depth is kept where the rendered alpha is ≥ ``alpha_min``
(and inside the view's mask, when ``use_masks``), as GOF's ``extract_mesh_tsdf.py`` does; the depth maps
are fused into a dense TSDF grid (:mod:`gof_warp.kernels.tsdf`), and the zero level set is extracted by
marching cubes (optionally refined by binary search on the trilinear TSDF). Cubes with an unobserved
corner produce no faces, as in Open3D.

Memory: the grid holds 20 bytes per voxel (tsdf, weight, RGB): 2.7 GB at 512³. Resolution is a config
value; the grid's extent is the bounding box of the Gaussians' centres (robust percentiles) unless given.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import torch
import warp as wp

from ..core.devices import resolve_device, warp_device
from ..core.errors import GofError
from ..kernels.render_types import camera_params_from
from ..kernels.tsdf import integrate_tsdf, sample_grid_trilinear
from .marching import compact_mesh, marching_cubes
from ..rendering.render import RenderConfig, render

log = logging.getLogger(__name__)


@dataclass
class TSDFConfig:
    """TSDF fusion settings (defaults: GOF ``extract_mesh_tsdf.py`` where scale-free)."""

    resolution: int = 256  # voxels along the longest side of the box (when voxel_size is None)
    voxel_size: float | None = None  # world units; overrides resolution
    trunc_voxels: float = 8.0  # truncation distance in voxels
    depth_max: float | None = None  # ignore depths beyond this (GOF: 6.0 on DTU's unit-sphere frame)
    alpha_min: float = 0.5  # use the median depth only where alpha >= this (GOF: 0.5)
    use_masks: bool = True  # zero depth outside the view's mask (GOF: mask < 0.5)
    bounds: tuple[float, ...] | None = None  # (xmin, ymin, zmin, xmax, ymax, zmax); None = from the Gaussians
    bounds_percentile: float = 0.5  # robust box from the [p, 100 − p] percentiles of the centres …
    bounds_padding: float = 0.05  # … padded by this fraction of its size


@dataclass
class TSDFVolume:
    """``tsdf``, ``weight`` ``[X, Y, Z]`` and ``rgb`` ``[X, Y, Z, 3]`` numpy arrays on a grid at ``origin``."""

    tsdf: np.ndarray
    weight: np.ndarray
    rgb: np.ndarray
    origin: np.ndarray
    voxel_size: float

    def sample(self, points: np.ndarray, grid: np.ndarray) -> np.ndarray:
        """Trilinear interpolation of ``grid`` (``[X, Y, Z, ...]``) at world ``points`` ``[M, 3]``."""
        res = np.array(self.tsdf.shape)
        x = np.clip((points - self.origin) / self.voxel_size, 0, res - 1 - 1e-6)
        i0 = np.floor(x).astype(np.int64)
        f = x - i0
        out = 0.0
        for corner in range(8):
            o = np.array([(corner >> a) & 1 for a in range(3)])
            idx = np.minimum(i0 + o, res - 1)
            wgt = np.prod(np.where(o, f, 1 - f), axis=1)
            val = grid[idx[:, 0], idx[:, 1], idx[:, 2]]
            out = out + (wgt[:, None] * val if val.ndim == 2 else wgt * val)
        return out


def gaussian_bounds(means: np.ndarray, percentile: float, padding: float, extent: np.ndarray | None = None) -> np.ndarray:
    """Robust axis-aligned box ``(min xyz, max xyz)`` of the Gaussians, padded.

    ``extent`` ``[N]`` (e.g. 3 × the largest scale) widens each centre into a cube before the percentiles.
    """
    if len(means) == 0:
        raise GofError("cannot bound an empty set of Gaussians")
    e = np.zeros((len(means), 1)) if extent is None else np.asarray(extent, float).reshape(-1, 1)
    lo = np.percentile(means - e, percentile, axis=0)
    hi = np.percentile(means + e, 100 - percentile, axis=0)
    pad = padding * (hi - lo).max()
    return np.concatenate([lo - pad, hi + pad])


def scene_bounds(gaussians, cameras, *, percentile: float = 0.5, padding: float = 0.05, near: float = 0.2,
                 max_widening: float = 10.0) -> np.ndarray:
    """The box a dense grid (TSDF, marching cubes) should cover: the Gaussians some camera sees (frustum
    test on the centres), each widened by its 3σ extent, capped at ``max_widening`` × the median 3σ extent
    and at a tenth of the diagonal of the centres' box (itself widened by the median extent), robust
    percentiles, padded. A few huge or unseen Gaussians cannot swamp it: a grid larger than the scene also
    reaches space that every view sees only through the scene, which GOF's field calls "inside"."""
    from .tetra import frustum_mask

    means = gaussians.means.detach()
    extent = 3.0 * gaussians.scales.detach().max(dim=1).values
    finite = torch.isfinite(extent)  # an overflowed scale (see extract.meshable) cannot bound anything
    if not bool(finite.any()):
        raise GofError(f"cannot bound the grid: all {len(extent)} Gaussians have non-finite scales")
    means, extent = means[finite], extent[finite]
    if cameras:
        seen = frustum_mask(means.double(), cameras, near, 1e6)
        if bool(seen.any()):
            means, extent = means[seen], extent[seen]
    e = extent.cpu().numpy().astype(np.float64)
    m = means.cpu().numpy().astype(np.float64)
    median = float(np.median(e)) if len(e) else 0.0
    core = gaussian_bounds(m, percentile, 0.0, np.full(len(m), median))
    cap = min(max_widening * median, 0.1 * float(np.linalg.norm(core[3:] - core[:3])))
    return gaussian_bounds(m, percentile, padding, np.minimum(e, cap))


@torch.no_grad()
def fuse_tsdf(gaussians, views, config: TSDFConfig | None = None, render_config: RenderConfig | None = None,
              device=None) -> TSDFVolume:
    """Render every view's median depth and fuse them into a TSDF volume.

    Args:
        gaussians: a :class:`~gof_warp.core.model.Gaussians`.
        views: sequence of :class:`~gof_warp.core.scene.View` (camera + optional mask); usually the train views.
    """
    config = config or TSDFConfig()
    render_config = render_config or RenderConfig()
    if not views:
        raise GofError("TSDF fusion needs at least one view")
    box = np.asarray(config.bounds, float) if config.bounds is not None else scene_bounds(
        gaussians, [v.camera for v in views], percentile=config.bounds_percentile, padding=config.bounds_padding,
        near=render_config.near)
    if box.shape != (6,) or not np.all(np.isfinite(box)) or np.any(box[3:] <= box[:3]):
        raise GofError(f"TSDF bounds must be (xmin, ymin, zmin, xmax, ymax, zmax) with max > min, got {box.tolist()}")
    size = box[3:] - box[:3]
    voxel = float(config.voxel_size or size.max() / config.resolution)
    res = np.maximum(2, np.ceil(size / voxel).astype(int) + 1)
    wp.init()
    wdev = warp_device(resolve_device(None if device is None else str(device), like=gaussians.means))
    log.info("TSDF grid %s voxels of %.4g (%.1f MB)", res.tolist(), voxel, res.prod() * 20 / 2**20)
    shape = tuple(int(r) for r in res)
    tsdf = wp.ones(shape, dtype=float, device=wdev)
    weight = wp.zeros(shape, dtype=float, device=wdev)
    rgb = wp.zeros(shape, dtype=wp.vec3, device=wdev)
    depth_max = float(config.depth_max) if config.depth_max is not None else math.inf
    for v in views:
        out = render(gaussians, v.camera, config=render_config)
        depth = torch.where(out["alpha"] >= config.alpha_min, out["median_depth"], torch.zeros_like(out["alpha"]))
        if config.use_masks and v.mask is not None:
            depth = torch.where(torch.from_numpy(v.mask).to(depth.device) >= 128, depth, torch.zeros_like(depth))
        wp.launch(integrate_tsdf, dim=shape, device=wdev, inputs=[
            wp.from_torch(depth.float().contiguous()), wp.from_torch(out["rgb"].clamp(0, 1).contiguous(), dtype=wp.vec3),
            camera_params_from(v.camera), wp.vec3(*box[:3].astype(np.float32)), voxel, config.trunc_voxels * voxel,
            depth_max], outputs=[tsdf, weight, rgb])
    return TSDFVolume(tsdf.numpy(), weight.numpy(), rgb.numpy(), box[:3].copy(), voxel)


class GridSampler:
    """Trilinear samples of a scalar grid ``[X, Y, Z]`` (node ``(i, j, k)`` at ``origin + voxel_size ·
    (i, j, k)``) on a Warp device, with :meth:`TSDFVolume.sample`'s semantics (points clamped onto the
    grid). Calling it with ``points`` (``wp.array`` of ``vec3`` ``[M]``) returns ``wp.array(float32)`` ``[M]``
    on ``device``: the field of :func:`~gof_warp.mesh.marching.marching_cubes` with ``field_input="warp"``.
    Memory: the grid on the device (4 B/voxel) plus 4 B per sampled point."""

    def __init__(self, grid: np.ndarray, origin, voxel_size: float, device):
        grid = np.asarray(grid, np.float32)
        if grid.ndim != 3 or min(grid.shape) < 2:
            raise GofError(f"grid must be [X, Y, Z] with every side >= 2, got shape {grid.shape}")
        wp.init()
        self.device = str(device)
        self.grid = wp.array(grid, dtype=wp.float32, device=self.device)
        self.origin = wp.vec3(*np.asarray(origin, np.float32))
        self.voxel_size = float(voxel_size)

    def __call__(self, points: wp.array) -> wp.array:
        values = wp.empty(points.shape[0], dtype=wp.float32, device=self.device)
        wp.launch(sample_grid_trilinear, dim=points.shape[0], device=self.device,
                  inputs=[self.grid, self.origin, self.voxel_size, points.to(self.device)], outputs=[values])
        return values


def extract_tsdf_mesh(volume: TSDFVolume, *, binary_steps: int = 0, device=None):
    """Zero level set of the TSDF: ``(vertices [V, 3], faces [F, 3], colours [V, 3] in [0, 1])``.

    Faces touching a cube with an unobserved corner (weight 0) are dropped (Open3D's rule). The grid and
    the binary search's trilinear samples live on the Warp ``device`` (default CUDA when available).
    """
    res = np.array(volume.tsdf.shape)
    observed = volume.weight > 0
    field_grid = np.where(observed, -volume.tsdf, -1.0).astype(np.float32)  # inside = value >= 0
    wp.init()
    device = warp_device(None if device is None else str(device))
    field = GridSampler(field_grid, volume.origin, volume.voxel_size, device)
    del field_grid

    lower = volume.origin
    upper = volume.origin + volume.voxel_size * (res - 1)
    verts, faces = marching_cubes(field, np.stack([lower, upper]), tuple(int(r) for r in res), level=0.0,
                                  binary_steps=binary_steps, field_input="warp", device=device)
    if len(faces) == 0:
        return verts, faces, np.zeros((0, 3), np.float32)
    cell = np.clip(np.floor((verts - lower) / volume.voxel_size).astype(np.int64), 0, res - 2)
    ok = np.ones(len(verts), bool)
    for corner in range(8):
        o = np.array([(corner >> a) & 1 for a in range(3)])
        c = cell + o
        ok &= observed[c[:, 0], c[:, 1], c[:, 2]]
    keep = ok[faces].all(axis=1)
    faces = faces[keep]
    verts, faces, _ = compact_mesh(verts, faces)
    colours = volume.sample(verts.astype(np.float64), volume.rgb).astype(np.float32)
    return verts, faces, colours
