"""The Gaussian-induced tetrahedral grid (GOF Sec. 5): points from 3σ boxes, Delaunay, cell filter.

Points: each Gaussian gives the 8 corners of its 3σ box, ``μ + R diag(3 s) (±1, ±1, ±1)``, and its
centre ``μ`` (``s`` = the scales the renderer uses, i.e. GOF's 3D-filtered ones). Order as the official
code: all corners (8 per Gaussian, Gaussian-major, signs in ``itertools.product((-1, 1), repeat=3)``
order), then all centres. Each point records its Gaussian (``owner``) and that Gaussian's largest 3σ
extent (``point_scale = 3 max(s)``).

Reducing the number of points (Delaunay dominates extraction: scipy takes ~53 s and 3 GB for 1e6 points
on one core): ``opacity_min`` drops Gaussians below an opacity; ``cameras`` keeps only points seen by
some camera between ``near`` and ``far`` (official PR #91, there with ``near=0.02, far=1e6``);
``corner_min_extent`` keeps only the centre of Gaussians whose 3σ extent is below it. All are off unless
asked for (the official code has only the frustum mask); ``TetraConfig.fast()`` sets the measured
``opacity_min`` (see :meth:`TetraConfig.fast`).

Memory (host, measured on 900k points / 6.0M tetrahedra): points 12 B + owner
4 B + scale 4 B per point; ``delaunay`` output 16 B/tet (int32); scipy's Qhull peaks at ~360 B/tet
(2.2 GB), the CGAL backend at ~50 B/tet in memory plus a ~60 B/tet temporary text file (``TMPDIR``);
``orient_and_drop_degenerate`` and ``filter_cells`` work in chunks (~250 B/tet and ~100 B/tet of a chunk)
plus a 1 B/tet mask and the 16 B/tet output.
"""

from __future__ import annotations

import itertools
import logging
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from ..core.camera import Camera
from .delaunay import default_workers, delaunay
from ..core.errors import GofError
from ..core.model import quat_to_rotmat
from .octree_tets import OctreeConfig, OctreeTets, octree_grid_tets
from .reach import points_in_boxes

log = logging.getLogger(__name__)

BOX_SIGMAS = 3.0  # paper: "3 times the Gaussian scales"
CORNER_SIGNS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))  # [8, 3]
BAND_NEIGHBOURS = 12  # level_band: nearest points looked at per point
GRIDS = ("auto", "delaunay", "octree")
FAST_OPACITY_MIN = 0.2  # TetraConfig.fast(): −34 % points, F-score ±0.2 points


