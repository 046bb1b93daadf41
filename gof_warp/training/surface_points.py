"""Points on the surfaces the training views agree on, from the model's rendered depths: what stands in for SfM
points in a run that starts without any (``model.init=random``).

A run from SfM points bounds each camera by its nearest point (``render.near_from_points``: a per-camera near plane;
``densify.near_camera_fraction``: pruning what a camera's rays meet nearer than a fraction of it), so Gaussians
cannot settle right in front of a camera and cover its view. Without points both are off, and such floaters cover
test views. Once the model has surfaces, :func:`surface_points` gives points to bound the cameras by:

1. every training view is rendered (no gradients); the pixels of a ``stride``-spaced grid whose ``alpha`` is at
   least ``min_alpha`` are lifted to world points at their median depth;
2. a point lifted from view ``i`` is kept when at least ``min_views - 1`` *other* views see the same surface there:
   it projects inside view ``j`` at camera depth ``z_j``, view ``j``'s own median depth at that pixel (nearest grid
   sample) ``d_j`` is opaque, and ``|z_j − d_j| ≤ rel_tol · z_j``.

A floater right in front of one camera is in that camera's depth map only: the other views see the surface behind it
there, so its points are dropped, and the camera is bounded by the surface the views agree on. Memory: one view's
render at a time, then ``C`` depth grids of ``(H / stride) (W / stride)`` floats and the lifted points.
"""

from __future__ import annotations

import numpy as np
import torch

from ..core.camera import Camera
from ..rendering.render import RenderConfig, render


def _grid(camera: Camera, stride: int, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel centres ``u [h, w]``, ``v [h, w]`` (float64) of the ``stride``-spaced grid, first at ``stride / 2``."""
    u = torch.arange(stride // 2, camera.width, stride, device=device, dtype=torch.float64) + 0.5
    v = torch.arange(stride // 2, camera.height, stride, device=device, dtype=torch.float64) + 0.5
    return torch.meshgrid(u, v, indexing="xy")


def lift(camera: Camera, u: torch.Tensor, v: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """World points ``[..., 3]`` of pixels ``(u, v)`` at camera depth ``depth`` (z): ``R^T (z K^-1 [u v 1] − t)``."""
    x = (u - camera.cx) / camera.fx * depth
    y = (v - camera.cy) / camera.fy * depth
    pc = torch.stack([x, y, depth], dim=-1)
    R = torch.as_tensor(camera.R, dtype=pc.dtype, device=pc.device)
    t = torch.as_tensor(camera.t, dtype=pc.dtype, device=pc.device)
    return (pc - t) @ R


def surface_points(gaussians, cameras: list[Camera], config: RenderConfig | None = None, *, stride: int = 4,
                   min_alpha: float = 0.9, min_views: int = 2, rel_tol: float = 0.02) -> np.ndarray:
    """``[P, 3]`` float64 world points on the rendered surfaces that at least ``min_views`` of ``cameras`` agree on
    (see the module docstring). ``gaussians``: a model :func:`~gof_warp.rendering.render.render` takes."""
    if min_views < 1 or stride < 1 or not 0 < min_alpha <= 1 or rel_tol <= 0:
        raise ValueError(f"surface_points: need min_views >= 1, stride >= 1, 0 < min_alpha <= 1, rel_tol > 0; got "
                         f"{min_views}, {stride}, {min_alpha}, {rel_tol}")
    grids = []
    with torch.no_grad():
        for cam in cameras:
            out = render(gaussians, cam, config=config)
            depth, alpha = out["median_depth"].squeeze(-1), out["alpha"].squeeze(-1)
            s = slice(stride // 2, None, stride)
            d = depth[s, s].to(torch.float64)
            grids.append(torch.where((alpha[s, s] >= min_alpha) & (d > 0), d, torch.zeros_like(d)))
        kept = []
        for i, cam in enumerate(cameras):
            u, v = _grid(cam, stride, grids[i].device)
            ok = grids[i] > 0
            if not bool(ok.any()):
                continue
            pts = lift(cam, u[ok], v[ok], grids[i][ok])
            agree = torch.ones(len(pts), dtype=torch.int64, device=pts.device)  # view i itself
            for j, other in enumerate(cameras):
                if j == i:
                    continue
                agree += _agrees(pts, other, grids[j], stride, rel_tol)
            kept.append(pts[agree >= min_views])
    if not kept:
        return np.zeros((0, 3))
    return torch.cat(kept).cpu().numpy()


def _agrees(points: torch.Tensor, camera: Camera, grid: torch.Tensor, stride: int, rel_tol: float) -> torch.Tensor:
    """``[P]`` int64: 1 where ``camera``'s depth grid (0: no opaque surface) holds ``points``' depth at their pixel."""
    px, py, z, inside = camera.in_image_tensor(points)
    h, w = grid.shape
    # the nearest grid sample: sample k sits at pixel centre stride // 2 + k · stride + 0.5
    gx = torch.round((px - 0.5 - stride // 2) / stride).long()
    gy = torch.round((py - 0.5 - stride // 2) / stride).long()
    inside &= (gx >= 0) & (gx < w) & (gy >= 0) & (gy < h)
    d = torch.zeros_like(z)
    d[inside] = grid[gy[inside], gx[inside]]
    return (inside & (d > 0) & ((z - d).abs() <= rel_tol * z)).long()
