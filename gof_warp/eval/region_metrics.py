"""Region scoring: score only the surfaces some training camera sees, sampling *inside* the scored region,
with the exact-vs-exact floor beside every score and ground-plane metrics for whole scenes.

Why: GOF meshes whole scenes (ground, objects, far background). Sampling a whole mesh and cropping the
samples afterwards (:func:`gof_warp.eval.geometry_metrics.mesh_accuracy_completeness` with ``crop``) leaves the
scored region with a fraction of the samples and scores surfaces nobody could see (the underside of a box
resting on the ground, the faces inside a closed box, the shell below the ground). Here:

* **Seen GT** (:func:`seen_faces`): the GT faces hit by a primary ray of some training camera (Warp BVH ray
  casting, ``supersample``\\ ² rays per pixel so that small faces are not missed). GT meshes are first
  split to edges of at most ``gt_max_edge`` (default 1 % of the diagonal) so that "seen" is decided per
  small piece, not per large triangle (a two-triangle ground plane would otherwise be seen everywhere).
* **Region** (:func:`in_region`), DTU-style: a point ``x`` is in the region when, for at least one
  training camera, ``x`` is in front of it, projects inside its image, and lies not farther than
  ``margin`` (default ``max_dist``) behind the GT surface along that pixel's ray (the GT depth map is the
  largest GT depth over the pixel's sub-rays, infinite where any sub-ray misses); and ``x`` lies in the box
  of interest (default: the seen GT's bounding box grown by ``max_dist``). This is the *observed volume*:
  free space in front of seen surfaces is observed (floaters there are scored as errors), a thin shell
  behind them is scored (a surface reconstructed slightly too deep is an error, not invisible), anything
  deeper is unobservable and not scored. It replaces DTU's scanner-visibility mask (ObsMask) by the
  training cameras' own visibility, which is what a photometric method can possibly reconstruct.
* **Crop, then sample** (:func:`crop_mesh`): triangles are split (4-way, at edge midpoints) until each is
  at most ``coarse`` long, then those whose corners and centroid disagree about the region are split
  again down to ``density``; kept pieces are those inside (by their centroid at the finest level). The kept
  surface is then sampled at ``density`` (area-weighted, :func:`~gof_warp.eval.geometry_metrics.sample_surface`).
  The same crop is applied to the seen GT, so both sides are sampled at the same density on the same
  region and the exact mesh scores the sampling floor.
* **Floor**: the same protocol scoring the GT mesh itself (all of it, cropped by the region) against the
  same GT samples, with an independent sampling seed. It is the best score this protocol can give at this
  density; report it beside every score.
* **Ground** (:func:`ground_metrics`), when a ground plane ``z = height`` is known (synthetic
  ``scene.json``): over the seen ground outside the objects' footprints (grown by ``footprint_margin``),
  completeness per ``patch`` × ``patch`` square (fraction of GT ground samples with a predicted sample
  within ``tau``; worst patch; patches more than 10 % missing) and flatness (of the predicted samples whose
  nearest GT sample is a seen-ground sample within a vertical band of ``max_dist``: the fraction within
  ``flat_fraction`` × diagonal of the plane, and the 95th percentile of ``|z - height|``).

The **diagonal** is that of the bounding box of the seen GT (after splitting, before the depth crop,
inside the box of interest when one is given): tau = 0.5 % and 1 %, ``max_dist`` = 5 %, flatness
tolerance = 0.2 % of it.

Memory: the depth maps (one float32 ``[H, W]`` per camera) are held for the whole evaluation; points are
classified in chunks of ``chunk``.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ..core.arrays import distinct
from ..core.camera import Camera
from ..core.errors import GofError
from .geometry_metrics import (
    DEFAULT_GT_SAMPLES,
    DEFAULT_MAX_DIST_FRACTION,
    DEFAULT_TAU_FRACTIONS,
    _parts,
    _triangle_areas,
    load_geometry,
    mesh_accuracy_completeness,
    mesh_statistics,
    sample_surface,
)

log = logging.getLogger(__name__)

DEFAULT_SUPERSAMPLE = 3  # sub-rays per pixel axis for seen_faces: faces down to ~1/3 pixel are found
DEFAULT_GT_MAX_EDGE_FRACTION = 0.01  # GT split to edges <= 1 % of the diagonal before the seen test
FLAT_FRACTION = 0.002  # flatness tolerance: 0.2 % of the diagonal (the real-captures target: 95 % of points within it)
FLAT_TARGET = 0.95
PATCH_SIZE = 0.1  # ground patches of 10 x 10 cm in metric scenes (1 unit = 1 m)
PATCH_MISSING_LIMIT = 0.1  # a patch "fails" with more than 10 % of its GT ground samples missing
PATCH_MIN_SAMPLES = 16  # patches with fewer seen-ground samples (cut by footprints, edges) are not reported
PATCHES_LISTED = 50  # incomplete patches listed by centre in the report (worst first)
GROUND_SAMPLES_PER_PATCH = 100  # seen-ground sampling density for the patch statistics
ON_PLANE_FRACTION = 1e-5  # of the diagonal: a GT sample this close to the plane is a ground sample


# ----------------------------------------------------------------------------------------- visibility
@dataclass
class Observation:
    """What the training cameras see of a GT mesh (:func:`observe`).

    Attributes:
        views: ``[F]`` int, how many cameras hit the face with some primary (sub-)ray.
        seen: ``[F]`` bool (derived: ``views > 0``), GT face hit by some primary (sub-)ray.
        cameras: the cameras.
        depth: one ``[H, W]`` float32 per camera: the largest GT camera-z depth over the pixel's sub-rays,
            ``inf`` where any sub-ray misses the GT.
    """

    views: np.ndarray
    cameras: list
    depth: list

    @property
    def seen(self) -> np.ndarray:
        return self.views > 0


def _check_cameras(cameras) -> list:
    cameras = list(cameras)
    if not cameras or not all(isinstance(c, Camera) for c in cameras):
        raise GofError("region scoring needs a non-empty list of gof_warp.core.camera.Camera (the training views)")
    return cameras


def observe(vertices, faces, cameras, *, supersample: int = DEFAULT_SUPERSAMPLE, device=None) -> Observation:
    """Cast ``supersample`` x ``supersample`` primary rays per pixel of every camera at the mesh
    ``vertices [V, 3]``, ``faces [F, 3]`` (Warp ``wp.Mesh`` BVH; ``kernels/raycast.py``).

    Returns the :class:`Observation` (seen faces and per-camera GT depth maps). ``device``: Warp device
    (default cuda when present, else cpu)."""
    import warp as wp

    from ..kernels.raycast import cast_pinhole_rays

    from ..synthetic.render import default_device

    cameras = _check_cameras(cameras)
    if int(supersample) != supersample or supersample < 1:
        raise GofError(f"supersample must be a positive integer, got {supersample}")
    V = np.ascontiguousarray(np.asarray(vertices, np.float32).reshape(-1, 3))
    F = np.asarray(faces, np.int64).reshape(-1, 3)
    views = np.zeros(len(F), np.int32)
    if len(F) == 0:
        return Observation(views, cameras, [np.full((c.height, c.width), np.inf, np.float32) for c in cameras])
    dev = wp.get_device(device or default_device())
    mesh = wp.Mesh(points=wp.array(V, dtype=wp.vec3, device=dev),
                   indices=wp.array(np.ascontiguousarray(F.astype(np.int32).ravel()), dtype=wp.int32, device=dev))
    s = int(supersample)
    depths = []
    for c in cameras:
        hits = cast_pinhole_rays(mesh, c.R, c.t, c.fx, c.fy, c.cx, c.cy, c.width, c.height, s)
        face = hits["face"].numpy()
        views[distinct(face[face >= 0])] += 1
        d = np.where(face >= 0, hits["depth"].numpy(), np.inf).reshape(c.height, s, c.width, s)
        depths.append(d.max(axis=(1, 3)).astype(np.float32))
    return Observation(views, cameras, depths)


def seen_faces(vertices, faces, cameras, *, supersample: int = DEFAULT_SUPERSAMPLE, device=None) -> np.ndarray:
    """``[F]`` bool: the faces of ``vertices [V, 3]``, ``faces [F, 3]`` hit by a primary ray of some camera.

    Each pixel casts ``supersample`` x ``supersample`` rays (at the sub-pixel centres), so a face is found
    when it covers about ``1 / supersample`` of a pixel in some view."""
    return observe(vertices, faces, cameras, supersample=supersample, device=device).seen


def observed_by(cam: Camera, depth: np.ndarray, points: np.ndarray, margin: float) -> np.ndarray:
    """``[N]`` bool: ``points [N, 3]`` (float64) in front of ``cam``, inside its image and at most ``margin`` behind
    its GT ``depth`` map (:class:`Observation`) along the pixel's ray."""
    x = points @ cam.R.T + cam.t
    z = x[:, 2]
    front = z > 1e-9
    zs = np.where(front, z, 1.0)
    a, b = x[:, 0] / zs, x[:, 1] / zs
    u, v = cam.fx * a + cam.cx, cam.fy * b + cam.cy
    ok = front & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    iu = np.clip(np.floor(u).astype(np.int64), 0, cam.width - 1)
    iv = np.clip(np.floor(v).astype(np.int64), 0, cam.height - 1)
    behind = (z - depth[iv, iu]) * np.sqrt(a * a + b * b + 1.0)  # -inf where the GT ray misses
    return ok & (behind <= margin)