@dataclass
class TetraConfig:
    """How the tetrahedral grid is built (defaults: official GOF, paper's cell filter on)."""

    opacity_min: float | None = None  # drop Gaussians with opacity below this (official: none)
    frustum_mask: bool = True  # keep points seen by a camera, when cameras are given (official PR #91)
    near: float = 0.02  # frustum mask depth range (official)
    far: float = 1e6
    corner_min_extent: float | None = None  # centre only for Gaussians with 3 max(s) below this
    band: bool = False  # extract: keep only the points near a level crossing before Delaunay (see level_band)
    band_neighbours: int = BAND_NEIGHBOURS
    backend: str = "scipy"  # "scipy" (BSD), "cgal" (GPLv3 extra gof_warp[cgal]) or "auto"
    delaunay_workers: int = 0  # threads for scipy's Delaunay in chunks (0: every CPU; 1: one Qhull call)
    delaunay_chunks: int | None = None  # chunks of the parallel path (None: gof_warp.mesh.delaunay's default)
    # the chunks in forked processes where the OS can fork (Linux), else threads: Qhull and the chunks' numpy work
    # hold the GIL for part of the time (DTU scan 24 on a 16-core host: chunks 60.7 s in threads, 35.3 s in processes)
    delaunay_processes: bool = True
    filter_cells: bool = True  # paper's edge filter (the official code does not filter)
    # "octree": a balanced octree sized by the Gaussians' boxes, split into tetrahedra on the model's device
    # (gof_warp.mesh.octree_tets; no Delaunay). "delaunay": the official grid, the Delaunay of the 3σ-box corners and
    # centres on the CPU. "auto" (default): the octree, but the Delaunay grid for a small model, one whose octree at the
    # default cell factor would have fewer than octree.small_leaves leaves (and no cell factor is given): there the
    # Delaunay costs seconds and the octree's few large cells cost accuracy. Measured: DTU scan 24 on an H200 7.9 s /
    # 4.2M faces against 81 s / 9.4M, on the synthetic garden's ground-and-objects crop the same Chamfer (0.00563 vs
    # 0.00565); the README job's model (40k leaves), five seeds: the octree ×0.35 Chamfer +1.7 % (worst +2.3 %)
    # against the Delaunay grid in 7.8 s, the Delaunay grid 15.4 s (benchmarks/RESULTS.md)
    grid: str = "auto"
    octree: OctreeConfig = field(default_factory=OctreeConfig)

    def validate(self):
        if self.grid not in GRIDS:
            raise GofError(f"tetra grid must be one of {GRIDS}, got {self.grid!r}")
        if self.grid != "delaunay":
            self.octree.validate()
            delaunay_only = {"band (--band)": self.band, "corner_min_extent (--corner-min-extent)":
                             self.corner_min_extent is not None, "backend (--delaunay)": self.backend != "scipy",
                             "delaunay_workers (--delaunay-workers)": self.delaunay_workers != 0,
                             "delaunay_processes (--no-delaunay-processes)": not self.delaunay_processes,
                             "delaunay_chunks": self.delaunay_chunks is not None}
            asked = [name for name, set_ in delaunay_only.items() if set_]
            if asked:
                raise GofError(f"{', '.join(asked)}: Delaunay-grid settings, but the grid is {self.grid!r} (the "
                               "octree, or with 'auto', the default, the Delaunay grid only for a small model); add "
                               "--grid delaunay (TetraConfig.grid = 'delaunay') to use them")
        elif self.octree != OctreeConfig():
            raise GofError(f"octree settings ({self.octree}; --cell-factor, --piece-tets, --reach-filter) apply to the "
                           "octree grid, but the grid is 'delaunay': drop them or use --grid octree")

    @classmethod
    def fast(cls, **overrides) -> TetraConfig:
        """Faster grid: Gaussians with opacity < 0.2 give no points (the Delaunay runs in exact chunks on every CPU
        by default anyway).

        Measured on a trained synthetic scene: ``opacity_min = 0.2`` kept
        66 % of the points; F-score at τ = 0.5 % of the scene moved −0.2 points with linear interpolation and
        +0.2 with 8 search steps. ``corner_min_extent`` is scale-dependent and left off."""
        return cls(**{"opacity_min": FAST_OPACITY_MIN, **overrides})


# ---------------------------------------------------------------------------------------------- points
def _as_tensor(x, name: str, shape_tail: tuple, n: int | None = None) -> torch.Tensor:
    t = x.detach() if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x))
    if t.ndim != 1 + len(shape_tail) or tuple(t.shape[1:]) != shape_tail or (n is not None and t.shape[0] != n):
        want = f"[{'N' if n is None else n}{''.join(', ' + str(s) for s in shape_tail)}]"
        raise GofError(f"{name} must have shape {want}, got {tuple(t.shape)}")
    t = t.to(torch.float64)
    if t.numel() and not bool(torch.isfinite(t).all()):
        raise GofError(f"{name} has NaN/inf entries")
    return t


def _checked_scales(scales, n: int, device) -> torch.Tensor:
    """``scales [n, 3]`` (standard deviations, all > 0) as float64 on ``device``."""
    s = _as_tensor(scales, "scales", (3,), n).to(device)
    if n and not bool((s > 0).all()):
        raise GofError("scales must be positive (standard deviations, not log-scales)")
    return s


def _opacity_mask(opacities, opacity_min: float | None, n: int, device) -> torch.Tensor:
    """``[n]`` bool: the Gaussians with ``opacity >= opacity_min`` (all of them when it is ``None``); ``opacities``
    ``[n]`` or ``[n, 1]``."""
    keep = torch.ones(n, dtype=torch.bool, device=device)
    if opacity_min is not None:
        if opacities is None:
            raise GofError("opacity_min needs opacities")
        o = opacities.reshape(-1) if getattr(opacities, "ndim", 1) == 2 and opacities.shape[1] == 1 else opacities
        keep &= _as_tensor(o, "opacities", (), n).to(device) >= opacity_min
    return keep


def frustum_mask(points: torch.Tensor, cameras: Sequence[Camera], near: float, far: float) -> torch.Tensor:
    """``[P]`` bool: the point projects into some camera's image ``[0, W] × [0, H]`` with ``near <= z <= far``."""
    keep = torch.zeros(points.shape[0], dtype=torch.bool, device=points.device)
    for cam in cameras:
        u, v, z = cam.project_tensor(points)
        keep |= (z >= near) & (z <= far) & (u >= 0) & (u <= cam.width) & (v >= 0) & (v <= cam.height)
    return keep


