"""``opacity_field(gaussians, cameras, points)``: GOF's Gaussian opacity field at 3D points.

The opacity of a point is the minimum, over the training views in whose image it projects (in front of
the near plane), of the opacity composited along that view's ray up to the point's depth (GOF Sec. 3.2;
math in :mod:`gof_warp.kernels.opacity_field`). Points no view sees (or fewer than ``min_views``) get
``unseen_value`` (GOF keeps 1, i.e. "inside": such points produce no surface against other unseen points but can
against seen ones).

Evaluation is tile-binned (paper Algorithm 2): per view the Gaussians are preprocessed and binned once
(the renderer's own kernels) and each point walks only its tile's depth-sorted list.

Memory bound: points are processed in chunks of ``chunk_size`` (20 bytes each on the device: position,
running minimum, seen count); per view the renderer's state is ``104 B × N + 24 B × (Gaussian, tile)
entries``. Nothing else grows with the scene.
"""

from __future__ import annotations

import dataclasses

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
import warp as wp

from ..core.camera import Camera
from ..core.errors import GofError
from ..kernels.opacity_field import opacity_min_over_view
from ..kernels.render_types import camera_params_from
from ..kernels.renderer import prepare_view
from .render import RenderConfig, raster_settings_for

log = logging.getLogger(__name__)

#: Rays through points leave from anywhere inside a pixel, not its centre: bin with half a pixel margin.
POINT_PIXEL_PAD = 0.5


@dataclass
class OpacityFieldConfig:
    """Settings of the opacity-field evaluation."""

    unseen_value: float = 1.0  # field of points no view sees (GOF: 1)
    # Points inside fewer than this many training views' frusta count as unseen (GOF: 1). A surface one photo alone
    # sees has no parallax to place it (COLMAP's fusion likewise asks for several views: min_num_pixels); with 2 the
    # tetra path leaves such space out of the grid (gof_warp.mesh.extraction) instead of meshing whatever depth the
    # Gaussians took there.
    min_views: int = 1
    chunk_size: int = 1 << 22  # points per device chunk
    # Screen tile (pixels) of the per-view Gaussian lists the points are evaluated against; None: CPU_TILE_SIZE on
    # the CPU, the renderer's tile on a GPU. The value is the same for any tile (the lists are conservative and
    # each point tests its own ray: bit-identical, tests/rendering/test_opacity_field.py); smaller tiles mean shorter
    # lists per point and more list entries. Measured on the 2-core CPU (default scene, 9k Gaussians, 40 views 128²,
    # 20k points): 16 px 4.5-5.0 s, 8 px 2.9 s, 4 px 2.1-2.4 s, 2 px 1.9 s. Not measured on a GPU yet: unchanged there.
    tile_size: int | None = None
    # On the CPU, where Warp runs a kernel on one core: points shared out to this many forked processes (0: one
    # per core; 1: none), from cpu_split_min_points points on (fewer: the fork costs more than it saves).
    cpu_processes: int = 0
    cpu_split_min_points: int = 20_000

    def validate(self):
        if isinstance(self.min_views, bool) or not isinstance(self.min_views, int) or self.min_views < 1:
            raise GofError(f"opacity field min_views must be an integer >= 1, got {self.min_views!r}")


CPU_TILE_SIZE = 4


def _wp_device(t: torch.Tensor) -> str:
    from ..core.devices import warp_device

    return warp_device(t.device)