def in_region(points, observation: Observation, margin: float, bbox=None, chunk: int = 1 << 16,
              min_views: int = 1) -> np.ndarray:
    """``[N]`` bool: ``points [N, 3]`` inside the observed region (module docstring): in ``bbox``
    (``(min_xyz, max_xyz)`` or None) and, for at least ``min_views`` cameras, in front of it, inside its image and
    at most ``margin`` behind the GT depth along the pixel's ray. Cameras are tried in turn; a point stops at the
    ``min_views``-th camera that observes it."""
    P = np.asarray(points, np.float64).reshape(-1, 3)
    out = np.zeros(len(P), bool)
    need = np.full(len(P), int(min_views), np.int32)  # observations still missing
    idx = np.arange(len(P))
    if bbox is not None:
        lo, hi = np.asarray(bbox, np.float64).reshape(2, 3)
        idx = idx[np.all((P >= lo) & (P <= hi), axis=1)]
    for s in range(0, len(idx), chunk):
        left = idx[s : s + chunk]
        for cam, D in zip(observation.cameras, observation.depth):
            if not len(left):
                break
            hit = observed_by(cam, D, P[left], margin)
            need[left[hit]] -= 1
            done = need[left] <= 0
            out[left[done]] = True
            left = left[~done]
    return out


