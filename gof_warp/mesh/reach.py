"""Which grid points the Gaussians reach: inside some Gaussian's oriented box ``|Rᵀ (p − μ)| ≤ σ s`` on every axis.

The octree grid (:mod:`gof_warp.mesh.octree_tets`) fills the cells its Gaussians' boxes overlap, so it has vertices where
no Gaussian is, under a ground and between objects; GOF's Delaunay grid has points only at the boxes' corners and
centres. :func:`points_in_boxes` marks the grid points that lie in some Gaussian's box (the Warp kernels of
:mod:`gof_warp.kernels.reach`: a ``wp.Bvh`` over the boxes' bounds, one thread per point, on the points' device), and
the extraction can keep only the tetrahedra with such a vertex (``OctreeConfig.reach_filter``, off by default). Measured
on a 170k-Gaussian model of the synthetic ``background`` scene: the
ground-and-objects crop's Chamfer +5.5 % of the Delaunay grid's without it, +1.7 % with boxes of the unfiltered
scales, +5.2 % with the 3D-filtered ones used here. What it cuts depends on whether the octree's lattice lies near a
surface of flat Gaussians: on ``background_full`` no vertex fell inside the ground's thin boxes in places and 12 % of
the ground was lost; boxes widened to half a cell to prevent that left the +5.5 % as it was.

Memory: the BVH (~64 B per Gaussian), the float32 centres, quaternions and half extents (40 B per Gaussian), one
byte per point.
"""

from __future__ import annotations

import torch
import warp as wp

from ..core.devices import warp_device
from ..core.errors import GofError
from ..kernels.reach import oriented_box_bounds, points_in_boxes as _points_in_boxes_kernel
from ..core.streams import torch_stream
from ..core.model import quat_to_rotmat

REFERENCE_CHUNK = 1 << 22  # points × Gaussians compared at once by the float64 reference (~0.5 GB)


def _checked(points, means, rotations, half_extents) -> tuple[torch.Tensor, ...]:
    shapes = {"points": (points, 3), "means": (means, 3), "rotations": (rotations, 4), "half_extents": (half_extents, 3)}
    for name, (t, width) in shapes.items():
        if not isinstance(t, torch.Tensor) or t.ndim != 2 or t.shape[1] != width:
            raise GofError(f"points_in_boxes: {name} must be a [*, {width}] tensor, got {getattr(t, 'shape', type(t))}")
        if not bool(torch.isfinite(t).all()):
            raise GofError(f"points_in_boxes: {name} has NaN/inf entries")
    n = means.shape[0]
    if rotations.shape[0] != n or half_extents.shape[0] != n:
        raise GofError(f"points_in_boxes: means {tuple(means.shape)}, rotations {tuple(rotations.shape)} and "
                       f"half_extents {tuple(half_extents.shape)} must have one row per Gaussian")
    if n and not bool((rotations.norm(dim=1) > 0).all()):
        raise GofError("points_in_boxes: rotations has zero quaternions")
    if n and not bool((half_extents >= 0).all()):
        raise GofError("points_in_boxes: half_extents must be >= 0")
    device = points.device
    return (points.detach(), means.detach().to(device), rotations.detach().to(device),
            half_extents.detach().to(device))


@torch.no_grad()
def points_in_boxes(points: torch.Tensor, means: torch.Tensor, rotations: torch.Tensor,
                    half_extents: torch.Tensor) -> torch.Tensor:
    """``[P]`` bool on ``points``' device: whether ``points [P, 3]`` lies in the oriented box of some Gaussian
    ``k``: ``|R_kᵀ (p − means[k])| <= half_extents[k]`` on each axis, ``R_k`` from ``rotations [N, 4]`` (wxyz, any
    non-zero length; normalised here), ``half_extents [N, 3]`` (e.g. ``3 × scales`` for GOF's 3σ boxes).

    Float32 Warp kernels (:mod:`gof_warp.kernels.reach`); a point within float32 rounding of a box face may fall either
    way. :func:`points_in_boxes_reference` is the float64 reference."""
    points, means, rotations, half_extents = _checked(points, means, rotations, half_extents)
    if points.shape[0] == 0 or means.shape[0] == 0:
        return torch.zeros(points.shape[0], dtype=torch.bool, device=points.device)
    wp.init()
    device = warp_device(points.device)
    f32 = lambda t: t.to(torch.float32).contiguous()  # noqa: E731
    mu, q = f32(means), f32(torch.nn.functional.normalize(rotations.to(torch.float64), dim=1))
    e, p = f32(half_extents), f32(points)
    inside = torch.zeros(p.shape[0], dtype=torch.int8, device=points.device)
    with torch_stream(device):
        mu_w, q_w, e_w = (wp.from_torch(mu, dtype=wp.vec3), wp.from_torch(q, dtype=wp.vec4),
                          wp.from_torch(e, dtype=wp.vec3))
        lowers = wp.empty(mu.shape[0], dtype=wp.vec3, device=device)
        uppers = wp.empty(mu.shape[0], dtype=wp.vec3, device=device)
        wp.launch(oriented_box_bounds, dim=mu.shape[0], device=device, inputs=[mu_w, q_w, e_w], outputs=[lowers, uppers])
        bvh = wp.Bvh(lowers, uppers)
        wp.launch(_points_in_boxes_kernel, dim=p.shape[0], device=device,
                  inputs=[bvh.id, wp.from_torch(p, dtype=wp.vec3), mu_w, q_w, e_w], outputs=[wp.from_torch(inside)])
    return inside.bool()


@torch.no_grad()
def points_in_boxes_reference(points: torch.Tensor, means: torch.Tensor, rotations: torch.Tensor,
                              half_extents: torch.Tensor, chunk: int = REFERENCE_CHUNK) -> torch.Tensor:
    """:func:`points_in_boxes` in float64 by brute force (every point against every box, ``chunk`` pairs at a time)."""
    points, means, rotations, half_extents = _checked(points, means, rotations, half_extents)
    p, mu, e = points.to(torch.float64), means.to(torch.float64), half_extents.to(torch.float64)
    R = quat_to_rotmat(rotations.to(torch.float64))  # [N, 3, 3], columns the local axes
    out = torch.zeros(p.shape[0], dtype=torch.bool, device=p.device)
    rows = max(1, chunk // max(1, mu.shape[0]))
    for a in range(0, p.shape[0], rows):
        d = p[a:a + rows, None, :] - mu[None]  # [rows, N, 3]
        local = torch.einsum("nji,pnj->pni", R, d)  # Rᵀ d
        out[a:a + rows] = (local.abs() <= e[None]).all(dim=-1).any(dim=-1)
    return out
