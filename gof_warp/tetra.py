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
``opacity_min`` (see ``benchmarks/extract/README.md``).

Memory (host, measured on 900k points / 6.0M tetrahedra, ``benchmarks/extract``): points 12 B + owner
4 B + scale 4 B per point; ``delaunay`` output 16 B/tet (int32); scipy's Qhull peaks at ~360 B/tet
(2.2 GB), the CGAL backend at ~50 B/tet in memory plus a ~60 B/tet temporary text file (``TMPDIR``);
``orient_and_drop_degenerate`` and ``filter_cells`` work in chunks (~250 B/tet and ~100 B/tet of a chunk)
plus a 1 B/tet mask and the 16 B/tet output.
"""

from __future__ import annotations

import itertools
import logging
import os
import tempfile
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from .camera import Camera
from .errors import GofError
from .model import quat_to_rotmat

log = logging.getLogger(__name__)

BOX_SIGMAS = 3.0  # paper: "3 times the Gaussian scales"
CORNER_SIGNS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))  # [8, 3]
# A tetrahedron is degenerate (zero volume) when |6 V| <= this × (longest edge)³: Qhull's "Qt" output
# contains flat simplices whose float64 volume is a rounding residue (~1e-16 relative).
DEGENERATE_REL_VOLUME = 1e-10
CGAL_FILE_PRECISION = 17  # digits: doubles round-trip exactly through CGAL's text output
BACKENDS = ("scipy", "cgal", "auto")
FAST_OPACITY_MIN = 0.2  # TetraConfig.fast(): −34 % points, F-score ±0.2 points (benchmarks/extract)


@dataclass
class TetraConfig:
    """How the tetrahedral grid is built (defaults: official GOF, paper's cell filter on)."""

    opacity_min: float | None = None  # drop Gaussians with opacity below this (official: none)
    frustum_mask: bool = True  # keep points seen by a camera, when cameras are given (official PR #91)
    near: float = 0.02  # frustum mask depth range (official)
    far: float = 1e6
    corner_min_extent: float | None = None  # centre only for Gaussians with 3 max(s) below this
    backend: str = "scipy"  # "scipy" (BSD), "cgal" (GPLv3 extra gof_warp[cgal]) or "auto"
    filter_cells: bool = True  # paper's edge filter (the official code does not filter)

    @classmethod
    def fast(cls, **overrides) -> TetraConfig:
        """Fewer points for a faster Delaunay: Gaussians with opacity < 0.2 give no points.

        Measured (``benchmarks/extract/README.md``, "Point reduction vs accuracy"): on a trained synthetic
        scene it kept 66 % of the points; F-score at τ = 0.5 % of the scene moved −0.2 points with linear
        interpolation and +0.2 with 8 search steps (not yet measured on real scenes). Scale-free, unlike
        ``corner_min_extent``, which is left off."""
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


def frustum_mask(points: torch.Tensor, cameras: Sequence[Camera], near: float, far: float) -> torch.Tensor:
    """``[P]`` bool: the point projects into some camera's image ``[0, W] × [0, H]`` with ``near <= z <= far``."""
    keep = torch.zeros(points.shape[0], dtype=torch.bool, device=points.device)
    for cam in cameras:
        R = torch.as_tensor(cam.R, dtype=points.dtype, device=points.device)
        t = torch.as_tensor(cam.t, dtype=points.dtype, device=points.device)
        pc = points @ R.T + t
        z = pc[:, 2]
        zs = torch.where(z > 0, z, torch.ones_like(z))
        u = cam.fx * pc[:, 0] / zs + cam.cx
        v = cam.fy * pc[:, 1] / zs + cam.cy
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
    s = _as_tensor(scales, "scales", (3,), n).to(mu.device)
    if n and not bool((s > 0).all()):
        raise GofError("scales must be positive (standard deviations, not log-scales)")
    if n and not bool((q.norm(dim=-1) > 0).all()):
        raise GofError("rotations has zero quaternions")
    keep = torch.ones(n, dtype=torch.bool, device=mu.device)
    if opacity_min is not None:
        if opacities is None:
            raise GofError("opacity_min needs opacities")
        o = opacities.reshape(-1) if getattr(opacities, "ndim", 1) == 2 and opacities.shape[1] == 1 else opacities
        keep &= _as_tensor(o, "opacities", (), n).to(mu.device) >= opacity_min
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


# ---------------------------------------------------------------------------------------------- Delaunay
def _check_points(points) -> np.ndarray:
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise GofError(f"points must have shape [P, 3], got {p.shape}")
    p = p.astype(np.float64)
    if not np.all(np.isfinite(p)):
        raise GofError("points has NaN/inf entries")
    if p.shape[0] < 4:
        raise GofError(f"Delaunay needs at least 4 points, got {p.shape[0]}")
    return p


def _signed_volume6(tets: np.ndarray, p: np.ndarray) -> np.ndarray:
    a, b, c, d = (p[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)


def orient_and_drop_degenerate(tets: np.ndarray, points: np.ndarray, chunk_size: int = 1 << 20) -> np.ndarray:
    """Drop zero-volume tetrahedra (|6V| <= DEGENERATE_REL_VOLUME × longest edge³) and swap two vertices
    of the negative ones, so every returned tetrahedron has positive volume. ``[T, 4]`` → ``[T', 4]`` int32."""
    p = np.asarray(points, np.float64)
    out = []
    for s in range(0, tets.shape[0], chunk_size):
        t = np.ascontiguousarray(tets[s : s + chunk_size], dtype=np.int32)
        vol6 = _signed_volume6(t, p)
        longest = np.max([np.linalg.norm(p[t[:, i]] - p[t[:, j]], axis=1) for i, j in itertools.combinations(range(4), 2)],
                         axis=0)
        keep = np.abs(vol6) > DEGENERATE_REL_VOLUME * longest**3
        t = t[keep]
        neg = vol6[keep] < 0
        t[neg] = t[neg][:, [0, 1, 3, 2]]
        out.append(t)
    result = np.concatenate(out) if out else np.zeros((0, 4), np.int32)
    if result.shape[0] < tets.shape[0]:
        log.info("delaunay: dropped %d degenerate tetrahedra", tets.shape[0] - result.shape[0])
    return result


def _delaunay_scipy(p: np.ndarray) -> np.ndarray:
    from scipy.spatial import Delaunay, QhullError

    try:
        return Delaunay(p).simplices
    except QhullError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else ""
        raise GofError(f"Delaunay failed: the {p.shape[0]} points are degenerate (coplanar/collinear?): {first}") from e


def _read_numbers(f, n_lines: int, dtype, block: int = 1 << 20) -> np.ndarray:
    """Next ``n_lines`` whitespace-separated number lines of a text file, in blocks."""
    parts = []
    for start in range(0, n_lines, block):
        text = b"".join(itertools.islice(f, min(block, n_lines - start))).decode()
        parts.append(np.fromstring(text, dtype=dtype, sep=" "))  # text mode (not deprecated), 4x split()
    return np.concatenate(parts) if parts else np.zeros(0, dtype)


def _delaunay_cgal(p: np.ndarray) -> np.ndarray:
    """CGAL's ``Delaunay_triangulation_3`` (pip ``cgal``, SWIG bindings, GPLv3): insert all points, write
    the triangulation as text (full precision), read finite cells, map CGAL's vertices back to our indices
    by their exact coordinates (duplicates map to their first copy)."""
    try:
        from CGAL.CGAL_Kernel import Point_3
        from CGAL.CGAL_Triangulation_3 import Delaunay_triangulation_3
    except ImportError as e:
        raise GofError("backend='cgal' needs the optional CGAL bindings (GPLv3): pip install 'gof_warp[cgal]'") from e
    tri = Delaunay_triangulation_3()
    tri.insert([Point_3(x, y, z) for x, y, z in p.tolist()])
    if tri.dimension() < 3:
        raise GofError(f"Delaunay failed: the {p.shape[0]} points are degenerate (dimension {tri.dimension()})")
    with tempfile.TemporaryDirectory(prefix="gof_cgal_") as tmp:
        path = os.path.join(tmp, "triangulation.txt")
        tri.write_to_file(path, CGAL_FILE_PRECISION)
        del tri
        with open(path, "rb") as f:  # dimension, n, n vertex lines, n_cells, n_cells cell lines, neighbours
            int(f.readline())
            n = int(f.readline())
            xyz = _read_numbers(f, n, np.float64).reshape(n, 3)
            n_cells = int(f.readline())
            cells = _read_numbers(f, n_cells, np.int64).reshape(n_cells, 4)
    cells = cells[(cells != 0).all(axis=1)] - 1  # index 0 is the infinite vertex
    unique, first = np.unique(p, axis=0, return_index=True)
    order = np.lexsort(xyz.T[::-1])
    if unique.shape != xyz.shape or not np.array_equal(unique, xyz[order]):
        raise RuntimeError("CGAL's vertices do not match the input points")
    to_input = np.empty(n, np.int64)
    to_input[order] = first
    return to_input[cells]


def delaunay(points, backend: str = "scipy") -> np.ndarray:
    """Delaunay tetrahedralisation of ``points [P, 3]`` → ``tets [T, 4] int32``, positively oriented,
    zero-volume tetrahedra dropped.

    ``backend``: ``"scipy"`` (Qhull, BSD, default), ``"cgal"`` (optional extra ``gof_warp[cgal]``, GPLv3;
    faster triangulation but its Python bindings export cells through a text file) or ``"auto"`` (CGAL if
    importable, else scipy). Duplicate points are merged (only one copy is used). Raises ``GofError`` for
    fewer than 4 points or points that span no volume (coplanar, collinear).
    """
    if backend not in BACKENDS:
        raise GofError(f"backend must be one of {BACKENDS}, got {backend!r}")
    p = _check_points(points)
    if backend == "auto":
        try:
            import CGAL.CGAL_Triangulation_3  # noqa: F401

            backend = "cgal"
        except ImportError:
            backend = "scipy"
    tets = _delaunay_cgal(p) if backend == "cgal" else _delaunay_scipy(p)
    tets = orient_and_drop_degenerate(tets, p)
    if tets.shape[0] == 0:
        raise GofError(f"Delaunay of {p.shape[0]} points gave no tetrahedron with volume (degenerate points)")
    log.info("delaunay (%s): %d points → %d tetrahedra", backend, p.shape[0], tets.shape[0])
    return tets


# ---------------------------------------------------------------------------------------------- cell filter
def filter_cells(tets, points, owner, point_scale, *, chunk_size: int = 1 << 22) -> np.ndarray:
    """Paper's cell filter: drop tetrahedra with an edge between points of two different Gaussians that is
    longer than the sum of their largest 3σ extents (``|p_i - p_j| > scale_i + scale_j``; the official
    ``--filter_mesh`` test on vertices). Edges within one Gaussian are always kept. Returns ``[T', 4]``."""
    tets = np.asarray(tets)
    p = np.asarray(points, np.float32)
    owner, scale = np.asarray(owner), np.asarray(point_scale, np.float32)
    if tets.ndim != 2 or tets.shape[1] != 4:
        raise GofError(f"tets must have shape [T, 4], got {tets.shape}")
    if not (p.ndim == 2 and p.shape[1] == 3 and owner.shape == scale.shape == (p.shape[0],)):
        raise GofError(f"points [P, 3], owner [P], point_scale [P] disagree: {p.shape}, {owner.shape}, {scale.shape}")
    keep = np.ones(tets.shape[0], bool)
    for s in range(0, tets.shape[0], chunk_size):
        t = tets[s : s + chunk_size]
        k = keep[s : s + chunk_size]
        for i, j in itertools.combinations(range(4), 2):
            a, b = t[:, i], t[:, j]
            too_long = np.linalg.norm(p[a] - p[b], axis=1) > scale[a] + scale[b]
            k &= ~(too_long & (owner[a] != owner[b]))
    log.info("filter_cells: kept %d of %d tetrahedra", int(keep.sum()), tets.shape[0])
    return tets[keep]


def tetrahedral_grid(means, rotations, scales, opacities=None, cameras: Sequence[Camera] | None = None,
                     config: TetraConfig | None = None, stats: dict | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points → Delaunay → (optional) cell filter, as ``config`` says. Returns
    ``(points [P, 3] float32, tets [T, 4] int32, owner [P] int32, point_scale [P] float32)``.

    ``stats``: when a dict is given, the wall time of each sub-stage is written into it (seconds, keys
    ``tetra_points``, ``delaunay``, ``filter_cells``)."""
    cfg = config or TetraConfig()
    stats = {} if stats is None else stats
    t0 = time.perf_counter()
    points, owner, scale = tetra_points(
        means, rotations, scales, opacities, opacity_min=cfg.opacity_min,
        cameras=cameras if cfg.frustum_mask else None, near=cfg.near, far=cfg.far,
        corner_min_extent=cfg.corner_min_extent)
    t1 = time.perf_counter()
    tets = delaunay(points, cfg.backend)
    t2 = time.perf_counter()
    if cfg.filter_cells:
        tets = filter_cells(tets, points, owner, scale)
    stats.update(tetra_points=round(t1 - t0, 4), delaunay=round(t2 - t1, 4),
                 filter_cells=round(time.perf_counter() - t2, 4))
    return points, tets, owner, scale