# ----------------------------------------------------------------------------------------- crop, then sample
def _split4(tri: np.ndarray) -> np.ndarray:
    """``[M, 3, 3]`` triangles -> ``[4M, 3, 3]`` (edge midpoints)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    return np.concatenate([np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])


def _longest_edge(tri: np.ndarray) -> np.ndarray:
    return np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)


def split_triangles(tri: np.ndarray, max_edge: float, max_levels: int = 16) -> np.ndarray:
    """Split triangles ``[M, 3, 3]`` 4-way until every edge is at most ``max_edge``; returns ``[M', 3, 3]``."""
    tri = np.asarray(tri, np.float64).reshape(-1, 3, 3)
    done = []
    for _ in range(max_levels):
        big = _longest_edge(tri) > max_edge
        done.append(tri[~big])
        if not big.any():
            break
        tri = _split4(tri[big])
    else:
        done.append(tri)
    return np.concatenate(done) if done else tri


def crop_mesh(vertices, faces, inside, *, resolution: float, coarse: float | None = None,
              max_levels: int = 16) -> np.ndarray:
    """The part of a mesh inside a region, as a triangle soup ``[M, 3, 3]`` (float64).

    Args:
        vertices, faces: ``[V, 3]``, ``[F, 3]``.
        inside: ``points [N, 3] -> bool [N]``.
        resolution: boundary triangles are split down to edges of at most this (use the sample spacing).
        coarse: every triangle is first split to at most this (default ``8 * resolution``), so a region
            smaller than a large triangle is not missed; a region pocket smaller than ``coarse`` that holds
            none of a triangle's corners or centroid can still be missed.
    """
    V, F = _parts((np.asarray(vertices), np.asarray(faces)))
    tri = split_triangles(V[F], coarse or 8.0 * resolution, max_levels)
    kept = []
    for _ in range(max_levels):
        if not len(tri):
            break
        flags = inside(np.concatenate([tri.reshape(-1, 3), tri.mean(axis=1)]))
        corner, centre = flags[: 3 * len(tri)].reshape(-1, 3), flags[3 * len(tri) :]
        all_in, all_out = corner.all(axis=1) & centre, ~corner.any(axis=1) & ~centre
        small = _longest_edge(tri) <= resolution
        kept.append(tri[all_in | (~all_out & small & centre)])
        tri = _split4(tri[~all_in & ~all_out & ~small])
    else:
        kept.append(tri[inside(tri.mean(axis=1))])
    return np.concatenate(kept) if kept else np.zeros((0, 3, 3))


def _soup(tri: np.ndarray):
    return tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3)


