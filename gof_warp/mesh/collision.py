"""A closed triangle mesh of the opacity field for physics and printing: :func:`collision_mesh`.

The extraction's mesh (:mod:`gof_warp.mesh.extraction`) drops the faces no training camera sees, so it is open
where no photo looks. A collision mesh must be solid, so it is made differently, rather than by filling the extraction's
holes (which would have to invent surface over openings of any size and shape, in a mesh whose tetrahedral grid does
not reach space no Gaussian covers): a dense grid whose border is empty gives a surface closed by construction.

1. **Field on a grid.** The opacity field (:func:`gof_warp.rendering.opacity_field.opacity_field`) is evaluated on
   a regular grid over the box the Gaussians occupy (:func:`gof_warp.mesh.tsdf.scene_bounds`, or
   ``CollisionConfig.bounds``), ``resolution`` cells along its longest side. It is sampled adaptively
   (:func:`sample_grid_adaptive`): first every ``coarse_factor``-th node; then exactly at every fine node of the
   coarse cells whose corners straddle the level or that hold a Gaussian's centre, and of their neighbours; every
   other fine node takes the trilinear interpolation of its coarse cell's corners, which all lie on one side of the
   level, so no surface is made there. The Gaussians' centres find the parts thinner than a coarse cell that no
   coarse node falls in (a rod, a wire); a surface more than one coarse cell from every centre and every crossing
   cell would still be missed (``coarse_factor=1``: dense sampling, no such loss).
2. **Unseen space.** A point seen by fewer than ``min_views`` training views is *empty* (field 0): nothing claims
   solid matter there. A point the views do see gets GOF's field, the minimum over those views of the opacity
   accumulated along the view's ray up to it; space that every view sees only through the object (its inside,
   the underside of a half-seen object, the gap behind it that no photo looks into) therefore counts as solid,
   and the surface closes around it. That is what closes the extraction's open regions: no face is dropped.
3. **Closed at the box.** The grid is padded by one node of value 0 on every side, so marching cubes (Warp's
   ``IsoSurfaceMarchingCubes``, one vertex per crossing grid edge, linear placement) closes every surface that
   reaches the box on the box's faces. Warp's case table shares each crossing edge's vertex between the cubes
   that meet there, so every edge of its output bounds exactly two faces, wound from inside (high opacity) to
   outside. Where the solid reaches the box, the surface lies between the last grid node and the padding, within
   one cell outside the box.
4. **Pieces.** Connected pieces (by shared edges) whose signed volume is not positive (the walls of internal
   voids, which are filled) or below ``min_component_fraction`` of the largest piece's volume (floaters) are
   removed.
5. **Face budget.** Quadric decimation (:func:`gof_warp.mesh.decimate.decimate`, ``fast-simplification``) to
   ``max_faces``. Collapses can break closedness; the result is checked (:func:`closed_report`: trimesh's
   ``is_watertight``, ``is_winding_consistent`` and ``is_volume``). When the check fails, ``trimesh.repair``
   (normals, holes) is tried, and if that fails too, the mesh is remade by marching cubes on every ``k``-th grid
   node for the smallest ``k`` that meets the budget, which is closed by construction and needs no decimation
   (``info["route"]`` names which of the three was kept; a warning says when none passes). The pieces rule of step 4
   runs again after decimation (a collapse can pinch a thin part off as a sliver). Where decimation made two parts of
   the surface touch, :func:`~gof_warp.mesh.decimate.decimate` splits the shared vertex
   (``info["decimate"]["pinch_vertices_split"]``): every edge still bounds two faces, but the solid touches itself
   there.

The surface sits on the 0.5 level (``level``) to within the linear interpolation along one grid edge: at most
one cell, much less where the field is smooth.

Cost: one opacity-field evaluation per sampled node (the coarse nodes plus the band of fine ones), then marching
cubes and decimation over the dense grid (4 B/node values, Warp's extraction about 44 B/node).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..core.errors import GofError

log = logging.getLogger(__name__)

MAX_RESOLUTION = 1024  # cells along the longest side: 1025^3 nodes are 4.3 GB of float32 values


@dataclass
class CollisionConfig:
    """Settings of :func:`collision_mesh` (see the module docstring for what each step does)."""

    resolution: int = 128  # grid cells along the longest side of the box
    coarse_factor: int = 4  # fine cells per coarse cell of the adaptive sampling (1: evaluate every node)
    level: float = 0.5  # the opacity level of the surface
    max_faces: int | None = 20_000  # face budget (None: no decimation)
    min_component_fraction: float = 0.01  # drop pieces enclosing less than this fraction of the largest's volume
    min_views: int = 1  # fewer training views than this see a point: it is empty space
    bounds: tuple[float, ...] | None = None  # (xmin, ymin, zmin, xmax, ymax, zmax); None: the Gaussians' box

    def validate(self) -> None:
        def integer(x):
            return isinstance(x, (int, np.integer)) and not isinstance(x, bool)

        if not integer(self.resolution) or not 2 <= self.resolution <= MAX_RESOLUTION:
            raise GofError(f"collision resolution must be an integer in [2, {MAX_RESOLUTION}] (grid cells along the "
                           f"longest side), got {self.resolution!r}")
        if not integer(self.coarse_factor) or not 1 <= self.coarse_factor <= 16:
            raise GofError(f"collision coarse_factor must be an integer in [1, 16], got {self.coarse_factor!r}")
        if not 0.0 < float(self.level) < 1.0:
            raise GofError(f"collision level must be an opacity in (0, 1), got {self.level!r}")
        if self.max_faces is not None and (not integer(self.max_faces) or self.max_faces < 4):
            raise GofError(f"collision max_faces must be an integer >= 4 (or None), got {self.max_faces!r}")
        if not 0.0 <= float(self.min_component_fraction) <= 1.0:
            raise GofError("collision min_component_fraction must be in [0, 1], got "
                           f"{self.min_component_fraction!r}")
        if not integer(self.min_views) or self.min_views < 1:
            raise GofError(f"collision min_views must be an integer >= 1, got {self.min_views!r}")
        if self.bounds is not None:
            b = np.asarray(self.bounds, float)
            if b.shape != (6,) or not np.all(np.isfinite(b)) or not np.all(b[3:] > b[:3]):
                raise GofError(f"collision bounds must be 6 finite numbers (min xyz, max xyz) with max > min, "
                               f"got {self.bounds!r}")


# ------------------------------------------------------------------------------------------------ grid
def grid_spec(bounds, resolution: int) -> tuple[np.ndarray, float, tuple[int, int, int]]:
    """``(lower [3] float64, spacing, shape)`` of a grid of cubic cells covering ``bounds`` (6 numbers) with
    ``resolution`` cells along the longest side; node ``(i, j, k)`` lies at ``lower + spacing * (i, j, k)``. The
    grid is centred on the box (the other sides are rounded up to whole cells)."""
    b = np.asarray(bounds, np.float64)
    size = b[3:] - b[:3]
    spacing = float(size.max()) / int(resolution)
    cells = np.maximum(1, np.ceil(size / spacing - 1e-9)).astype(int)
    lower = (b[:3] + b[3:]) / 2 - cells * spacing / 2
    return lower, spacing, tuple(int(c) + 1 for c in cells)


def _node_points(lower, spacing, idx: np.ndarray) -> np.ndarray:
    return (np.asarray(lower, np.float64) + spacing * idx.astype(np.float64)).astype(np.float32)


def sample_grid_adaptive(field: Callable[[np.ndarray], np.ndarray], lower, spacing: float, shape, *,
                         coarse_factor: int = 4, level: float = 0.5, seed_points=None) -> tuple[np.ndarray, dict]:
    """Values ``[nx, ny, nz]`` float32 of ``field`` at the nodes of a grid, evaluated exactly near the level only.

    Args:
        field: ``[M, 3]`` float32 points → ``[M]`` values (numpy-convertible).
        lower, spacing, shape: the grid (:func:`grid_spec`).
        coarse_factor: ``c``; the field is first evaluated at every ``c``-th node (and the last one on each axis),
            then at every node of the coarse cells whose corners straddle ``level`` and of their 26 neighbours.
            The remaining nodes take the trilinear interpolation of their coarse cell's corners, which all lie on
            one side of ``level``. ``c = 1``: every node evaluated.
        level: the level the refinement looks for.
        seed_points: optional ``[S, 3]`` world points whose coarse cells (and their neighbours) are refined too,
            whatever their corners say: a part thinner than a coarse cell that no coarse node falls in is found
            through them (:func:`collision_mesh` passes the Gaussians' centres).

    Returns:
        ``(values, info)``: ``info`` with ``nodes`` (all), ``evaluated`` (field calls' points).
    """
    from scipy import ndimage

    shape = tuple(int(s) for s in shape)
    n_all = int(np.prod(shape))

    def call(idx):
        v = np.asarray(field(_node_points(lower, spacing, idx)), np.float32).reshape(-1)
        if v.shape[0] != idx.shape[0]:
            raise GofError(f"the field returned {v.shape[0]} values for {idx.shape[0]} points")
        return v

    if coarse_factor <= 1 or min(shape) <= 2:
        idx = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).reshape(-1, 3)
        return call(idx).reshape(shape), {"nodes": n_all, "evaluated": n_all}
    axes = [np.unique(np.append(np.arange(0, s, coarse_factor), s - 1)) for s in shape]
    cidx = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    coarse = call(cidx).reshape(tuple(len(a) for a in axes))
    inside = coarse >= np.float32(level)
    # coarse cells whose 8 corners are not all on one side
    corners = [inside[i:i + inside.shape[0] - 1, j:j + inside.shape[1] - 1, k:k + inside.shape[2] - 1]
               for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    crossing = np.logical_or.reduce(corners) & ~np.logical_and.reduce(corners)
    seeded = np.zeros_like(crossing)
    if seed_points is not None and len(seed_points):
        # the coarse cell of each point: the last coarse node at or below its fine index, per axis
        fine = (np.asarray(seed_points, np.float64) - np.asarray(lower, np.float64)) / spacing
        ok = np.all((fine >= 0) & (fine <= np.asarray(shape) - 1), axis=1)
        cell = np.stack([np.clip(np.searchsorted(ax, fine[ok, d], side="right") - 1, 0, len(ax) - 2)
                         for d, ax in enumerate(axes)], -1)
        seeded[tuple(cell.T)] = True
    band = ndimage.binary_dilation(crossing | seeded, structure=np.ones((3, 3, 3), bool))
    # every fine node from trilinear interpolation of the coarse values (coarse nodes are exact)
    fine_pos = [np.interp(np.arange(s), a, np.arange(len(a))) for s, a in zip(shape, axes)]
    mesh_pos = np.meshgrid(*fine_pos, indexing="ij")
    values = ndimage.map_coordinates(coarse, mesh_pos, order=1, mode="nearest").astype(np.float32)
    # the fine nodes of the band's cells, evaluated exactly
    need = np.zeros(shape, bool)
    for ci, cj, ck in np.argwhere(band):
        need[axes[0][ci]:axes[0][ci + 1] + 1, axes[1][cj]:axes[1][cj + 1] + 1, axes[2][ck]:axes[2][ck + 1] + 1] = True
    on_coarse = [np.isin(np.arange(s), a) for s, a in zip(shape, axes)]  # the coarse nodes are known already
    need &= ~(on_coarse[0][:, None, None] & on_coarse[1][None, :, None] & on_coarse[2][None, None, :])
    idx = np.argwhere(need)
    if len(idx):
        values[tuple(idx.T)] = call(idx)
    return values, {"nodes": n_all, "evaluated": int(len(cidx) + len(idx)),
                    "coarse_cells_crossing": int(crossing.sum()), "coarse_cells_seeded": int(seeded.sum()),
                    "coarse_cells_refined": int(band.sum())}


def _padded(values: np.ndarray) -> np.ndarray:
    """``values`` with one node of 0 (empty) added on every side: every surface closes at the box."""
    return np.pad(np.asarray(values, np.float32), 1, mode="constant", constant_values=0.0)


def marching_cubes_closed(values: np.ndarray, lower, spacing: float, level: float = 0.5,
                          device: str = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes (Warp's ``IsoSurfaceMarchingCubes``) on ``values [nx, ny, nz]`` (node ``(i, j, k)`` at
    ``lower + spacing * (i, j, k)``) padded by one empty node on every side, so the surface is closed.

    Returns:
        ``(vertices [V, 3] float32, faces [F, 3] int64)``, inside = ``value >= level``, wound outwards.
    """
    import warp as wp
    import warp.geometry

    wp.init()
    grid = _padded(values)
    lo = np.asarray(lower, np.float64) - spacing
    hi = lo + spacing * (np.asarray(grid.shape, np.float64) - 1)
    verts, tris = warp.geometry.IsoSurfaceMarchingCubes.extract(
        wp.array(grid, dtype=wp.float32, device=device), float(level), lower=wp.vec3(*lo.astype(np.float32)),
        upper=wp.vec3(*hi.astype(np.float32)))
    v = verts.numpy().reshape(-1, 3).astype(np.float32)
    f = tris.numpy().reshape(-1, 3)[:, [0, 2, 1]].astype(np.int64)  # Warp winds toward high values
    return v, f


# ------------------------------------------------------------------------------------------ mesh checks
def signed_volume(verts, faces) -> float:
    """Signed enclosed volume of a closed triangle mesh (positive when wound outwards)."""
    v = np.asarray(verts, np.float64)
    f = np.asarray(faces, np.int64)
    if len(f) == 0:
        return 0.0
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def closed_report(verts, faces) -> dict:
    """trimesh's checks of a mesh meant to be solid: ``watertight`` (every edge bounds exactly two faces),
    ``winding_consistent``, ``is_volume`` (both, finite and a positive volume), ``volume``, ``components``."""
    import trimesh

    m = trimesh.Trimesh(np.asarray(verts, np.float64), np.asarray(faces, np.int64), process=False)
    if len(m.faces) == 0:
        return {"watertight": False, "winding_consistent": False, "is_volume": False, "volume": 0.0,
                "components": 0, "faces": 0, "vertices": int(len(m.vertices))}
    labels = trimesh.graph.connected_component_labels(m.face_adjacency, node_count=len(m.faces))
    return {"watertight": bool(m.is_watertight), "winding_consistent": bool(m.is_winding_consistent),
            "is_volume": bool(m.is_volume), "volume": float(m.volume), "components": int(labels.max() + 1),
            "faces": int(len(m.faces)), "vertices": int(len(m.vertices))}


def is_solid(report: dict) -> bool:
    """Whether :func:`closed_report` says the mesh bounds a volume."""
    return bool(report["watertight"] and report["winding_consistent"] and report["is_volume"])


def keep_solid_pieces(verts, faces, min_fraction: float = 0.01) -> tuple[np.ndarray, np.ndarray, dict]:
    """The connected pieces (by shared edges) of ``faces`` with a positive signed volume of at least
    ``min_fraction`` of the largest one's; drops the walls of internal voids (negative volume) and floaters.
    Returns ``(verts, faces, info)`` compacted; ``info``: ``pieces_before``, ``pieces_kept``, ``voids_filled``."""
    import trimesh

    from .marching import compact_mesh

    v = np.asarray(verts, np.float32)
    f = np.asarray(faces, np.int64)
    if len(f) == 0:
        return v, f, {"pieces_before": 0, "pieces_kept": 0, "voids_filled": 0}
    labels = trimesh.graph.connected_component_labels(trimesh.graph.face_adjacency(f), node_count=len(f))
    a, b, c = (v[f[:, i]].astype(np.float64) for i in range(3))
    vol = np.bincount(labels, np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0)
    keep = (vol > 0) & (vol >= min_fraction * max(float(vol.max()), 0.0))
    out_v, out_f, _ = compact_mesh(v, f[keep[labels]])
    return out_v, np.asarray(out_f, np.int64), {"pieces_before": int(len(vol)), "pieces_kept": int(keep.sum()),
                                                "voids_filled": int((vol < 0).sum())}


def _repaired(verts, faces) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    m = trimesh.Trimesh(np.asarray(verts, np.float64), np.asarray(faces, np.int64), process=True)
    trimesh.repair.fix_normals(m)
    trimesh.repair.fill_holes(m)
    trimesh.repair.fix_winding(m)
    return np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int64)


# ------------------------------------------------------------------------------------------ the mesh
def closed_mesh_from_grid(values: np.ndarray, lower, spacing: float, config: CollisionConfig | None = None
                          ) -> tuple[np.ndarray, np.ndarray, dict]:
    """Steps 3–5 of the module docstring on sampled values: a closed mesh of ``values >= config.level``.

    Args:
        values: ``[nx, ny, nz]`` field values at the nodes ``lower + spacing * (i, j, k)``; the space outside the
            grid counts as empty.
        config: ``level``, ``max_faces``, ``min_component_fraction`` are used.

    Returns:
        ``(vertices [V, 3] float32, faces [F, 3] int64, info)``; ``info``: ``route`` (``"marching_cubes"`` when no
        decimation was needed, ``"decimated"``, ``"repaired"`` or ``"coarser_grid_<k>"``), ``marching_cubes_faces``,
        ``pieces`` (:func:`keep_solid_pieces`), ``check`` (:func:`closed_report` of the result), ``solid``.
    """
    from .decimate import decimate

    config = config or CollisionConfig()
    level = float(config.level)
    v, f = marching_cubes_closed(values, lower, spacing, level)
    info: dict = {"marching_cubes_faces": int(len(f))}
    v, f, info["pieces"] = keep_solid_pieces(v, f, config.min_component_fraction)
    budget = config.max_faces
    if budget is None or len(f) <= budget:
        check = closed_report(v, f)
        return v, f, {**info, "route": "marching_cubes", "check": check, "solid": is_solid(check)}
    dv, df, dinfo = decimate(v, f, max_faces=int(budget), measure=False)
    info["decimate"] = {k: dinfo[k] for k in ("faces_after", "time_s", "coincident_removed", "pinch_vertices_split")}
    # a collapse can pinch a thin part off into a sliver shell of its own: the same rule drops it
    dv, df, info["decimate"]["pieces"] = keep_solid_pieces(dv, df, config.min_component_fraction)
    check = closed_report(dv, df)
    if is_solid(check):
        return dv, np.asarray(df, np.int64), {**info, "route": "decimated", "check": check, "solid": True}
    info["decimated_check"] = check
    rv, rf = _repaired(dv, df)
    check = closed_report(rv, rf)
    if is_solid(check) and len(rf) <= budget:
        log.warning("collision mesh: decimation broke closedness; trimesh.repair closed it")
        return rv, rf, {**info, "route": "repaired", "check": check, "solid": True}
    info["repaired_check"] = check
    # marching cubes on every k-th node: closed by construction, no decimation
    values = np.asarray(values, np.float32)
    for k in range(2, max(values.shape) + 1):
        sub = values[::k, ::k, ::k]
        cv, cf = marching_cubes_closed(sub, lower, spacing * k, level)
        cv, cf, pieces = keep_solid_pieces(cv, cf, config.min_component_fraction)
        if len(cf) <= budget:
            check = closed_report(cv, cf)
            log.warning("collision mesh: decimation did not stay closed; marching cubes on every %d-th grid node "
                        "instead (%d faces)", k, len(cf))
            return cv, cf, {**info, "route": f"coarser_grid_{k}", "coarse_pieces": pieces, "check": check,
                            "solid": is_solid(check)}
    check = closed_report(dv, df)
    log.warning("collision mesh: no closed mesh within %d faces; returning the decimated one (not closed)", budget)
    return dv, np.asarray(df, np.int64), {**info, "route": "decimated", "check": check, "solid": False}


def collision_mesh(gaussians, cameras, config: CollisionConfig | None = None, *, render_config=None,
                   field: Callable[[np.ndarray], np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """A closed, consistently wound triangle mesh of the Gaussians' opacity field at ``config.level``.

    Args:
        gaussians: :class:`~gof_warp.core.model.Gaussians` (any device; the field is evaluated there).
        cameras: the training cameras (:class:`~gof_warp.core.camera.Camera` list): the field is the minimum over
            the views that see a point; a point fewer than ``config.min_views`` see is empty space.
        config: :class:`CollisionConfig`.
        render_config: the renderer's settings (near plane, alpha thresholds) for the field.
        field: instead of the opacity field, any ``[M, 3]`` float32 points → ``[M]`` values callable
            (``gaussians`` then only bounds the grid unless ``config.bounds`` is given, and seeds the refinement;
            tests use analytic fields).

    Returns:
        ``(vertices [V, 3] float32, faces [F, 3] int64, info)``: ``info`` as :func:`closed_mesh_from_grid`'s,
        plus ``bounds``, ``grid`` (``shape``, ``spacing``), ``sampling`` (:func:`sample_grid_adaptive`),
        ``time_s`` per stage.
    """
    from ..rendering.opacity_field import OpacityFieldConfig, opacity_field
    from ..rendering.render import RenderConfig
    from .extraction import meshable
    from .tsdf import scene_bounds

    config = config or CollisionConfig()
    config.validate()
    render_config = render_config or RenderConfig()
    t0 = time.perf_counter()
    if config.bounds is not None:
        box = np.asarray(config.bounds, np.float64)
    else:
        if gaussians is None or len(gaussians) == 0:
            raise GofError("collision mesh: no Gaussians to bound the grid (give CollisionConfig.bounds)")
        gaussians = meshable(gaussians)
        box = scene_bounds(gaussians, cameras, near=render_config.near)
    if field is None:
        if not cameras:
            raise GofError("collision mesh: the opacity field needs the training cameras")
        if config.min_views > len(cameras):
            raise GofError(f"collision mesh: min_views {config.min_views}, but there are {len(cameras)} cameras: "
                           "no space would be solid")
        if config.bounds is not None:
            gaussians = meshable(gaussians)
        field_config = OpacityFieldConfig(unseen_value=0.0, min_views=config.min_views)

        def field(points):
            return opacity_field(gaussians, cameras, points, config=field_config,
                                 render_config=render_config).cpu().numpy()

    lower, spacing, shape = grid_spec(box, config.resolution)
    seeds = None if gaussians is None or len(gaussians) == 0 else gaussians.means.detach().cpu().numpy()
    values, sampling = sample_grid_adaptive(field, lower, spacing, shape, coarse_factor=config.coarse_factor,
                                            level=config.level, seed_points=seeds)
    t1 = time.perf_counter()
    v, f, info = closed_mesh_from_grid(values, lower, spacing, config)
    t2 = time.perf_counter()
    if len(f) == 0:
        raise GofError(f"collision mesh: the field does not reach the level {config.level:g} anywhere in the box "
                       f"{np.round(box, 4).tolist()}: no solid to mesh")
    if not info["solid"]:
        log.warning("warning: the collision mesh is not closed: %s", info["check"])
    info.update(bounds=[float(x) for x in box], grid={"shape": list(shape), "spacing": spacing},
                sampling=sampling, time_s={"field": round(t1 - t0, 3), "mesh": round(t2 - t1, 3),
                                           "total": round(t2 - t0, 3)},
                config=dataclasses.asdict(config))
    return v, f, info
