"""The 3D smoothing filter of Mip-Splatting (Yu et al., CVPR 2024) as GOF computes it.

Each Gaussian gets a variance floor ``φ`` from the highest sampling rate any training camera has at
its centre: ``φ = d / f_max · sqrt(0.2)``, where ``d`` is the smallest camera-space depth ``z`` over
the training cameras that see the centre and ``f_max`` the largest ``fx`` over those cameras
(GOF ``scene/gaussian_model.py::compute_3D_filter``; GOF_REFERENCE §1). A camera "sees" a centre when
``z > near`` (0.2) and its projection ``(u, v) = (fx x/z + cx, fy y/z + cy)`` lies in
``[−0.15 W, 1.15 W] × [−0.15 H, 1.15 H]`` (a 15 % guard band). Centres no camera sees get the largest
``d`` of the seen ones. The renderer then uses ``s_f = sqrt(s² + φ²)`` and the energy-preserving
opacity (see :class:`gof_warp.core.model.Gaussians`).

GOF projects with the principal point at the image centre; we use each camera's own ``(cx, cy)``,
which is identical for GOF's cameras. GOF recomputes the filter at the start, after every
densification, and every 100 iterations for 15 000 < it < 29 900 (see
:attr:`gof_warp.training.densify.DensifyReport.filter_3d_due`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import warp as wp

from ..core.camera import Camera, camera_arrays
from ..core.devices import warp_device
from ..core.errors import GofError
from ..kernels.filter3d import nearest_seen_depth
from ..core.streams import torch_stream
from ..core.model import Gaussians

FILTER_VARIANCE = 0.2  # Mip-Splatting's 3D filter variance in pixels² (GOF: sqrt(0.2))
SCREEN_GUARD = 0.15  # fraction of W/H by which the visibility test extends past the image (GOF)
DEFAULT_CHUNK_ELEMENTS = 1 << 22  # cameras × Gaussians evaluated at once (≈ 16 floats each → ~270 MB fp32 peak)


def _camera_tensors(cameras: Sequence[Camera], dtype, device) -> dict[str, torch.Tensor]:
    return {k: torch.as_tensor(v, dtype=dtype, device=device) for k, v in camera_arrays(cameras).items()}


@torch.no_grad()
def compute_filter_3d(means: torch.Tensor, cameras: Sequence[Camera], *, near: float = 0.2,
                      chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> torch.Tensor:
    """Per-Gaussian 3D filter standard deviation ``φ`` (GOF's ``filter_3D``).

    float32 centres (what training holds) go through the Warp kernel
    :func:`gof_warp.kernels.filter3d.nearest_seen_depth` (one thread per centre, on the centres' device and
    torch's stream; ~50 ms of chunked torch work per update on an H200 at 800k Gaussians became one launch);
    other dtypes (float64: the reference the tests hold the kernel to) through chunked torch operations.

    Args:
        means: ``[N, 3]`` Gaussian centres, world space (any float dtype/device; no gradient).
        cameras: the training cameras (world-to-camera ``R, t``, OpenCV axes, any principal point).
        near: depth below which a camera does not count (GOF: 0.2).
        chunk_elements: bound on cameras × Gaussians processed at once by the torch path; memory is
            ``O(chunk_elements)`` plus ``O(N)`` for the result, whatever the number of cameras.

    Returns:
        ``[N]`` tensor ``φ = d / max_c fx_c · sqrt(0.2)`` on ``means``' device and dtype.

    Raises:
        GofError: bad shapes, no cameras, or no Gaussian seen by any camera (φ undefined).
    """
    if not isinstance(means, torch.Tensor) or means.ndim != 2 or means.shape[1] != 3:
        raise GofError(f"compute_filter_3d: means must be a [N, 3] tensor, got {getattr(means, 'shape', type(means))}")
    cameras = list(cameras)
    if not cameras:
        raise GofError("compute_filter_3d: needs at least one training camera")
    if not means.is_floating_point():
        raise GofError(f"compute_filter_3d: means must be floating point, got {means.dtype}")
    n = means.shape[0]
    if n == 0:
        return means.new_zeros(0)
    if means.dtype == torch.float32:
        d = _nearest_seen_depth_warp(means, cameras, near)
    else:
        d = nearest_seen_depth_torch(means, cameras, near, chunk_elements)
    seen_any = torch.isfinite(d)
    if not seen_any.any():
        if not bool(torch.isfinite(means).all()):  # a NaN step: the trainer's loss check names where it began
            return torch.full_like(d, math.nan)
        raise GofError(f"compute_filter_3d: none of the {n} Gaussians is seen by any of the {len(cameras)} cameras "
                       f"(depth > {near} and inside the image); check the poses and the scene scale")
    d = torch.where(seen_any, d, d.masked_fill(~seen_any, -math.inf).amax())
    f_max = max(c.fx for c in cameras)
    return d / f_max * math.sqrt(FILTER_VARIANCE)


def _nearest_seen_depth_warp(means: torch.Tensor, cameras: Sequence[Camera], near: float) -> torch.Tensor:
    """``[N]`` nearest seeing depth (``+inf`` if unseen) of float32 ``means`` by the Warp kernel."""
    wp.init()
    device = warp_device(means.device)
    depth = torch.empty(means.shape[0], dtype=torch.float32, device=means.device)
    cam = _camera_tensors(cameras, torch.float32, means.device)
    types = {"R": wp.mat33, "t": wp.vec3, "f": wp.vec2, "c": wp.vec2, "wh": wp.vec2}
    with torch_stream(device):
        arrays = [wp.from_torch(means.detach().contiguous(), dtype=wp.vec3)] + [wp.from_torch(cam[k], dtype=v) for k, v in types.items()]
        wp.launch(nearest_seen_depth, dim=means.shape[0], device=device, inputs=[*arrays, float(near), float(SCREEN_GUARD)],
                  outputs=[wp.from_torch(depth)])
    return depth


def nearest_seen_depth_torch(means: torch.Tensor, cameras: Sequence[Camera], near: float = 0.2,
                             chunk_elements: int = DEFAULT_CHUNK_ELEMENTS) -> torch.Tensor:
    """``[N]`` nearest seeing depth (``+inf`` if unseen) in ``means``' dtype, by chunked torch operations (the
    kernel's reference in float64)."""
    n = means.shape[0]
    cam = _camera_tensors(cameras, means.dtype, means.device)
    d = torch.full((n,), math.inf, dtype=means.dtype, device=means.device)
    chunk = max(1, chunk_elements // n)
    for c0 in range(0, len(cameras), chunk):
        sl = slice(c0, c0 + chunk)
        x_cam = torch.einsum("cij,nj->cni", cam["R"][sl], means) + cam["t"][sl, None, :]  # [c, N, 3]
        z = x_cam[..., 2]
        uv = x_cam[..., :2] / z.clamp_min(1e-3)[..., None] * cam["f"][sl, None, :] + cam["c"][sl, None, :]
        wh = cam["wh"][sl, None, :]
        in_screen = ((uv >= -SCREEN_GUARD * wh) & (uv <= (1.0 + SCREEN_GUARD) * wh)).all(dim=-1)
        seen = (z > near) & in_screen
        d = torch.minimum(d, torch.where(seen, z, torch.full_like(z, math.inf)).amin(dim=0))
    return d


def update_filter_3d(gaussians: Gaussians, cameras: Sequence[Camera], *, near: float = 0.2) -> torch.Tensor:
    """Recompute ``gaussians.filter_3d`` from the current centres (in place); returns it."""
    gaussians.filter_3d = compute_filter_3d(gaussians.means.detach(), cameras, near=near)
    return gaussians.filter_3d