def sample_soup(tri: np.ndarray, density: float, seed: int) -> np.ndarray:
    """Area-weighted samples ``[N, 3]`` of a triangle soup at mean spacing ``density``."""
    if not len(tri):
        return np.zeros((0, 3))
    return sample_surface(_soup(tri), density=density, seed=seed)


# ----------------------------------------------------------------------------------------- ground
@dataclass
class Ground:
    """A horizontal ground plane ``z = height`` (z up) over ``extent = ((xmin, ymin), (xmax, ymax))``;
    ``footprints``: ``[K, 2, 2]`` xy boxes ``((xmin, ymin), (xmax, ymax))`` of the objects resting on it."""

    height: float
    extent: tuple
    footprints: np.ndarray

    @classmethod
    def from_scene_json(cls, scene: dict) -> "Ground | None":
        g = scene.get("ground")
        if not g:
            return None
        fp = [np.asarray(p["bbox"], np.float64)[:, :2] for p in scene.get("parts", [])
              if p.get("role") == "object" and "bbox" in p]
        return cls(float(g["height"]), tuple(map(tuple, g["extent"])), np.asarray(fp).reshape(-1, 2, 2))

    def free(self, xy: np.ndarray, margin: float) -> np.ndarray:
        """``[N]`` bool: ``xy [N, 2]`` inside the extent and outside every footprint grown by ``margin``."""
        lo, hi = np.asarray(self.extent, np.float64)
        ok = np.all((xy >= lo) & (xy <= hi), axis=1)
        for b in self.footprints:
            ok &= ~np.all((xy >= b[0] - margin) & (xy <= b[1] + margin), axis=1)
        return ok


