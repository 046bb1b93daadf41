"""Mesh extraction from trained Gaussians — the library behind ``python -m gof_warp.extract`` (GOF Sec. 3.4,
appendix Algorithms 1–3):

* ``tetra`` (GOF): a tetrahedral grid around the Gaussians → opacity field at its points → marching tetrahedra with
  binary search on the crossing edges → (optional) quadric decimation to a face budget. The grid is by default
  (``TetraConfig.grid = "auto"``) the octree grid (:mod:`gof_warp.mesh.octree_tets`: a balanced octree sized by the 3σ
  boxes, split into tetrahedra on the model's device, no Delaunay), or for a small model the official one
  (``"delaunay"``): each Gaussian's centre and 3σ-box corners → (optional level band) → exact Delaunay tetrahedra
  (cell filter) on the CPU.
* ``cubes``: the same opacity field on a dense grid → marching cubes (+ the same binary search).
* ``tsdf``: fusion of rendered median depths (the 2DGS/3DGS baseline) → marching cubes.

:class:`MeshConfig` (one dataclass for the stage), :func:`extract_mesh`, :class:`StageTimer` (per-stage wall time
and peak memory; ``python -m gof_warp.extract`` writes them per stage as JSON), :func:`meshable`,
:func:`save_mesh`. Each stage's memory bound is in its module's docstring.
"""


from __future__ import annotations

import dataclasses
import logging
import resource
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch

from ..core.arrays import distinct, even_split
from ..core.camera import Camera
from ..training.distributed import Ranks
from ..core.errors import GofError, ModelError
from .marching import compact_mesh, marching_tetrahedra, merge_keyed_pieces, search_edges
from .marching_inputs import MAX_BINARY_STEPS, MAX_STEPS_PER_CALL
from ..rendering.opacity_field import (OpacityFieldConfig, cameras_inside_message, cameras_inside_surfaces,
                                      opacity_field)
from ..rendering.render import RenderConfig
from .tetra import TetraConfig, grid_points, level_band, octree_tets_from_gaussians, tetrahedralize
from .tsdf import TSDFConfig, extract_tsdf_mesh, fuse_tsdf
from .visibility import faces_seen

log = logging.getLogger(__name__)
METHODS = ("tetra", "cubes", "tsdf")
UNSEEN_MARK = -1.0  # field value marking the points no view sees (the field itself lies in [0, 1])
# grid nodes along the longest side (cubes, tsdf): marching cubes needs 2; 2048³ dense nodes are already 8.6e9 values
MIN_RESOLUTION, MAX_RESOLUTION = 2, 2048