def tetra_points(means, rotations, scales, opacities=None, *, opacity_min: float | None = None,
                 cameras: Sequence[Camera] | None = None, near: float = 0.02, far: float = 1e6,
                 corner_min_extent: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points of the tetrahedral grid (see the module docstring).

    Args:
        means: ``[N, 3]`` centres; rotations: ``[N, 4]`` quaternions wxyz (normalised here); scales:
            ``[N, 3]`` standard deviations (> 0); opacities: ``[N]`` or ``[N, 1]`` (for ``opacity_min``).
            numpy or torch (computed on the tensors' device in float64).
        opacity_min: keep Gaussians with ``opacity >= opacity_min``.
        cameras: keep points in the frustum ``near <= z <= far`` of at least one camera.
        corner_min_extent: Gaussians with ``3 max(s) < corner_min_extent`` give only their centre.

    Returns:
        ``points [P, 3] float32``, ``owner [P] int32`` (Gaussian index), ``point_scale [P] float32``.
    """
    mu = _as_tensor(means, "means", (3,))
    n = mu.shape[0]
    q = _as_tensor(rotations, "rotations", (4,), n).to(mu.device)
    s = _checked_scales(scales, n, mu.device)
    if n and not bool((q.norm(dim=-1) > 0).all()):
        raise GofError("rotations has zero quaternions")
    keep = _opacity_mask(opacities, opacity_min, n, mu.device)
    gid = torch.nonzero(keep).squeeze(1)
    mu, q, s = mu[gid], q[gid], s[gid]
    extent = BOX_SIGMAS * s.max(dim=1).values
    with_corners = torch.ones_like(extent, dtype=torch.bool)
    if corner_min_extent is not None:
        with_corners = extent >= corner_min_extent
    signs = torch.as_tensor(CORNER_SIGNS, dtype=mu.dtype, device=mu.device)
    cg = torch.nonzero(with_corners).squeeze(1)
    R = quat_to_rotmat(q[cg])  # [n, 3, 3]
    local = signs[None, :, :] * (BOX_SIGMAS * s[cg])[:, None, :]  # [n, 8, 3] = diag(3s) (±1, ±1, ±1)
    offsets = torch.einsum("nij,nkj->nki", R, local)
    corners = (mu[cg][:, None, :] + offsets).reshape(-1, 3)
    points = torch.cat([corners, mu], 0)
    owner = torch.cat([gid[cg].repeat_interleave(8), gid])
    scale = torch.cat([extent[cg].repeat_interleave(8), extent])
    if cameras:
        m = frustum_mask(points, cameras, near, far)
        points, owner, scale = points[m], owner[m], scale[m]
    log.info("tetra_points: %d of %d Gaussians, %d points", gid.numel(), n, points.shape[0])
    return (points.to(torch.float32).cpu().numpy(), owner.to(torch.int32).cpu().numpy(),
            scale.to(torch.float32).cpu().numpy())


# ---------------------------------------------------------------------------------------------- cell filter
def filter_cells(tets, points, owner, point_scale, *, chunk_size: int = 1 << 20, workers: int = 1) -> np.ndarray:
    """Paper's cell filter: drop tetrahedra with an edge between points of two different Gaussians that is
    longer than the sum of their largest 3σ extents (``|p_i - p_j| > scale_i + scale_j``; the official
    ``--filter_mesh`` test on vertices). Edges within one Gaussian are always kept. Returns ``[T', 4]``.
    ``workers``: threads over chunks of ``chunk_size`` tetrahedra (numpy releases the GIL in its loops)."""
    tets = np.asarray(tets)
    p = np.asarray(points, np.float32)
    owner, scale = np.asarray(owner), np.asarray(point_scale, np.float32)
    if tets.ndim != 2 or tets.shape[1] != 4:
        raise GofError(f"tets must have shape [T, 4], got {tets.shape}")
    if not (p.ndim == 2 and p.shape[1] == 3 and owner.shape == scale.shape == (p.shape[0],)):
        raise GofError(f"points [P, 3], owner [P], point_scale [P] disagree: {p.shape}, {owner.shape}, {scale.shape}")
    keep = np.ones(tets.shape[0], bool)

    def run(s):
        t = tets[s : s + chunk_size]
        k = keep[s : s + chunk_size]
        for i, j in itertools.combinations(range(4), 2):
            a, b = t[:, i], t[:, j]
            too_long = np.linalg.norm(p[a] - p[b], axis=1) > scale[a] + scale[b]
            k &= ~(too_long & (owner[a] != owner[b]))

    with ThreadPoolExecutor(max(1, workers)) as pool:
        list(pool.map(run, range(0, tets.shape[0], chunk_size)))
    log.info("filter_cells: kept %d of %d tetrahedra", int(keep.sum()), tets.shape[0])
    return tets[keep]


def level_band(points, values, owner, point_scale, levels, *, neighbours: int = BAND_NEIGHBOURS,
               workers: int = -1, chunk: int = 1 << 20) -> np.ndarray:
    """``[P]`` bool: the points that can end a crossing edge of the level sets — those with one of their
    ``neighbours`` nearest points on the other side of some level within the cell filter's reach
    (``|p_i - p_j| <= scale_i + scale_j``, or both of one Gaussian), and that neighbour — plus every point of
    a Gaussian that holds such a point or whose own points lie on both sides of a level.

    An approximation: after the paper's cell filter a crossing edge joins two points within reach on either
    side of a level, but the partner need not be among the few nearest points (a point's nearest ones are
    mostly its own Gaussian's corners), and dropping the far points changes which tetrahedra fill the band.
    Measured on the DTU model: 29 % of the points with nearest neighbours
    alone (F 0.90 against the full grid's mesh at 0.1 % of the diagonal), 75 % with whole Gaussians (F 0.95):
    not the same mesh, hence off by default. Cost: a KD-tree and a ``neighbours``-NN query over all points (``workers``
    threads; ~8 core-s per million points at 12 neighbours).

    Args:
        points ``[P, 3]``, values ``[P]`` (the field at the points), owner ``[P]`` int (Gaussian),
        point_scale ``[P]`` (3 max(s) of the owner), levels: the iso-levels.
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, np.float32)
    v = np.asarray(values, np.float32).reshape(-1)
    owner, scale = np.asarray(owner), np.asarray(point_scale, np.float32)
    if not (p.ndim == 2 and p.shape[1] == 3 and v.shape == owner.shape == scale.shape == (p.shape[0],)):
        raise GofError(f"points [P, 3], values/owner/point_scale [P] disagree: {p.shape}, {v.shape}, {owner.shape}, "
                       f"{scale.shape}")
    band = np.zeros(p.shape[0], bool)
    k = min(neighbours + 1, p.shape[0])
    if k < 2:
        return band
    tree = cKDTree(p, balanced_tree=False, compact_nodes=False)
    sides = np.stack([v >= float(level) for level in levels], axis=1)  # [P, L]
    for start in range(0, p.shape[0], chunk):
        dist, nbr = tree.query(p[start:start + chunk], k=k, workers=workers)
        dist, nbr = dist[:, 1:], nbr[:, 1:]  # the first is the point itself (or an exact duplicate)
        own = np.arange(start, start + dist.shape[0])
        other = np.any(sides[nbr] != sides[own][:, None, :], axis=2)  # [C, K]
        reach = (dist <= scale[own][:, None] + scale[nbr]) | (owner[nbr] == owner[own][:, None])
        pair = other & reach
        band[own[pair.any(axis=1)]] = True
        band[nbr[pair]] = True
    # a Gaussian whose 3σ box straddles a level, or that holds a band point, brings all its points: its box
    # corners span the crossing at its own scale, which a few nearest neighbours among smaller Gaussians miss
    straddles = np.zeros(int(owner.max()) + 1 if owner.size else 0, bool)
    for level_side in sides.T:
        lo = np.ones_like(straddles)
        hi = np.zeros_like(straddles)
        np.logical_and.at(lo, owner, level_side)
        np.logical_or.at(hi, owner, level_side)
        straddles |= hi & ~lo
    straddles[owner[band]] = True
    band |= straddles[owner]
    log.info("level_band: %d of %d points near a level crossing", int(band.sum()), p.shape[0])
    return band


def tetrahedralize(points, owner, point_scale, config: TetraConfig | None = None, stats: dict | None = None
                   ) -> np.ndarray:
    """Delaunay of ``points [P, 3]`` then (optional) the paper's cell filter → ``tets [T, 4] int32``;
    ``stats`` gets ``delaunay`` and ``filter_cells`` seconds (and the Delaunay's counters)."""
    cfg = config or TetraConfig()
    stats = {} if stats is None else stats
    t1 = time.perf_counter()
    workers = cfg.delaunay_workers or default_workers()
    tets = delaunay(points, cfg.backend, workers=workers, chunks=cfg.delaunay_chunks, stats=stats,
                    processes=cfg.delaunay_processes)
    t2 = time.perf_counter()
    if cfg.filter_cells:
        tets = filter_cells(tets, points, owner, point_scale, workers=workers)
    stats.update(delaunay=round(t2 - t1, 4), filter_cells=round(time.perf_counter() - t2, 4))
    return tets


def grid_points(means, rotations, scales, opacities=None, cameras: Sequence[Camera] | None = None,
                config: TetraConfig | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`tetra_points` with the point reductions and frustum mask that ``config`` asks for."""
    cfg = config or TetraConfig()
    return tetra_points(means, rotations, scales, opacities, opacity_min=cfg.opacity_min,
                        cameras=cameras if cfg.frustum_mask else None, near=cfg.near, far=cfg.far,
                        corner_min_extent=cfg.corner_min_extent)


def octree_tets_from_gaussians(means, rotations, scales, opacities=None, cameras: Sequence[Camera] | None = None,
                               config: TetraConfig | None = None, stats: dict | None = None) -> OctreeTets | None:
    """The octree grid (:mod:`gof_warp.mesh.octree_tets`) over the Gaussians' 3σ boxes (radius ``3 max(s)``), with the
    Delaunay grid's selection: ``opacity_min``, and the frustum mask applied to the centres. Returns the grid's
    :class:`~gof_warp.mesh.octree_tets.OctreeTets` (points held, tetrahedra made in pieces) on the means' device, or, with
    ``config.grid = "auto"``, None for a small model, whose grid is the Delaunay one (``stats`` says why). With
    ``config.octree.reach_filter`` its ``reach [P]`` marks the points inside some selected Gaussian's oriented 3σ box
    (:func:`gof_warp.mesh.reach.points_in_boxes`; ``stats["octree_points_in_reach"]``).

    ``means [N, 3]``, ``rotations [N, 4]`` (wxyz), ``scales [N, 3]`` (standard deviations), ``opacities [N]``."""
    cfg = config or TetraConfig()
    mu = _as_tensor(means, "means", (3,))
    q = _as_tensor(rotations, "rotations", (4,), mu.shape[0]).to(mu.device)
    s = _checked_scales(scales, mu.shape[0], mu.device)
    keep = _opacity_mask(opacities, cfg.opacity_min, mu.shape[0], mu.device)
    if cameras and cfg.frustum_mask:
        keep &= frustum_mask(mu, cameras, cfg.near, cfg.far)
    if not bool(keep.any()):
        raise GofError(f"no Gaussian is left for the octree grid: of {mu.shape[0]}, none has its centre in some camera's "
                       f"view (near {cfg.near:g}, far {cfg.far:g})"
                       + (f" and opacity >= opacity_min {cfg.opacity_min:g}" if cfg.opacity_min is not None else ""))
    mu, q, s = mu[keep], q[keep], s[keep]
    grid = octree_grid_tets(mu, BOX_SIGMAS * s.max(dim=1).values, cfg.octree, stats=stats,
                            small_grid="none" if cfg.grid == "auto" else "finer")
    if grid is not None and cfg.octree.reach_filter:
        t0 = time.perf_counter()
        grid.reach = points_in_boxes(grid.points, mu, q, BOX_SIGMAS * s)
        if stats is not None:
            stats.update(octree_points_in_reach=int(grid.reach.sum()), reach=round(time.perf_counter() - t0, 4))
    return grid


def tetrahedral_grid(means, rotations, scales, opacities=None, cameras: Sequence[Camera] | None = None,
                     config: TetraConfig | None = None, stats: dict | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points → Delaunay → (optional) cell filter, as ``config`` says (no level band: that needs the field,
    see :func:`gof_warp.mesh.extraction.extract_mesh`). Returns
    ``(points [P, 3] float32, tets [T, 4] int32, owner [P] int32, point_scale [P] float32)``.

    ``stats``: when a dict is given, the wall time of each sub-stage is written into it (seconds, keys
    ``tetra_points``, ``delaunay``, ``filter_cells``)."""
    cfg = config or TetraConfig()
    stats = {} if stats is None else stats
    t0 = time.perf_counter()
    points, owner, scale = grid_points(means, rotations, scales, opacities, cameras, cfg)
    stats.update(tetra_points=round(time.perf_counter() - t0, 4))
    return points, tetrahedralize(points, owner, scale, cfg, stats), owner, scale