def ground_metrics(pred_pts, gt_pts, gt_ground_pts, ground: Ground, *, tau: float, band: float, flat_tol: float,
                   margin: float, patch: float = PATCH_SIZE, min_samples: int = PATCH_MIN_SAMPLES) -> dict:
    """Ground completeness per patch and flatness (module docstring).

    Args:
        pred_pts: ``[N, 3]`` predicted samples (inside the region).
        gt_pts: ``[M, 3]`` all scored GT samples (decide which GT surface is nearest).
        gt_ground_pts: ``[G, 3]`` dense samples of the seen ground (outside footprints).
        tau: a GT ground sample is covered when a predicted sample lies within ``tau``.
        band: vertical band around the plane for flatness; flat_tol: allowed ``|z - height|``.
        margin: footprint growth; patch: patch side; min_samples: smaller patches are not reported.
    """
    pred_pts = np.asarray(pred_pts, np.float64).reshape(-1, 3)
    h = ground.height
    out = {"height": h, "patch": patch, "tau": tau, "band": band, "flat_tolerance": flat_tol,
           "footprint_margin": margin, "ground_samples": int(len(gt_ground_pts))}
    # completeness per patch
    if len(gt_ground_pts) and len(pred_pts):
        covered = cKDTree(pred_pts).query(gt_ground_pts, distance_upper_bound=tau, workers=-1)[0] < tau
    else:
        covered = np.zeros(len(gt_ground_pts), bool)
    lo = np.asarray(ground.extent, np.float64)[0]
    cell = np.floor((gt_ground_pts[:, :2] - lo) / patch).astype(np.int64)
    keys, inv, counts = np.unique(cell, axis=0, return_inverse=True, return_counts=True)
    frac = np.bincount(inv.ravel(), weights=covered.astype(np.float64), minlength=len(keys)) / np.maximum(counts, 1)
    rep = counts >= min_samples
    worst = int(np.argmin(np.where(rep, frac, np.inf))) if rep.any() else None
    over = rep & (1.0 - frac > PATCH_MISSING_LIMIT)
    short = np.flatnonzero(over)
    short = short[np.argsort(frac[short], kind="stable")][:PATCHES_LISTED]
    out.update(
        patches=int(rep.sum()),
        patches_over_limit=int(over.sum()),
        missing_limit=PATCH_MISSING_LIMIT,
        worst_patch_completeness=float(frac[worst]) if worst is not None else None,
        worst_patch_center=(lo + (keys[worst] + 0.5) * patch).tolist() if worst is not None else None,
        # the patches over the limit, worst first (at most PATCHES_LISTED): where the ground is incomplete
        patches_over_limit_list=[{"center": (lo + (keys[i] + 0.5) * patch).tolist(), "completeness": float(frac[i])}
                                 for i in short.tolist()],
        ground_completeness=float(covered.mean()) if len(covered) else None,
    )
    out["patch_target_met"] = bool(rep.any() and out["patches_over_limit"] == 0)
    # flatness: predicted samples over the seen ground whose nearest GT sample is a ground sample
    err = np.zeros(0)
    if len(pred_pts) and len(gt_pts):
        near = np.abs(pred_pts[:, 2] - h) < band
        near &= ground.free(pred_pts[:, :2], margin)
        cand = pred_pts[near]
        if len(cand):
            d_gt, _ = cKDTree(gt_pts).query(cand, workers=-1)
            d_ground = cKDTree(gt_ground_pts).query(cand, workers=-1)[0] if len(gt_ground_pts) else np.inf
            on_ground = np.asarray(d_ground <= d_gt * (1 + 1e-9) + 1e-12) & (d_ground < band)
            err = np.abs(cand[on_ground, 2] - h)
    out.update(flat_points=int(len(err)),
               flat_fraction=float(np.mean(err <= flat_tol)) if len(err) else None,
               height_error_p95=float(np.percentile(err, 95)) if len(err) else None,
               height_error_max=float(err.max()) if len(err) else None,
               flat_target=FLAT_TARGET)
    out["flat_target_met"] = bool(len(err) and out["flat_fraction"] >= FLAT_TARGET)
    return out