@dataclass
class MeshConfig:
    """Mesh extraction settings (defaults: GOF's — level 0.5, 8 bisection steps)."""

    method: str = "tetra"
    levels: tuple[float, ...] = (0.5,)
    binary_steps: int = 8
    cubes_resolution: int = 256  # grid nodes along the longest side (method "cubes")
    crop: tuple[float, ...] | None = None  # (xmin, ymin, zmin, xmax, ymax, zmax): drop faces outside
    min_component_faces: int = 0  # drop connected components with fewer faces (0 = keep all)
    max_faces: int | None = None  # quadric decimation to at most this many faces per mesh (gof_warp.mesh.decimate)
    max_error: float | None = None  # ... or to the fewest faces whose vertices stay this close (world units)
    tetra: TetraConfig = field(default_factory=TetraConfig)
    tsdf: TSDFConfig = field(default_factory=TSDFConfig)
    field: OpacityFieldConfig = field(default_factory=OpacityFieldConfig)
    # tetra: bisection steps served by one opacity-field call (0: on CUDA chosen from the field's measured cost,
    # SearchPlanner, on the CPU one; d >= 1 fixed). The mesh is the same for any value; only the calls change.
    search_steps_per_call: int = 0
    # drop the faces no training camera sees (gof_warp.mesh.visibility): level crossings under a ground, inside objects,
    # behind walls, which the octree grid finds and no photo supports. False: GOF's mesh as marched
    drop_hidden: bool = True

    def validate(self):
        if self.method not in METHODS:
            raise GofError(f"mesh method must be one of {METHODS}, got {self.method!r}")
        if not self.levels or not all(0.0 < float(v) < 1.0 for v in self.levels):
            raise GofError(f"levels must be opacities in (0, 1), got {self.levels}")
        twice = level_name_clash(self.levels)
        if twice:
            raise GofError(f"levels {twice[0]:g} and {twice[1]:g} name the same mesh (each level writes one): give "
                           "each level once")
        if isinstance(self.binary_steps, bool) or not isinstance(self.binary_steps, (int, np.integer)) \
                or not 0 <= self.binary_steps <= MAX_BINARY_STEPS:
            raise GofError(f"binary_steps must be an integer in [0, {MAX_BINARY_STEPS}] (each step halves the "
                           f"bracket; float32 has 24 significand bits), got {self.binary_steps!r}")
        for name, res in (("cubes_resolution", self.cubes_resolution), ("tsdf.resolution", self.tsdf.resolution)):
            if isinstance(res, bool) or not isinstance(res, (int, np.integer)) or not MIN_RESOLUTION <= res <= MAX_RESOLUTION:
                raise GofError(f"{name} must be an integer in [{MIN_RESOLUTION}, {MAX_RESOLUTION}] (grid nodes along "
                               f"the longest side), got {res!r}")
        if isinstance(self.min_component_faces, bool) or not isinstance(self.min_component_faces, (int, np.integer)) \
                or self.min_component_faces < 0:
            raise GofError(f"min_component_faces must be an integer >= 0, got {self.min_component_faces!r}")
        if self.max_faces is not None and not self.max_faces >= 4:
            raise GofError(f"max_faces must be >= 4, got {self.max_faces}")
        if isinstance(self.search_steps_per_call, bool) or not isinstance(self.search_steps_per_call, int) \
                or not 0 <= self.search_steps_per_call <= MAX_STEPS_PER_CALL:
            raise GofError(f"search_steps_per_call must be an integer in [0, {MAX_STEPS_PER_CALL}] (0: automatic), "
                           f"got {self.search_steps_per_call!r}")
        if self.max_error is not None and not self.max_error > 0:
            raise GofError(f"max_error must be > 0 (world units), got {self.max_error}")
        self.field.validate()
        self.tetra.validate()


def level_name_clash(levels) -> tuple[float, float] | None:
    """The first two of ``levels`` whose mesh files would have one name (``<stem>_<level:g>``), or None."""
    seen = {}
    for level in levels:
        key = f"{float(level):g}"
        if key in seen:
            return seen[key], float(level)
        seen[key] = float(level)
    return None