@torch.no_grad()
def opacity_field(gaussians, cameras: Sequence[Camera], points, *, config: OpacityFieldConfig | None = None,
                  render_config: RenderConfig | None = None, return_seen: bool = False, ranks=None):
    """Evaluate the opacity field at ``points``.

    Args:
        gaussians: :class:`~gof_warp.core.model.Gaussians` (activated values are used; the 3D filter applies).
        cameras: the views (normally the training cameras), at the resolution the model was trained at.
        points: ``[M, 3]`` world positions (numpy or torch).
        config, render_config: see :class:`OpacityFieldConfig` and :class:`~gof_warp.rendering.render.RenderConfig`
            (near plane, alpha thresholds, k_max — the same rules as rendering).
        return_seen: also return ``[M]`` int32, how many views see each point.
        ranks: a :class:`~gof_warp.training.distributed.Ranks` of several processes (``torchrun``): each evaluates
            every ``world``-th camera from its ``rank`` and the ranks reduce the minimum and the view counts
            (:meth:`~gof_warp.training.distributed.Ranks.reduce_field`) before the unseen points get ``unseen_value``.
            Every rank must call with the same points and cameras; each returns the one-process result.

    Returns:
        ``[M]`` float32 torch tensor on the Gaussians' device (and the seen counts when asked).
    """
    config = config or OpacityFieldConfig()
    render_config = render_config or RenderConfig()
    render_config.validate()
    device = gaussians.device
    pts = torch.as_tensor(points, dtype=torch.float32).to(device)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise GofError(f"points must be [M, 3], got {list(pts.shape)}")
    if not torch.isfinite(pts).all():
        raise GofError("points contain NaN/inf")
    if not cameras:
        raise GofError("the opacity field needs at least one camera")
    config.validate()
    if ranks is not None and ranks.active:
        cameras = list(cameras)[ranks.rank :: ranks.world]  # this rank's views (none: it still takes part below)
    m = pts.shape[0]
    field = torch.ones(m, dtype=torch.float32, device=device)  # running minimum (O <= 1); unseen set at the end
    seen = torch.zeros(m, dtype=torch.int32, device=device)
    if m == 0:
        return (field, seen) if return_seen else field
    if len(gaussians) == 0:  # nothing anywhere: empty space wherever a view looks
        for cam in cameras:
            z = pts @ torch.as_tensor(cam.R[2], dtype=pts.dtype, device=device) + float(cam.t[2])
            uv, _ = cam.project(pts.cpu().double().numpy())
            uv = torch.as_tensor(uv, device=device)
            inside = (z > render_config.near) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] < cam.height)
            seen += inside.int()
        if ranks is not None:
            ranks.reduce_field(field, seen)
        field = torch.where(seen >= config.min_views, torch.zeros_like(field),
                            torch.full_like(field, config.unseen_value))
        return (field, seen) if return_seen else field
    wp.init()
    wdev = _wp_device(pts)
    tile = config.tile_size if config.tile_size is not None else (
        CPU_TILE_SIZE if wdev == "cpu" else render_config.tile_size)
    if isinstance(tile, bool) or not isinstance(tile, int) or tile < 1:
        raise GofError(f"opacity field tile_size must be a positive integer (pixels), got {config.tile_size!r}")
    arrays, views = _view_inputs(gaussians, cameras, dataclasses.replace(render_config, tile_size=tile))
    workers = _cpu_workers(config, m) if wdev == "cpu" else 1
    if workers > 1:  # Warp runs a CPU kernel on one core: share the points out to forked processes
        f_np, s_np = _in_forked_processes(arrays, views, pts.numpy(), workers, config.chunk_size)
        field, seen = torch.from_numpy(f_np), torch.from_numpy(s_np)
    else:
        for start in range(0, m, config.chunk_size):
            stop = min(m, start + config.chunk_size)
            _min_over_views(arrays, views, wp.from_torch(pts[start:stop].contiguous(), dtype=wp.vec3),
                            wp.from_torch(field[start:stop]), wp.from_torch(seen[start:stop]))
    if ranks is not None:
        ranks.reduce_field(field, seen)
    field = torch.where(seen >= config.min_views, field, torch.full_like(field, config.unseen_value))
    return (field, seen) if return_seen else field


def _view_inputs(gaussians, cameras: Sequence[Camera], render_config: RenderConfig):
    """``(arrays, views)`` for :func:`_min_over_views`: the Gaussians as Warp arrays (no colours: the field does not
    need them) and each camera's parameters and raster settings (rays through points: half a pixel of padding)."""
    params = [gaussians.means, gaussians.rotations, gaussians.scales, gaussians.opacities]
    arrays = [wp.from_torch(p.detach().contiguous().float(), dtype=d)
              for p, d in zip(params, (wp.vec3, wp.vec4, wp.vec3, wp.float32))]
    arrays.append(wp.zeros((len(gaussians), 1), dtype=wp.vec3, device=arrays[0].device))
    views = [(camera_params_from(cam), raster_settings_for(cam, render_config, pixel_pad=POINT_PIXEL_PAD))
             for cam in cameras]
    return tuple(arrays), views


def _min_over_views(arrays, views, points: wp.array, field: wp.array, seen: wp.array,
                    kernel=opacity_min_over_view) -> None:
    """Lower ``field`` to each view's opacity at ``points`` and count the views that see them (Warp only;
    ``kernel``: the bounded walk, or its whole-walk reference for tests and benchmarks)."""
    for cp, settings in views:
        splats, lists, _ = prepare_view(*arrays, 0, cp, settings)
        wp.launch(kernel, dim=points.shape[0], device=points.device,
                  inputs=[points, lists, splats, cp, settings], outputs=[field, seen])


