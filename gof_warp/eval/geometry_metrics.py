"""Mesh metrics: accuracy, completeness, Chamfer, precision/recall/F-score, mesh statistics.

Definitions (``pred`` = the reconstruction, ``gt`` = the ground truth; both meshes or point clouds):

* Both are turned into points by :func:`sample_surface`: uniform, area-weighted random samples with
  mean spacing ``density`` (one sample per ``density^2`` of area, like DTU's ``downsample_density``);
  a point cloud is used as it is.
* ``d(p -> Q)`` is the distance from a point to the other side. ``method="points"`` (default,
  DTU-style) takes the nearest *sample* of the other side (``scipy.spatial.cKDTree``); this is biased
  upward by about ``density / 2`` even for coincident surfaces, so use a ``density`` well below the
  accuracy you want to resolve. ``method="triangles"`` takes the exact distance to the other side's
  triangles (:func:`point_mesh_distance`; point clouds fall back to samples).
* accuracy = mean over pred samples of ``d(p -> gt)``; completeness = mean over gt samples of
  ``d(g -> pred)``; Chamfer = their mean. Truncation at ``max_dist``: ``truncate="exclude"`` drops
  distances ``>= max_dist`` from the mean, exactly as DTU's evaluation (official MATLAB and
  DTUeval-python) does -- the dropped fraction is reported as ``*_outlier_fraction``;
  ``truncate="clamp"`` replaces them by ``max_dist``. Medians use the raw distances.
* precision(tau) = fraction of pred samples with ``d < tau``; recall(tau) = fraction of gt samples with
  ``d < tau``; F = 2PR / (P + R), 0 when both are 0 (Tanks and Temples).
* ``crop``: an axis-aligned box ``(min_xyz, max_xyz)`` (inclusive) or a function ``[N, 3] -> bool [N]``
  selects which samples are *scored* on both sides; their nearest neighbours are searched among all
  samples of the other side, so the box's edge does not create false errors (as in DTU, which crops
  the queries but not the search set).
* An empty side (no faces and no points, or nothing left after the crop) gives infinite distances and
  precision = recall = F = 0.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..core.arrays import distinct
from ..core.errors import GofError
from ..core.orientation import world_from_file

log = logging.getLogger(__name__)

DEFAULT_GT_SAMPLES = 300_000  # default density aims at this many GT samples (seconds on 2 CPU cores)
MAX_SAMPLES = 2_000_000  # per side; above it the spacing is widened (warning) to bound memory (~50 MB)
DEFAULT_TAU_FRACTIONS = (0.005, 0.01)  # of the GT bounding-box diagonal
DEFAULT_MAX_DIST_FRACTION = 0.05  # of the GT diagonal; DTU's 20 mm is ~5% of its ~400 mm objects


# ----------------------------------------------------------------------------- inputs
def load_geometry(path) -> trimesh.Trimesh | trimesh.PointCloud:
    """Read a mesh or point cloud (PLY, OBJ, STL, OFF, ...) as stored (no vertex merging), in the scene's frame (a
    GLB or OBJ written upright is turned back: :func:`gof_warp.core.orientation.world_from_file`)."""
    p = Path(path)
    if not p.is_file():
        raise GofError(f"mesh file {p} does not exist")
    try:
        geom = trimesh.load(p, process=False)
    except Exception as e:  # trimesh raises many types for bad files
        raise GofError(f"cannot read mesh file {p}: {e}") from None
    if isinstance(geom, trimesh.Scene):
        parts = list(geom.dump()) if geom.geometry else []
        meshes = [g for g in parts if isinstance(g, trimesh.Trimesh)]
        geom = trimesh.util.concatenate(meshes) if meshes else trimesh.Trimesh()
    if not isinstance(geom, (trimesh.Trimesh, trimesh.PointCloud)):
        raise GofError(f"mesh file {p} holds a {type(geom).__name__}, not a triangle mesh or point cloud")
    back = world_from_file(p)  # a GLB/OBJ extract wrote upright: scored in the scene's frame
    if back is not None:
        geom.vertices = np.asarray(geom.vertices, np.float64) @ back.T
    return geom


def _parts(geom) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices [V, 3] float64, faces [F, 3] int64)`` of a mesh, point cloud, ``[N, 3]`` array, path or
    ``(vertices, faces)`` tuple; faces are empty for point clouds."""
    if isinstance(geom, (str, Path)):
        geom = load_geometry(geom)
    if isinstance(geom, tuple) and len(geom) == 2:
        v, f = np.asarray(geom[0], np.float64), np.asarray(geom[1], np.int64)
    elif isinstance(geom, trimesh.Trimesh):
        v, f = np.asarray(geom.vertices, np.float64), np.asarray(geom.faces, np.int64)
    elif isinstance(geom, trimesh.PointCloud):
        v, f = np.asarray(geom.vertices, np.float64), None
    else:
        v, f = np.asarray(geom, np.float64), None
    v = v.reshape(-1, 3) if v.size == 0 else v
    if v.ndim != 2 or v.shape[1] != 3:
        raise GofError(f"expected a mesh, a point cloud or [N, 3] points, got an array of shape {v.shape}")
    if v.size and not np.isfinite(v).all():
        raise GofError(f"{int((~np.isfinite(v).all(axis=1)).sum())} vertices have NaN/inf coordinates")
    f = np.zeros((0, 3), np.int64) if f is None else f.reshape(-1, 3)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise GofError(f"mesh faces index vertices outside [0, {len(v)})")
    return v, f