class StageTimer:
    """Wall time and peak memory (host RSS; on a CUDA ``device`` its torch and Warp-pool peaks) per named stage."""

    def __init__(self, device="cpu", progress=None):
        from ..core.progress import as_stages

        self.stages: dict[str, dict] = {}
        self.device = torch.device(str(device))
        self.progress = as_stages(progress)  # gof_warp.core.progress.Stages: a line (or ticking line) per stage

    @contextmanager
    def __call__(self, name: str):
        cuda = self.device.type == "cuda"
        if cuda:
            torch.cuda.synchronize(self.device)
            torch.cuda.reset_peak_memory_stats(self.device)
        t0 = time.perf_counter()
        with self.progress.stage(name):
            yield
            if cuda:
                torch.cuda.synchronize(self.device)
        entry = {"time_s": round(time.perf_counter() - t0, 4),
                 "host_peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)}
        children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
        if children > 0:  # forked workers (Delaunay chunks, CPU field) that have ended: the largest one's peak
            entry["host_child_peak_rss_mb"] = round(children, 1)
        if cuda:
            import warp as wp

            entry["gpu_peak_allocated_mb"] = round(torch.cuda.max_memory_allocated(self.device) / 2**20, 1)
            entry["gpu_warp_pool_high_mb"] = round(  # since start
                wp.get_mempool_used_mem_high(f"cuda:{self.device.index or 0}") / 2**20, 1)
        self.stages[name] = entry


def _postprocess(verts, faces, config: MeshConfig):
    """Crop and small-component removal; returns compacted ``(verts, faces)``."""
    keep = np.ones(len(faces), bool)
    if config.crop is not None:
        box = np.asarray(config.crop, float)
        inside = np.all((verts >= box[:3]) & (verts <= box[3:]), axis=1)
        keep &= inside[faces].all(axis=1)
    faces = faces[keep]
    if config.min_component_faces > 0 and len(faces):
        import trimesh

        labels = trimesh.graph.connected_component_labels(trimesh.graph.face_adjacency(faces), node_count=len(faces))
        counts = np.bincount(labels)
        faces = faces[counts[labels] >= config.min_component_faces]
    verts, faces, _ = compact_mesh(verts, faces)
    return verts, faces


def meshable(gaussians):
    """The Gaussians that can be bounded and meshed, with a warning naming what was left out.

    A scale whose square overflows float32 (log-scale above ~44, e.g. a diverged model's e^50) turns the
    covariance, the 3D filter's scale and its opacity compensation into inf/NaN. The renderer already skips
    such a Gaussian (NaN opacity), but a grid cannot be sized around it nor a 3σ box triangulated, so it is
    left out here — the mesh is that of the other Gaussians, which is what they render. A model with none
    left raises :class:`~gof_warp.core.errors.ModelError`.
    """
    with torch.no_grad():
        s = gaussians.raw_scales
        ok = (torch.isfinite(s * s).all(dim=1) & torch.isfinite(gaussians.scales).all(dim=1)
              & torch.isfinite(gaussians.opacities))
        n_bad = int((~ok).sum())
        if n_bad == 0:
            return gaussians
        top = float(gaussians.log_scales.detach()[~ok].max())
    why = f"scales too large to represent (log-scale up to {top:.3g}; scale squared overflows float32)"
    if n_bad == len(gaussians):
        raise ModelError(f"all {n_bad} Gaussians have {why}: the model is degenerate, nothing to mesh")
    log.warning("warning: %d of %d Gaussians have %s: left out of the mesh", n_bad, len(gaussians), why)
    return gaussians.subset(ok)


def empty_mesh_message(gaussians, method: str, levels, config: MeshConfig | None = None) -> str:
    """Why a mesh came out empty, for the one-line error of a CLI that refuses to write it."""
    with torch.no_grad():
        s = gaussians.raw_scales.max(dim=1).values
        o = gaussians.opacities
        stats = (f"{len(gaussians)} Gaussians, largest scale {float(s.max()):.3g}, median {float(s.median()):.3g}, "
                 f"opacity up to {float(o.max()):.3g}")
    lv = ", ".join(f"{x:g}" for x in levels)
    removed = ""
    if config is not None and (config.crop is not None or config.min_component_faces > 0):
        removed = " or the crop/--min-component-faces removed every face"
    return (f"no surface crosses level {lv} ({method}): the mesh would be empty — the model is empty or degenerate "
            f"({stats}){removed}; nothing was written")


def _tetra_grid(gaussians, cameras, config: MeshConfig, tc: TetraConfig, field_fn, timer: StageTimer, ranks: Ranks):
    """The tetra path's grid: points → the field at them → (band) → Delaunay + cell filter. Returns
    ``(points [P, 3] float32, values [P] (the field, on the model's device), tets, counts)``: ``tets`` the grid's
    tetrahedra as pieces for :func:`_march` (:class:`_WholeTets` of ``[T, 4]`` int32, or the octree's
    :class:`_OctreePieces`), None when there are none; each stage is timed on ``timer``. With several ``ranks`` the
    Delaunay runs on rank 0 only and its tetrahedra are broadcast (every rank has the same points)."""
    chosen = "delaunay"
    if tc.grid != "delaunay":
        octree = _octree_grid(gaussians, cameras, config, field_fn, timer)
        if octree[0] is not None:
            return octree
        chosen = octree[3]["grid"]  # "auto" found a small model: the Delaunay grid, and why
    with timer("tetra_points"):
        points, owner, scale = grid_points(gaussians.means.detach(), gaussians.rotations.detach(),
                                           gaussians.scales.detach(), gaussians.opacities.detach(), cameras, tc)
    counts = {"grid": chosen, "points": int(len(points))}
    few_views = config.field.min_views > 1  # the frustum mask kept points one view sees: mark them, drop their cells
    with timer("opacity_field"):  # at every point first: the level band needs it, the marching reuses it
        values = field_fn(points, dataclasses.replace(config.field, unseen_value=UNSEEN_MARK)) if few_views \
            else field_fn(points)
    if tc.band:
        with timer("level_band"):
            keep = level_band(points, values.detach().cpu().numpy(), owner, scale, config.levels,
                              neighbours=tc.band_neighbours)
            points, owner, scale = points[keep], owner[keep], scale[keep]
            values = values[torch.as_tensor(keep, device=values.device)]
        counts["band_points"] = int(len(points))
    if len(points) < 4:
        return points, values, None, counts
    substages: dict = {}
    with timer("delaunay+filter"):
        tets = ranks.broadcast_rows(tetrahedralize(points, owner, scale, tc, stats=substages) if ranks.is_main else None)
        if ranks.active:
            substages.setdefault("computed_on_rank", 0)
    timer.stages["delaunay+filter"]["substages"] = substages
    if few_views:
        values, tets, dropped = _drop_unseen_cells(values, tets, config.field.unseen_value)
        tets = tets.cpu().numpy()
        counts["tetrahedra_out_of_view"] = dropped
    log.info("%d points, %d tetrahedra", len(points), len(tets))
    counts["tetrahedra"] = int(len(tets))
    return points, values, (_WholeTets(tets) if len(tets) else None), counts


def _unmarked(values: torch.Tensor, unseen_value: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``(values, seen [P] bool)``: the field with its ``UNSEEN_MARK`` points set to ``unseen_value`` (which the search
    keeps using), and which points were seen."""
    seen = values >= 0
    return torch.where(seen, values, torch.full_like(values, unseen_value)), seen


def _in_view(tets: torch.Tensor, seen: torch.Tensor) -> torch.Tensor:
    """``[T]`` bool: every corner of the tetrahedron ``tets [T, 4]`` is seen."""
    return seen[tets.long()].all(dim=1)


def _drop_unseen_cells(values: torch.Tensor, tets, unseen_value: float):
    """``(values, tets, dropped)``: the tetrahedra ``[T, 4]`` with a corner marked ``UNSEEN_MARK`` left out, and the
    marks replaced by ``unseen_value`` (:func:`_unmarked`). ``tets`` may be numpy; a torch tensor returns."""
    values, seen = _unmarked(values, unseen_value)
    tets = torch.as_tensor(tets, device=values.device)
    in_view = _in_view(tets, seen)
    return values, tets[in_view], int(tets.shape[0] - int(in_view.sum()))


def _octree_grid(gaussians, cameras, config: MeshConfig, field_fn, timer: StageTimer):
    """The tetra path's octree grid (:func:`gof_warp.mesh.tetra.octree_tets_from_gaussians`): ``(points, values, tets,
    counts)`` as :func:`_tetra_grid`, but ``tets`` is an :class:`_OctreePieces`: the tetrahedra are made piece by
    piece when marched, never held whole.

    The octree fills whole boxes, which can reach out of every view; the Delaunay grid has no such points (its
    frustum mask drops them before triangulating). To match it, the tetrahedra with a corner no view sees are left
    out: an unseen corner would otherwise carry GOF's "unseen = 1" next to empty seen space and raise walls at the
    frustum boundaries. With ``field.min_views`` > 1 "unseen" means seen by fewer views (both grids). The search keeps
    GOF's setting, as on the Delaunay grid.

    With ``TetraConfig.grid = "auto"`` a small model gets no octree: ``(None, None, None, counts)``, ``counts["grid"]``
    saying why, and :func:`_tetra_grid` takes the Delaunay grid."""
    sub: dict = {}
    with timer("octree_grid"):
        grid = octree_tets_from_gaussians(gaussians.means.detach(), gaussians.rotations.detach(),
                                          gaussians.scales.detach(), gaussians.opacities.detach(), cameras,
                                          config.tetra, stats=sub)
    timer.stages["octree_grid"]["substages"] = sub
    if grid is None:
        oc = config.tetra.octree
        return None, None, None, {"grid": f"delaunay (auto: {sub['octree_leaves']:,} octree leaves at cell factor "
                                          f"{sub['octree_cell_factor']:g}, fewer than {oc.small_leaves:,})"}
    with timer("opacity_field"):
        values, seen = _unmarked(field_fn(grid.points, dataclasses.replace(config.field, unseen_value=UNSEEN_MARK)),
                                 config.field.unseen_value)
    counts = {"grid": "octree", "points": int(grid.points.shape[0]), "tetrahedra_made": grid.count}
    log.info("octree grid: %d points, %d tetrahedra", grid.points.shape[0], grid.count)
    tets = _OctreePieces(grid, seen, config.tetra.octree.piece_tets)
    return grid.points, values, (tets if grid.count else None), counts


class _OctreePieces:
    """The octree grid's tetrahedra kept, piece by piece: each piece of :meth:`OctreeTets.pieces
    <gof_warp.mesh.octree_tets.OctreeTets.pieces>` without the tetrahedra that have a corner no view sees (``seen [P]``
    false) and, when the grid has its ``reach`` (``OctreeConfig.reach_filter``), those with no corner inside a
    Gaussian's 3σ box. ``n_pieces(world)``: enough pieces of at most ``piece_tets`` made tetrahedra, and one per rank
    at least."""

    def __init__(self, grid, seen: torch.Tensor, piece_tets: int):
        self.grid, self.seen, self.piece_tets = grid, seen, piece_tets

    def n_pieces(self, world: int) -> int:
        return max(world, -(-self.grid.count // self.piece_tets))

    def pieces(self, n_pieces: int, first: int, last: int, tally: dict):
        """Yield the kept tetrahedra of pieces ``first … last - 1`` of ``n_pieces``; ``tally`` counts the kept
        (``"tetrahedra"``), out-of-view (``"tetrahedra_out_of_view"``) and, in view, out-of-reach
        (``"tetrahedra_out_of_reach"``) ones."""
        for _, t in self.grid.pieces(n_pieces, first, last):
            t_long = t.long()
            keep = _in_view(t_long, self.seen)
            in_view = int(keep.sum())
            if self.grid.reach is not None:
                keep &= self.grid.reach[t_long].any(dim=1)
                tally["tetrahedra_out_of_reach"] = tally.get("tetrahedra_out_of_reach", 0) + in_view - int(keep.sum())
            tally["tetrahedra"] = tally.get("tetrahedra", 0) + int(keep.sum())
            tally["tetrahedra_out_of_view"] = tally.get("tetrahedra_out_of_view", 0) + t.shape[0] - in_view
            yield t[keep]


class _WholeTets:
    """A grid's tetrahedra held whole (the Delaunay grid's, already in view): its pieces are consecutive slices."""

    def __init__(self, tets):
        self.tets = tets

    def n_pieces(self, world: int) -> int:
        return world

    def pieces(self, n_pieces: int, first: int, last: int, tally: dict):
        bounds = even_split(len(self.tets), n_pieces)
        for k in range(first, last):
            tally["tetrahedra"] = tally.get("tetrahedra", 0) + bounds[k + 1] - bounds[k]
            yield self.tets[bounds[k]:bounds[k + 1]]


class SearchPlanner:
    """How many bisection steps each opacity-field call of the search serves (``steps_per_call`` of
    :func:`~gof_warp.mesh.marching.marching_tetrahedra`), from the field's own cost on this model and device.

    A field call costs a fixed part ``F`` (every view preprocesses and bins every Gaussian) and a part per point
    ``c`` (each point walks its tile's list in every view). ``d`` steps in one call evaluate ``2^d − 1`` points per
    edge, so the remaining ``r`` steps cost ``⌈r / d⌉ (F + c E (2^d − 1))`` for ``E`` edges. ``F`` and ``c`` are fitted
    from two calls that happen anyway: the field at the grid's ``P`` points (``grid_call``: points, seconds) and the
    search's first call (one step, ``E`` points); every later call takes the ``d`` with the least predicted cost.
    Many Gaussians and few edges (3M jittered Gaussians, 25k edges) make ``F`` dominate and ``d`` large; dense meshes
    keep ``d = 1``. Without a usable grid sample (none, or ``P < 2E``) or a usable fit (``c <= 0`` or ``F <= 0``: on the
    CPU, forked workers make the times noisy) every call is one step. After the first call of several steps the fit
    is made again from the search's own two calls, and the calls left follow it. With several ranks each rank's fit
    is gathered and the largest ``F`` and ``c`` used, so every rank makes the same calls. The vertices do
    not depend on ``d``; ``decisions`` records the fit and the steps of each call."""

    def __init__(self, field_fn, steps: int, device, ranks: Ranks, fixed: int = 0,
                 grid_call: tuple[int, float] | None = None):
        self._field, self.steps, self.ranks, self.fixed, self.grid_call = field_fn, steps, ranks, fixed, grid_call
        self._device = torch.device(str(device))
        self.timings: list[tuple[int, float]] = []  # (points, seconds) per search call
        self.decisions: dict = {"steps_per_call": []}

    def field(self, points):
        """The field, timed (synchronised) per call."""
        t0 = time.perf_counter()
        out = self._field(points)
        if self._device.type == "cuda":
            torch.cuda.synchronize(self._device)
        self.timings.append((int(len(points)), time.perf_counter() - t0))
        return out

    def __call__(self, n_edges: int, done: int) -> int:
        d = self._choose(n_edges, done)
        self.decisions["steps_per_call"].append(d)
        return d

    def _choose(self, n_edges: int, done: int) -> int:
        if self.fixed:
            return self.fixed
        if done == 0 or n_edges == 0 or self.grid_call is None or self.grid_call[0] < 2 * n_edges:
            return 1
        (p1, t1), (p_last, t_last) = self.timings[0], self.timings[-1]
        if "fixed_s" not in self.decisions:
            self._fit((p1, t1), self.grid_call, n_edges)
        elif p_last > p1 and self.decisions.get("refit_from") is None:
            # a call of several steps has run: fit again from the search's own two calls (same points, same field),
            # so a plan that the grid sample made too optimistic is corrected for the calls left
            self._fit((p1, t1), (p_last, t_last), n_edges)
            self.decisions["refit_from"] = [p_last, round(t_last, 4)]
        f, c, left = self.decisions["fixed_s"], self.decisions["per_point_s"], self.steps - done
        if c <= 0.0 or f <= 0.0:  # no usable fit (timing noise, forked CPU workers): one step a call
            return 1
        return min(range(1, min(left, MAX_STEPS_PER_CALL) + 1),
                   key=lambda d: (-(-left // d)) * (f + c * n_edges * ((1 << d) - 1)))

    def _fit(self, a: tuple[int, float], b: tuple[int, float], n_edges: int) -> None:
        """``F`` and ``c`` through two (points, seconds) samples, the largest over the ranks; ``c <= 0`` (the calls'
        times do not grow with their points) is kept as it is and means no usable fit."""
        (pa, ta), (pb, tb) = a, b
        c = (tb - ta) / (pb - pa)
        f = ta - c * pa
        every = self.ranks.all_gather_objects((f, c))  # the same plan on every rank
        f, c = max(e[0] for e in every), max(e[1] for e in every)
        self.decisions.update({"fixed_s": round(f, 4), "per_point_s": c, "edges": n_edges})


def _march(points, tets, values, config: MeshConfig, field_fn, ranks: Ranks, counts: dict,
           grid_call: tuple[int, float] | None = None) -> list:
    """Marching tetrahedra with the binary search: one ``(vertices, faces)`` per level, the search's field calls
    planned by :class:`SearchPlanner` from ``grid_call`` (points, seconds of the field at the grid points), recorded
    in ``counts["search"]``.

    ``tets``: :class:`_WholeTets` or :class:`_OctreePieces`. One piece in one process: marched and searched at once.
    Otherwise the pieces are marched one after another without the search (each holds only its own tetrahedra), each
    piece's crossing edges kept by key, and the search runs once on their union; with several ``ranks`` the marching
    is split by space (each rank marches its consecutive share of the pieces) and the search by views: every rank
    searches the union of the ranks' crossing edges with ``field_fn``, which evaluates its own views and reduces the
    minimum over the ranks at each call. A call's cost is mostly the per-view preparation of every Gaussian (3M
    Gaussians, 48 views: ~7 s a call on one H100, whatever the number of edges), so sharing the views is what divides
    it. The pieces are joined by edge key (on rank 0) into the mesh of every tetrahedron marched at once, bit for bit;
    the other ranks return their own pieces joined, with the searched vertices."""
    # automatic on CUDA only: on the 2-core CPU the README job's plan ([1, 3]) made the search slower than one step a
    # call (17.9 s against 13.3 s), its near-surface points costing far more than the grid's (the fit's sample)
    fixed = config.search_steps_per_call or (0 if points.device.type == "cuda" else 1)
    plan = SearchPlanner(field_fn, config.binary_steps, points.device, ranks, fixed=fixed, grid_call=grid_call)
    n_pieces, tally = tets.n_pieces(ranks.world), {}
    first, last = ranks.my_range(n_pieces)
    if n_pieces == 1:
        meshes = marching_tetrahedra(points, next(tets.pieces(1, 0, 1, tally)), values, plan.field,
                                     levels=config.levels, binary_steps=config.binary_steps, oriented=True,
                                     steps_per_call=plan)
    else:
        pieces = [marching_tetrahedra(points, t, values, None, levels=config.levels, binary_steps=0, oriented=True,
                                      return_keys=True) for t in tets.pieces(n_pieces, first, last, tally)]
        mine = [distinct(np.concatenate([p[level][2] for p in pieces] + [np.zeros(0, np.int64)]))
                for level in range(len(config.levels))]
        every = ranks.all_gather_objects(mine)  # each rank's edge keys, per level
        keys = [distinct(np.concatenate([e[level] for e in every])) for level in range(len(config.levels))]
        vertices = search_edges(points, values, keys, plan.field, levels=config.levels,
                                binary_steps=config.binary_steps, steps_per_call=plan)
        pieces = [[(vertices[level][np.searchsorted(keys[level], k)], f, k) for level, (_, f, k) in enumerate(p)]
                  for p in pieces]
        gathered = [p for rank_pieces in ranks.gather_to_main(pieces) or [] for p in rank_pieces]
        own = gathered if ranks.is_main else pieces  # rank 0: every rank's pieces; the others: their own
        meshes = [merge_keyed_pieces([p[level] for p in own]) for level in range(len(config.levels))]
    counts["search"] = {**plan.decisions, "calls": len(plan.timings)}
    tallies = ranks.all_gather_objects(tally)  # what each rank marched (and, octree, left out of view or reach)
    for name in ("tetrahedra", "tetrahedra_out_of_view", "tetrahedra_out_of_reach"):
        if name in tally:
            counts[name] = sum(t.get(name, 0) for t in tallies)
    counts["pieces"] = n_pieces
    if ranks.active:
        counts["tetrahedra_per_rank"] = [t.get("tetrahedra", 0) for t in tallies]
    return meshes


def extract_mesh(gaussians, cameras: list[Camera], config: MeshConfig | None = None, *,
                 render_config: RenderConfig | None = None, views=None, timer: StageTimer | None = None,
                 grid_cache: dict | None = None, ranks=None):
    """Extract one mesh per level from trained Gaussians.

    Args:
        gaussians: :class:`~gof_warp.core.model.Gaussians` (on the device to compute on).
        cameras: the training cameras (the opacity field is the minimum over them).
        views: :class:`~gof_warp.core.scene.View` list for TSDF masks (optional; cameras alone otherwise).
        grid_cache: a dict kept by the caller for one model (the same ``gaussians``, cameras and render settings):
            the tetra path stores its grid there (points, field values, tetrahedra) and a later call with the same
            grid settings (tetra config, field config, and the levels when the band is on) reuses it, so extractions
            that differ only in search steps, levels or decimation build it once. ``timer.stages["grid_shared"]``
            says so, with the seconds the grid took when it was built. The check for cameras inside the solid
            (:func:`~gof_warp.rendering.opacity_field.cameras_inside_surfaces`) runs once per cache too.
        ranks: a :class:`~gof_warp.training.distributed.Ranks` of several processes (``torchrun``; every rank calls this
            with the same model and cameras). Tetra path: the field at the grid points is shared out by views, the
            Delaunay runs on rank 0 and is broadcast (the octree grid is built alike on every rank), and the
            marching is split by space, each rank marching its share of the tetrahedra (the pieces joined on rank 0
            into the one-process mesh), and the binary search by views (every rank searches every crossing edge
            over its views, the minimum reduced per field call). Cubes: each field evaluation is shared out by views. The
            post-processing (hidden faces, crop, components, decimation) runs on rank 0 only; the other ranks return
            their raw meshes (their pieces, on the tetra path). TSDF fusion is not shared out (every rank fuses every view).
    Returns:
        list of ``(vertices [V, 3] float32, faces [F, 3] int32)``, one per ``config.levels``.
    """
    from .marching import marching_cubes
    from ..core.scene import View

    config = config or MeshConfig()
    config.validate()
    ranks = Ranks.single() if ranks is None else ranks
    render_config = render_config or RenderConfig()
    timer = timer or StageTimer(gaussians.device)
    if len(gaussians) == 0:
        raise GofError("the model has no Gaussians: nothing to extract")
    gaussians = meshable(gaussians)
    # a camera inside the solid gets a cavity carved around it: say so before the work (once per model and cameras)
    if ranks.is_main and (grid_cache is None or "cameras_inside" not in grid_cache):
        with timer("cameras_inside"):
            inside = cameras_inside_surfaces(gaussians, cameras, render_config=render_config)
        timer.stages["cameras_inside"]["cameras"] = [c.name for c in inside]
        if grid_cache is not None:
            grid_cache["cameras_inside"] = inside
        if inside:
            log.warning("warning: %s", cameras_inside_message(inside, len(cameras)))

    def field_fn(points, field_config=config.field):
        ranks.check_same_points(points, "opacity field")
        return opacity_field(gaussians, cameras, points, config=field_config, render_config=render_config,
                             ranks=ranks)

    meshes = []
    if config.method == "tetra":
        tc = config.tetra
        key = ("tetra", repr(tc), repr(config.field), tuple(config.levels) if tc.band else None)
        cached = grid_cache.get(key) if grid_cache is not None else None
        if cached is not None:
            points, values, tets, counts = cached["points"], cached["values"], cached["tets"], dict(cached["counts"])
            timer.stages["grid_shared"] = {"built_s": cached["built_s"]}
        else:
            t_grid = time.perf_counter()
            points, values, tets, counts = _tetra_grid(gaussians, cameras, config, tc, field_fn, timer, ranks)
            counts["grid_field_call"] = [counts["points"], timer.stages["opacity_field"]["time_s"]]
            if grid_cache is not None:
                grid_cache[key] = {"points": points, "values": values, "tets": tets, "counts": counts,
                                   "built_s": round(time.perf_counter() - t_grid, 4)}
        if tets is None:  # nothing crosses a level: an empty mesh (the CLI refuses to write it)
            meshes = [(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64)) for _ in config.levels]
        else:
            with timer("marching_tetrahedra"):
                meshes = _march(torch.as_tensor(points, device=gaussians.device), tets, values, config, field_fn,
                                ranks, counts, grid_call=tuple(counts["grid_field_call"]))
        timer.stages["counts"] = counts
    elif config.method == "cubes":
        from .tsdf import scene_bounds

        box = np.asarray(config.crop, float) if config.crop is not None else scene_bounds(
            gaussians, cameras, near=render_config.near)
        size = box[3:] - box[:3]
        if box.shape != (6,) or not np.all(np.isfinite(box)) or not np.all(size > 0):
            raise GofError(f"marching cubes: the grid box must be 6 finite numbers with max > min, got {box.tolist()}")
        res = tuple(int(max(2, round(config.cubes_resolution * s / size.max()))) for s in size)
        for level in config.levels:
            with timer(f"marching_cubes@{level}"):
                # a dense grid reaches space no camera sees: count it as empty there (GOF's "unseen = 1" is
                # meant for tetra points, which the frustum mask already keeps in view; on a grid it builds
                # walls at the frustum boundaries)
                grid_field = dataclasses.replace(config.field, unseen_value=0.0)
                meshes.append(marching_cubes(lambda p: field_fn(p, grid_field).cpu().numpy(), np.stack([box[:3], box[3:]]), res,
                                             level=level, binary_steps=config.binary_steps))
    else:
        views = views or [View(camera=c, image=np.zeros((c.height, c.width, 3), np.uint8), name=c.name) for c in cameras]
        with timer("tsdf_fusion"):
            volume = fuse_tsdf(gaussians, views, config.tsdf, render_config)
        with timer("tsdf_marching_cubes"):
            v, f, _ = extract_tsdf_mesh(volume, binary_steps=config.binary_steps)
        meshes = [(v, f)]
    if not ranks.is_main:  # rank 0 post-processes and writes
        return meshes
    meshes = [(np.asarray(v, np.float32), np.asarray(f, np.int64)) for v, f in meshes]
    if config.drop_hidden:
        with timer("hidden_faces"):
            seen = [faces_seen(v, f, cameras, near=render_config.near, device=gaussians.device) for v, f in meshes]
            meshes = [(v, f[s]) for (v, f), s in zip(meshes, seen)]
        timer.stages["hidden_faces"]["dropped"] = [int((~s).sum()) for s in seen]
    meshes = [_postprocess(v, f, config) for v, f in meshes]
    if config.max_faces is not None or config.max_error is not None:
        from .decimate import decimate

        out, infos = [], []
        with timer("decimate"):
            for v, f in meshes:
                if len(f) == 0:
                    out.append((v, f))
                    continue
                v, f, info = decimate(v, f, max_faces=config.max_faces, max_error=config.max_error,
                                      measure=config.max_error is not None)
                out.append((v, f.astype(np.int64)))
                infos.append(info)
        timer.stages["decimate"]["meshes"] = infos
        meshes = out
    return meshes


def save_mesh(path, verts: np.ndarray, faces: np.ndarray) -> None:
    """Write a triangle mesh as binary PLY (float32 vertices, int32 indices), atomically."""
    from ..core.ply import write_ply_mesh

    write_ply_mesh(path, verts, faces)