# ----------------------------------------------------------------------------------------- the protocol
def read_scene(scene_dir) -> tuple[list, dict]:
    """``(training cameras, scene.json dict or {})`` of a Blender/NeRF-synthetic scene folder (OpenGL
    ``transform_matrix``; intrinsics ``fl_x/fl_y/cx/cy/w/h`` or ``camera_angle_x`` with the image size
    ``w``/``h``)."""
    root = Path(scene_dir)
    path = root / "transforms_train.json"
    if not path.is_file():
        raise GofError(f"scene folder {root} has no transforms_train.json (region scoring needs the training cameras)")
    try:
        meta = json.loads(path.read_text())
        cams = []
        for k, fr in enumerate(meta["frames"]):
            d = {**meta, **fr}
            w, h = int(d["w"]), int(d["h"])
            fx = float(d.get("fl_x") or (w / 2) / math.tan(float(d["camera_angle_x"]) / 2))
            fy = float(d.get("fl_y") or fx)
            cams.append(Camera.from_c2w(np.asarray(fr["transform_matrix"], np.float64), fx, fy,
                                        float(d.get("cx", w / 2)), float(d.get("cy", h / 2)), w, h,
                                        name=Path(fr.get("file_path", f"{k}")).name, opengl=True))
    except (KeyError, TypeError, ValueError) as e:
        raise GofError(f"{path}: cannot read the cameras ({e!r})") from None
    scene_json = root / "scene.json"
    scene = json.loads(scene_json.read_text()) if scene_json.is_file() else {}
    return cams, scene


def _box_diag(p: np.ndarray) -> float:
    return float(np.linalg.norm(p.max(0) - p.min(0))) if len(p) else 0.0


@dataclass
class ScoredRegion:
    """The region :func:`region_scores` scores (its docstring gives the defaults), from GT triangles already split.

    Attributes:
        observation: the cameras' :class:`Observation` of the triangles.
        seen: ``[T]`` bool, the triangles seen (inside the box of interest when one was given).
        seen_area: their area.
        diagonal, tau, max_dist, margin, bbox, density, min_views: as in :func:`region_scores`, defaults resolved.
    """

    observation: Observation
    seen: np.ndarray
    seen_area: float
    diagonal: float
    tau: list[float]
    max_dist: float
    margin: float
    bbox: tuple
    density: float
    min_views: int = 1

    def inside(self, points) -> np.ndarray:
        """``[N]`` bool: the points in the observed volume (:func:`in_region`) and the box of interest."""
        return in_region(points, self.observation, self.margin, self.bbox, min_views=self.min_views)


def scored_region(gt_tri: np.ndarray, cameras, *, tau=None, density: float | None = None,
                  max_dist: float | None = None, margin: float | None = None, bbox=None,
                  supersample: int = DEFAULT_SUPERSAMPLE, gt_samples: int = DEFAULT_GT_SAMPLES,
                  min_views: int = 1, device=None) -> ScoredRegion:
    """:class:`ScoredRegion` of the split GT triangles ``gt_tri`` ``[T, 3, 3]`` seen by ``cameras`` (by at least
    ``min_views`` of them)."""
    if isinstance(min_views, bool) or not isinstance(min_views, (int, np.integer)) or min_views < 1:
        raise GofError(f"min_views must be an integer >= 1, got {min_views!r}")
    obs = observe(*_soup(gt_tri), cameras, supersample=supersample, device=device)
    seen = obs.views >= min_views
    if bbox is not None:
        lo, hi = np.asarray(bbox, np.float64).reshape(2, 3)
        seen &= np.all((gt_tri.mean(1) >= lo) & (gt_tri.mean(1) <= hi), axis=1)
    seen_tri = gt_tri[seen]
    if not len(seen_tri):
        raise GofError(f"no GT face is seen by {'the' if min_views == 1 else f'at least {min_views}'} cameras "
                       "(inside the box of interest): nothing to score")
    diag = _box_diag(seen_tri.reshape(-1, 3))
    tau = [float(f * diag) for f in DEFAULT_TAU_FRACTIONS] if tau is None else [float(t) for t in np.atleast_1d(tau)]
    max_dist = DEFAULT_MAX_DIST_FRACTION * diag if max_dist is None else float(max_dist)
    margin = max_dist if margin is None else float(margin)
    if bbox is None:
        pts = seen_tri.reshape(-1, 3)
        bbox = (pts.min(0) - max_dist, pts.max(0) + max_dist)
    seen_area = float(_triangle_areas(seen_tri).sum())
    density = math.sqrt(seen_area / gt_samples) if density is None else float(density)
    return ScoredRegion(obs, seen, seen_area, diag, tau, max_dist, margin, bbox, density, int(min_views))