def _cpu_workers(config: OpacityFieldConfig, m: int) -> int:
    """Processes for ``m`` points on the CPU: ``config.cpu_processes`` (0: one per core) when there are at least
    ``config.cpu_split_min_points`` of them; forking is Linux-only (elsewhere: 1)."""
    import os

    from ..core.forked import can_fork

    if m < config.cpu_split_min_points or not can_fork():
        return 1
    return max(1, min(config.cpu_processes or os.cpu_count() or 1, m))


def _part(arrays, views, pts, bounds, chunk_size, part: int):
    """``(field, seen)`` numpy arrays of points ``bounds[part]:bounds[part + 1]`` (Warp and numpy only: it runs in
    a forked child)."""
    lo, hi = bounds[part], bounds[part + 1]
    field, seen = np.ones(hi - lo, np.float32), np.zeros(hi - lo, np.int32)
    for start in range(lo, hi, chunk_size):
        stop = min(hi, start + chunk_size)
        f = wp.array(field[start - lo:stop - lo], dtype=wp.float32, device="cpu")
        c = wp.array(seen[start - lo:stop - lo], dtype=wp.int32, device="cpu")
        _min_over_views(arrays, views, wp.array(pts[start:stop], dtype=wp.vec3, device="cpu"), f, c)
        field[start - lo:stop - lo], seen[start - lo:stop - lo] = f.numpy(), c.numpy()
    return field, seen


def _in_forked_processes(arrays, views, pts: np.ndarray, workers: int, chunk_size: int):
    """``(field [M] float32, seen [M] int32)`` of ``pts`` computed by ``workers`` forked processes, each on a
    contiguous part of the points (each point's result is the one-process result, bit for bit)."""
    from ..core.forked import map_forked

    bounds = np.linspace(0, pts.shape[0], workers + 1).round().astype(np.int64)
    inputs = (arrays, views, np.ascontiguousarray(pts, np.float32), bounds, chunk_size)
    parts = map_forked(_part, inputs, workers, workers)
    return np.concatenate([f for f, _ in parts]), np.concatenate([c for _, c in parts])


# ----------------------------------------------------------------------------------------- cameras inside surfaces
@dataclass
class CameraInside:
    """A camera whose own free space the other views see as solid (:func:`cameras_inside_surfaces`)."""

    index: int  # into the cameras given
    name: str
    solid_fraction: float  # of the tested points in front of it (its free space) that the other views see as solid
    tested: int  # points tested (seen by at least one other view)


def _owned_slices(views, pts: torch.Tensor, bounds, field: torch.Tensor, seen: torch.Tensor, arrays, own: bool):
    """Lower ``field`` / count ``seen`` at ``pts``: view ``j`` evaluated on its own block ``bounds[j]:bounds[j+1]``
    (``own``) or on every other block (``not own``). The view's binning is done once either way."""
    for j, (cp, settings) in enumerate(views):
        lo, hi = int(bounds[j]), int(bounds[j + 1])
        parts = [(lo, hi)] if own else [(0, lo), (hi, pts.shape[0])]
        parts = [(a, b) for a, b in parts if b > a]
        if not parts:
            continue
        splats, lists, _ = prepare_view(*arrays, 0, cp, settings)
        for a, b in parts:
            wp.launch(opacity_min_over_view, dim=b - a, device=_wp_device(pts),
                      inputs=[wp.from_torch(pts[a:b].contiguous(), dtype=wp.vec3), lists, splats, cp, settings],
                      outputs=[wp.from_torch(field[a:b]), wp.from_torch(seen[a:b])])