def _triangle_areas(tri: np.ndarray) -> np.ndarray:
    """``tri [F, 3, 3]`` -> ``[F]`` areas."""
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def sample_surface(geom, density: float | None = None, count: int | None = None, seed: int = 0,
                   max_samples: int = MAX_SAMPLES) -> np.ndarray:
    """Uniform area-weighted random points on a mesh's triangles, ``[N, 3]`` float64.

    Give exactly one of ``density`` (mean spacing: ``N = ceil(area / density^2)``) or ``count``.
    Deterministic for a given ``seed``. Point clouds (no faces) return their points unchanged.
    ``N`` is capped at ``max_samples`` (with a warning).
    """
    vertices, faces = _parts(geom)
    if len(faces) == 0:
        return vertices.copy()
    if (density is None) == (count is None):
        raise GofError("sample_surface needs exactly one of density or count")
    tri = vertices[faces]
    areas = _triangle_areas(tri)
    total = float(areas.sum())
    if count is None:
        if not density > 0:
            raise GofError(f"sample density (spacing) must be > 0, got {density}")
        count = math.ceil(total / density**2)
    if count > max_samples:
        log.warning("%d surface samples requested, using %d (spacing %.3g instead of %s)",
                    count, max_samples, math.sqrt(total / max_samples), density)
        count = max_samples
    if total <= 0 or count <= 0:
        return np.zeros((0, 3))
    rng = np.random.default_rng(seed)
    face = np.searchsorted(np.cumsum(areas), rng.random(count) * total, side="right").clip(max=len(faces) - 1)
    s, r2 = np.sqrt(rng.random(count)), rng.random(count)  # sqrt warps the unit square onto the triangle uniformly
    a, b, c = (vertices[faces[face, k]] for k in range(3))
    return a * (1.0 - s)[:, None] + b * (s * (1.0 - r2))[:, None] + c * (s * r2)[:, None]


# ----------------------------------------------------------------------------- distances
def _closest_point_on_triangles(p, a, b, c) -> np.ndarray:
    """Closest points ``[M, 3]`` on triangles ``(a, b, c)`` to points ``p`` (all ``[M, 3]``), by Voronoi region
    of the triangle's vertices, edges and face (Ericson, Real-Time Collision Detection, 5.1.5)."""
    def dot(u, v):
        return np.einsum("ij,ij->i", u, v)

    ab, ac = b - a, c - a
    d1, d2 = dot(ab, p - a), dot(ac, p - a)
    d3, d4 = dot(ab, p - b), dot(ac, p - b)
    d5, d6 = dot(ab, p - c), dot(ac, p - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):  # NaN only in branches that are not selected
        denom = va + vb + vc
        regions = [  # later entries take precedence
            (np.ones(len(p), bool), a + ab * (vb / denom)[:, None] + ac * (vc / denom)[:, None]),
            ((va <= 0) & (d4 >= d3) & (d5 >= d6), b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None]),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * (d2 / (d2 - d6))[:, None]),
            ((d6 >= 0) & (d5 <= d6), c),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * (d1 / (d1 - d3))[:, None]),
            ((d3 >= 0) & (d4 <= d3), b),
            ((d1 <= 0) & (d2 <= 0), a),
        ]
    out = regions[0][1]
    for mask, q in regions[1:]:
        out = np.where(mask[:, None], q, out)
    return out


RADIUS_CLASS_RATIO = 4.0  # triangles are pruned in classes whose bounding-sphere radii span at most this factor