def region_scores(pred, gt, cameras, *, tau=None, density: float | None = None, max_dist: float | None = None,
                  margin: float | None = None, bbox=None, ground: Ground | None = None,
                  footprint_margin: float | None = None, patch: float = PATCH_SIZE,
                  gt_max_edge: float | None = None, supersample: int = DEFAULT_SUPERSAMPLE,
                  truncate: str = "exclude", gt_samples: int = DEFAULT_GT_SAMPLES, seed: int = 0,
                  min_views: int = 1, device=None) -> dict:
    """Score ``pred`` against ``gt`` on the region the ``cameras`` observe (module docstring).

    Args:
        pred, gt: meshes (``trimesh.Trimesh``, ``(vertices [V, 3], faces [F, 3])`` or paths); ``gt`` needs faces.
        cameras: the training :class:`~gof_warp.core.camera.Camera` list.
        tau: F-score thresholds (default 0.5 % and 1 % of the diagonal); density: sample spacing (default
            ``~gt_samples`` samples on the scored GT); max_dist: truncation (default 5 % of the diagonal);
            margin: depth behind the GT still in the region (default ``max_dist``); bbox: box of interest
            ``(min_xyz, max_xyz)`` (default the seen GT's box grown by ``max_dist``).
        ground: a :class:`Ground` for the ground metrics (None: none); footprint_margin: default the
            largest tau; patch: ground patch side.
        gt_max_edge: GT split before the seen test (default 1 % of the GT's diagonal).
        supersample: sub-rays per pixel axis; truncate: as :func:`mesh_accuracy_completeness`.
        seed: pred samples use ``seed``, GT ``seed + 1``, the floor's GT-as-prediction ``seed + 2``.
        min_views: score only what at least this many cameras see (the GT faces they hit, the volume they observe);
            1 (default): any camera.

    Returns:
        ``{"metrics": SurfaceMetrics dict, "region": {...}, "floor": {"metrics", "ground"}, "ground": {...}
        or None}``.
    """
    cameras = _check_cameras(cameras)
    pv, pf = _parts(pred)
    gv, gf = _parts(gt)
    if len(gf) == 0:
        raise GofError("region scoring needs a GT mesh with faces (a point cloud has no visibility)")
    gt_tri = split_triangles(gv[gf], gt_max_edge or DEFAULT_GT_MAX_EDGE_FRACTION * _box_diag(gv))
    reg = scored_region(gt_tri, cameras, tau=tau, density=density, max_dist=max_dist, margin=margin, bbox=bbox,
                        supersample=supersample, gt_samples=gt_samples, min_views=min_views, device=device)
    obs, seen_tri, seen_area, inside = reg.observation, gt_tri[reg.seen], reg.seen_area, reg.inside
    diag, tau, max_dist, margin, bbox, density = reg.diagonal, reg.tau, reg.max_dist, reg.margin, reg.bbox, reg.density
    gt_crop = crop_mesh(*_soup(seen_tri), inside, resolution=density)
    pred_crop = crop_mesh(pv, pf, inside, resolution=density) if len(pf) else np.zeros((0, 3, 3))
    floor_crop = crop_mesh(gv, gf, inside, resolution=density)
    gt_pts = sample_soup(gt_crop, density, seed + 1)
    pred_pts = sample_soup(pred_crop, density, seed) if len(pf) else pv[inside(pv)] if len(pv) else pv
    floor_pts = sample_soup(floor_crop, density, seed + 2)

    def score(p):
        return mesh_accuracy_completeness(p, gt_pts, density=density, max_dist=max_dist, tau_list=tau,
                                          truncate=truncate, method="points").to_dict()

    report = {
        "metrics": score(pred_pts),
        "region": {"definition": "seen GT faces; pred and GT cropped to the observed volume (in an image, in "
                                 "front of the camera, <= margin behind the GT depth) inside bbox, then sampled",
                   "diagonal": diag, "diagonal_of": "bounding box of the seen GT", "tau": tau,
                   "max_dist": max_dist, "margin": margin, "density": density, "bbox": [list(map(float, b)) for b in bbox],
                   "cameras": len(cameras), "supersample": supersample,
                   "min_views": int(min_views), "gt_faces_split": int(len(gt_tri)), "gt_faces_seen": int(reg.seen.sum()),
                   "gt_area": float(_triangle_areas(gv[gf]).sum()), "gt_seen_area": seen_area,
                   "gt_scored_area": float(_triangle_areas(gt_crop).sum()),
                   "pred_area": float(_triangle_areas(pv[pf]).sum()) if len(pf) else 0.0,
                   "pred_scored_area": float(_triangle_areas(pred_crop).sum()),
                   "gt_samples": int(len(gt_pts)), "pred_samples": int(len(pred_pts))},
        "floor": {"metrics": score(floor_pts), "seed": seed + 2},
        "ground": None,
    }
    if ground is not None:
        fm = max(tau) if footprint_margin is None else float(footprint_margin)
        on_plane = np.all(np.abs(gt_crop[:, :, 2] - ground.height) <= ON_PLANE_FRACTION * diag, axis=1)
        g_tri = gt_crop[on_plane]
        g_pts = sample_soup(g_tri, patch / math.sqrt(GROUND_SAMPLES_PER_PATCH), seed + 3)
        g_pts = g_pts[ground.free(g_pts[:, :2], fm)] if len(g_pts) else g_pts
        kw = dict(tau=tau[0], band=max_dist, flat_tol=FLAT_FRACTION * diag, margin=fm, patch=patch)
        report["ground"] = ground_metrics(pred_pts, gt_pts, g_pts, ground, **kw)
        report["ground"]["seen_ground_area"] = float(_triangle_areas(g_tri).sum())
        report["floor"]["ground"] = ground_metrics(floor_pts, gt_pts, g_pts, ground, **kw)
    return report