@torch.no_grad()
def cameras_inside_surfaces(gaussians, cameras: Sequence[Camera], *, render_config: RenderConfig | None = None,
                            rays: int = 6, depths: int = 48, solid: float = 0.5,
                            min_fraction: float = 2.0 / 3.0, min_tested: int = 8) -> list[CameraInside]:
    """The cameras that sit inside what the other views see as solid: wrong poses, or photos taken from inside an
    object. Training carves each such camera's free space out of the solid, so the mesh gets a cavity around it.

    For each camera, ``rays × rays`` rays spread over its image are marched with its own opacity at ``depths``
    depths (geometric, from the near plane to twice the cameras' spread plus the Gaussians' extent) to where its
    own view reaches opacity ``solid`` (its surface); points at 0.5 and 0.8 of that depth lie in space this camera
    sees through. The other views' opacity field there (the minimum over them, GOF's rule, without this camera) is
    solid for a camera inside an object and free for a camera outside one — also in a 360° orbit, where the cameras
    beside it see the space in front of it through free space, and in a room, where the other cameras are inside
    it too. A camera is reported when at least ``min_fraction`` of at least ``min_tested`` such points (seen by at
    least one other view) are solid to the other views.

    Returns:
        the :class:`CameraInside` of each camera reported, in camera order (empty: none; also for fewer than two
        cameras or no Gaussians).
    """
    render_config = render_config or RenderConfig()
    render_config.validate()
    cameras = list(cameras)
    if len(cameras) < 2 or len(gaussians) == 0:
        return []
    device = gaussians.device
    wp.init()
    # the renderer's tile, not the field's smaller CPU tile: with a few hundred points a view the binning dominates,
    # and finer tiles make it dearer (2-core CPU, fox: 1.95 s here, 3.9 s with CPU_TILE_SIZE; the same cameras)
    arrays, views = _view_inputs(gaussians, cameras, render_config)
    centres = np.stack([c.center for c in cameras])
    means = gaussians.means.detach().cpu().double().numpy()
    reach = 2.0 * (np.ptp(centres, axis=0).max() + np.ptp(means, axis=0).max()) + 1e-6
    near = max(render_config.near, 1e-4 * reach)
    z = np.geomspace(near * 1.01, max(reach, near * 2.0), depths)  # depths along each ray (camera z)

    def rays_of(cam: Camera) -> np.ndarray:  # [rays², 3] camera-space directions with z = 1
        u = (np.arange(rays) + 0.5) / rays * cam.width
        v = (np.arange(rays) + 0.5) / rays * cam.height
        uu, vv = np.meshgrid(u, v, indexing="xy")
        return np.stack([(uu.ravel() - cam.cx) / cam.fx, (vv.ravel() - cam.cy) / cam.fy, np.ones(uu.size)], 1)

    def world(cam: Camera, d_cam: np.ndarray) -> np.ndarray:  # camera-space points → world
        return (d_cam - cam.t) @ cam.R

    n_r = rays * rays
    # 1. each camera's own surface depth along each of its rays
    march = np.concatenate([world(c, (rays_of(c)[:, None, :] * z[None, :, None]).reshape(-1, 3)) for c in cameras])
    pts = torch.as_tensor(march, dtype=torch.float32, device=device)
    field = torch.ones(len(pts), dtype=torch.float32, device=device)
    seen = torch.zeros(len(pts), dtype=torch.int32, device=device)
    _owned_slices(views, pts, np.arange(len(cameras) + 1) * n_r * depths, field, seen, arrays, own=True)
    own = torch.where(seen > 0, field, torch.zeros_like(field)).cpu().numpy().reshape(len(cameras), n_r, depths)
    hit = own >= solid
    has = hit.any(axis=2)
    surface = z[np.argmax(hit, axis=2)]  # [cameras, rays]: first depth at which the own view is solid
    # 2. points in front of those surfaces, judged by the other views
    tests, counts = [], []
    for j, c in enumerate(cameras):
        d = rays_of(c)[has[j]]
        zs = surface[j][has[j]]
        p = np.concatenate([d * (f * zs)[:, None] for f in (0.5, 0.8)])
        tests.append(world(c, p) if len(p) else np.zeros((0, 3)))
        counts.append(len(p))
    bounds = np.concatenate([[0], np.cumsum(counts)])
    if bounds[-1] == 0:
        return []
    pts = torch.as_tensor(np.concatenate(tests), dtype=torch.float32, device=device)
    field = torch.ones(len(pts), dtype=torch.float32, device=device)
    seen = torch.zeros(len(pts), dtype=torch.int32, device=device)
    _owned_slices(views, pts, bounds, field, seen, arrays, own=False)
    field, seen = field.cpu().numpy(), seen.cpu().numpy()
    out = []
    for j, c in enumerate(cameras):
        f, s = field[bounds[j]:bounds[j + 1]], seen[bounds[j]:bounds[j + 1]]
        tested = int((s > 0).sum())
        if tested >= min_tested:
            frac = float((f[s > 0] >= solid).mean())
            if frac >= min_fraction:
                out.append(CameraInside(j, c.name, round(frac, 3), tested))
    return out


def cameras_inside_message(inside: Sequence[CameraInside], n_cameras: int, shown: int = 5) -> str:
    """One line naming the cameras :func:`cameras_inside_surfaces` reported and what follows for the mesh."""
    names = ", ".join(f"{c.name or c.index!s} ({100 * c.solid_fraction:.0f} % of {c.tested} points)" for c in inside[:shown])
    more = f" and {len(inside) - shown} more" if len(inside) > shown else ""
    return (f"{len(inside)} of {n_cameras} cameras sit inside what the other views see as solid — {names}{more} "
            f"(the share of the space each sees through that is solid to the others): the training carved their view "
            f"out of the solid, so the mesh has cavities around them; check their poses (a wrong scale or sign) or "
            f"leave those photos out")