def point_mesh_distance(points, vertices, faces, chunk: int = 4096) -> np.ndarray:
    """Exact distances ``[N]`` from ``points [N, 3]`` to the triangles ``vertices[faces]`` (zero-area ones ignored).

    An upper bound ``u`` per point (nearest vertex or centroid) prunes the triangles to those whose
    bounding sphere reaches within ``u``; the exact point-triangle distance is computed for those. The
    triangles are grouped by bounding-sphere radius (classes a factor :data:`RADIUS_CLASS_RATIO` wide), each
    class searched with its own largest radius, so a few large triangles (a tetra mesh's edge of the seen
    space) do not widen every point's search. Empty mesh -> ``inf``.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    tri = np.asarray(vertices, np.float64)[faces]
    keep = _triangle_areas(tri) > 0
    tri, faces = tri[keep], faces[keep]
    if len(tri) == 0 or len(points) == 0:
        return np.full(len(points), np.inf)
    centroid = tri.mean(axis=1)
    radius = np.linalg.norm(tri - centroid[:, None], axis=2).max(axis=1)
    on_surface = np.concatenate([np.asarray(vertices, np.float64)[distinct(faces)], centroid])
    out, _ = cKDTree(on_surface).query(points, workers=-1)
    slack = 1e-9 * (radius.max() + np.abs(centroid).max())  # rounding in the sphere test
    cls = np.floor(np.log(np.maximum(radius / radius.max(), 1e-12)) / np.log(RADIUS_CLASS_RATIO)).astype(np.int64)
    classes = [np.flatnonzero(cls == c) for c in distinct(cls)]
    trees = [(cKDTree(centroid[ids]), ids, radius[ids].max()) for ids in classes]
    for s in range(0, len(points), chunk):
        q, u = points[s : s + chunk], out[s : s + chunk]
        for tree, ids, r_max in trees:  # u only shrinks, so each class's search uses the tightest bound so far
            lists = tree.query_ball_point(q, u + r_max + slack, workers=-1)
            counts = np.fromiter(map(len, lists), np.int64, len(lists))
            qi = np.repeat(np.arange(len(q)), counts)
            fi = ids[np.fromiter(itertools.chain.from_iterable(lists), np.int64, int(counts.sum()))]
            near = np.linalg.norm(q[qi] - centroid[fi], axis=1) <= u[qi] + radius[fi] + slack
            qi, fi = qi[near], fi[near]
            d = np.linalg.norm(q[qi] - _closest_point_on_triangles(q[qi], tri[fi, 0], tri[fi, 1], tri[fi, 2]), axis=1)
            np.minimum.at(u, qi, d)  # u is a view into out
    return out


def _distances(query: np.ndarray, target_samples: np.ndarray, target_parts, method: str) -> np.ndarray:
    if method == "triangles" and len(target_parts[1]):
        return point_mesh_distance(query, *target_parts)
    if len(target_samples) == 0:
        return np.full(len(query), np.inf)
    return cKDTree(target_samples).query(query, workers=-1)[0]


def _crop_mask(points: np.ndarray, crop) -> np.ndarray:
    if crop is None:
        return np.ones(len(points), bool)
    if callable(crop):
        m = np.asarray(crop(points), bool)
        if m.shape != (len(points),):
            raise GofError(f"crop function must return a bool array of shape ({len(points)},), got {m.shape}")
        return m
    box = np.asarray(crop, np.float64)
    if box.size != 6 or np.any(box.reshape(2, 3)[0] > box.reshape(2, 3)[1]):
        raise GofError(f"crop must be (min_xyz, max_xyz) with min <= max, got {crop!r}")
    lo, hi = box.reshape(2, 3)
    return np.all((points >= lo) & (points <= hi), axis=1)


# ----------------------------------------------------------------------------- metrics
@dataclass
class SurfaceMetrics:
    """Result of :func:`mesh_accuracy_completeness` (distances in the meshes' units)."""

    accuracy: float
    completeness: float
    chamfer: float
    accuracy_median: float
    completeness_median: float
    tau: list[float]
    precision: list[float]
    recall: list[float]
    fscore: list[float]
    num_pred_samples: int  # scored (after the crop)
    num_gt_samples: int
    pred_outlier_fraction: float  # fraction of pred samples with d >= max_dist
    gt_outlier_fraction: float
    density: float
    max_dist: float
    truncate: str
    method: str

    def to_dict(self) -> dict:
        """JSON-ready dict; non-finite numbers become ``None``."""
        def clean(v):
            if isinstance(v, float) and not math.isfinite(v):
                return None
            return [clean(x) for x in v] if isinstance(v, list) else v

        return {k: clean(v) for k, v in dataclasses.asdict(self).items()}


def _truncated_mean(d: np.ndarray, max_dist: float, truncate: str) -> float:
    if truncate == "clamp":
        return float(np.minimum(d, max_dist).mean()) if d.size else math.inf
    kept = d[d < max_dist]
    return float(kept.mean()) if kept.size else math.inf


def default_eval_params(gt) -> dict:
    """Defaults from the GT's size: ``tau`` = 0.5% and 1% and ``max_dist`` = 5% of its bounding-box
    diagonal; ``density`` = the spacing that puts ~``DEFAULT_GT_SAMPLES`` samples on a GT mesh, or the
    median nearest-neighbour spacing of a GT point cloud."""
    vertices, faces = _parts(gt)
    if len(vertices) == 0:
        raise GofError("the ground truth is empty: give tau, density and max_dist explicitly")
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    if diag == 0:
        raise GofError("the ground truth is a single point: give tau, density and max_dist explicitly")
    area = float(_triangle_areas(vertices[faces]).sum()) if len(faces) else 0.0
    if area > 0:
        density = math.sqrt(area / DEFAULT_GT_SAMPLES)
    else:
        sub = vertices[np.random.default_rng(0).permutation(len(vertices))[:20_000]]
        density = float(np.median(cKDTree(vertices).query(sub, k=2)[0][:, 1])) or diag * 1e-3
    return {"density": density, "max_dist": DEFAULT_MAX_DIST_FRACTION * diag,
            "tau": [f * diag for f in DEFAULT_TAU_FRACTIONS], "gt_diagonal": diag}


def mesh_accuracy_completeness(pred, gt, *, density: float | None = None, max_dist: float | None = None,
                               tau_list=None, crop=None, truncate: str = "exclude", method: str = "points",
                               seed: int = 0, max_samples: int = MAX_SAMPLES) -> SurfaceMetrics:
    """Accuracy, completeness, Chamfer and precision/recall/F-score (see the module docstring).

    Args:
        pred, gt: ``trimesh.Trimesh`` / ``trimesh.PointCloud`` / ``[N, 3]`` points / file paths.
        density: sample spacing; max_dist: truncation distance (``math.inf`` = none); tau_list:
            thresholds. ``None`` = :func:`default_eval_params` of ``gt``.
        crop: ``(min_xyz, max_xyz)`` box or ``points -> bool`` function, applied to the scored samples.
        truncate: ``"exclude"`` (DTU) or ``"clamp"``; method: ``"points"`` or ``"triangles"``.
        seed: sampling seed (pred uses ``seed``, gt ``seed + 1``).
    """
    if truncate not in ("exclude", "clamp"):
        raise GofError(f"truncate must be 'exclude' or 'clamp', got {truncate!r}")
    if method not in ("points", "triangles"):
        raise GofError(f"method must be 'points' or 'triangles', got {method!r}")
    pred_parts, gt_parts = _parts(pred), _parts(gt)
    if density is None or max_dist is None or tau_list is None:
        defaults = default_eval_params(gt_parts)
        density = defaults["density"] if density is None else density
        max_dist = defaults["max_dist"] if max_dist is None else max_dist
        tau_list = defaults["tau"] if tau_list is None else tau_list
    tau_list = [float(t) for t in np.atleast_1d(np.asarray(tau_list, np.float64))]
    if not max_dist > 0 or any(not t > 0 for t in tau_list):
        raise GofError(f"max_dist and every tau must be > 0, got max_dist={max_dist}, tau={tau_list}")
    pred_pts = sample_surface(pred_parts, density=density, seed=seed, max_samples=max_samples)
    gt_pts = sample_surface(gt_parts, density=density, seed=seed + 1, max_samples=max_samples)
    pred_q, gt_q = pred_pts[_crop_mask(pred_pts, crop)], gt_pts[_crop_mask(gt_pts, crop)]
    d_acc = _distances(pred_q, gt_pts, gt_parts, method)  # inf where gt is empty
    d_comp = _distances(gt_q, pred_pts, pred_parts, method)
    acc = _truncated_mean(d_acc, max_dist, truncate) if len(gt_pts) else math.inf  # not clamped to max_dist
    comp = _truncated_mean(d_comp, max_dist, truncate) if len(pred_pts) else math.inf

    def frac(d, t):
        return float(np.mean(d < t)) if d.size else 0.0

    P = [frac(d_acc, t) for t in tau_list]
    R = [frac(d_comp, t) for t in tau_list]
    return SurfaceMetrics(
        accuracy=acc, completeness=comp, chamfer=0.5 * (acc + comp),
        accuracy_median=float(np.median(d_acc)) if d_acc.size else math.inf,
        completeness_median=float(np.median(d_comp)) if d_comp.size else math.inf,
        tau=tau_list, precision=P, recall=R,
        fscore=[2 * p * r / (p + r) if p + r > 0 else 0.0 for p, r in zip(P, R)],
        num_pred_samples=len(pred_q), num_gt_samples=len(gt_q),
        pred_outlier_fraction=float(np.mean(d_acc >= max_dist)) if d_acc.size else 0.0,
        gt_outlier_fraction=float(np.mean(d_comp >= max_dist)) if d_comp.size else 0.0,
        density=float(density), max_dist=float(max_dist), truncate=truncate, method=method,
    )


def mesh_statistics(geom) -> dict:
    """Counts and topology of a mesh as stored (vertices are not merged).

    ``connected_components`` joins faces that share an edge; ``watertight`` = at least one face and every
    edge used by exactly two faces; ``winding_consistent`` = no directed edge used twice;
    ``degenerate_faces`` = repeated vertex index or (relative) zero area.
    """
    vertices, faces = _parts(geom)
    V, nF = len(vertices), len(faces)
    lo = vertices.min(0) if V else np.zeros(3)
    hi = vertices.max(0) if V else np.zeros(3)
    stats = {"vertices": V, "faces": nF, "unreferenced_vertices": V - len(distinct(faces)),
             "connected_components": 0, "watertight": False, "winding_consistent": True, "edges": 0,
             "boundary_edges": 0, "non_manifold_edges": 0, "degenerate_faces": 0, "euler_characteristic": 0,
             "area": 0.0, "bbox_min": lo.tolist(), "bbox_max": hi.tolist(), "bbox_diagonal": float(np.linalg.norm(hi - lo))}
    if nF == 0:
        return stats
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    undirected = np.sort(directed, axis=1)
    key = undirected[:, 0] * V + undirected[:, 1]
    uniq, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    E = len(uniq)
    # faces and edges as one graph (face f -- edge e when f uses e): its components among the faces
    rows = np.repeat(np.arange(nF), 3)
    graph = coo_matrix((np.ones(3 * nF), (rows, nF + inverse)), shape=(nF + E, nF + E))
    labels = connected_components(graph, directed=False)[1]
    tri = vertices[faces]
    areas = _triangle_areas(tri)
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(1)
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    stats.update(
        connected_components=len(distinct(labels[:nF])), edges=E,
        boundary_edges=int((counts == 1).sum()), non_manifold_edges=int((counts > 2).sum()),
        watertight=bool(np.all(counts == 2)),
        winding_consistent=len(distinct(directed[:, 0] * V + directed[:, 1])) == len(directed),
        degenerate_faces=int((repeated | (areas <= 1e-12 * longest**2)).sum()),  # 1e-12: float64 rounding of cross products
        euler_characteristic=int(V - stats["unreferenced_vertices"] - E + nF), area=float(areas.sum()),
    )
    return stats


def evaluate_mesh(mesh, gt, *, tau=None, density=None, max_dist=None, crop=None, truncate: str = "exclude",
                  method: str = "points", seed: int = 0) -> dict:
    """Load (if paths), score and describe a reconstruction against a ground truth; JSON-ready dict
    ``{"mesh", "gt", "metrics", "mesh_stats", "gt_stats"}``. Arguments as :func:`mesh_accuracy_completeness`."""
    pred_g = load_geometry(mesh) if isinstance(mesh, (str, Path)) else mesh
    gt_g = load_geometry(gt) if isinstance(gt, (str, Path)) else gt
    result = mesh_accuracy_completeness(pred_g, gt_g, density=density, max_dist=max_dist, tau_list=tau,
                                        crop=crop, truncate=truncate, method=method, seed=seed)
    return {"mesh": str(mesh) if isinstance(mesh, (str, Path)) else None,
            "gt": str(gt) if isinstance(gt, (str, Path)) else None,
            "metrics": result.to_dict(), "mesh_stats": mesh_statistics(pred_g), "gt_stats": mesh_statistics(gt_g)}