def evaluate_region(mesh, gt, scene_dir=None, *, cameras=None, ground: Ground | None = None, **kw) -> dict:
    """:func:`evaluate_mesh`-shaped report scored on the observed region: ``{"mesh", "gt", "metrics",
    "mesh_stats", "gt_stats", "region", "floor", "ground"}`` (``metrics`` keeps every key of
    :class:`~gof_warp.eval.geometry_metrics.SurfaceMetrics`). Cameras come from ``scene_dir``'s
    ``transforms_train.json`` (or ``cameras``), the ground plane and footprints from its ``scene.json``
    (or ``ground``). ``kw``: :func:`region_scores`."""
    scene = {}
    if scene_dir is not None:
        cams, scene = read_scene(scene_dir)
        cameras = cameras or cams
        ground = ground or Ground.from_scene_json(scene)
    if cameras is None:
        raise GofError("evaluate_region needs a scene folder or cameras")
    pred_g = load_geometry(mesh) if isinstance(mesh, (str, Path)) else mesh
    gt_g = load_geometry(gt) if isinstance(gt, (str, Path)) else gt
    rep = region_scores(pred_g, gt_g, cameras, ground=ground, **kw)
    rep["region"]["scene"] = None if scene_dir is None else str(scene_dir)
    return {"mesh": str(mesh) if isinstance(mesh, (str, Path)) else None,
            "gt": str(gt) if isinstance(gt, (str, Path)) else None,
            **rep, "mesh_stats": mesh_statistics(pred_g), "gt_stats": mesh_statistics(gt_g)}


__all__ = ["Ground", "Observation", "crop_mesh", "evaluate_region", "ground_metrics", "in_region", "observe",
           "observed_by",
           "read_scene", "region_scores", "sample_soup", "scored_region", "ScoredRegion", "seen_faces",
           "split_triangles"]
