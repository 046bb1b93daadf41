"""Sparse points triangulated from a scene's KNOWN poses (COLMAP's ``point_triangulator``, via pycolmap).

Blender, instant-ngp and DTU/NeuS scenes come without SfM points; official GOF starts from points that
COLMAP triangulates with the given cameras. This module does the same without a COLMAP binary:

1. **features**: every view's image is written to a temporary folder (PNG) and SIFT runs on the CPU
   (``pycolmap.extract_features``), on a copy downscaled to ``max_image_size`` when larger (keypoints
   come back in full-resolution pixels). The database cameras are set to our pinhole intrinsics.
2. **pairs**: all pairs (``exhaustive``) or, for each view, the ``pose_neighbors`` nearest views by
   camera centre and viewing direction whose frusta overlap (``pose``); ``auto`` picks exhaustive up to
   ``exhaustive_max_views`` views. SIFT matching (ratio test + cross check) on those pairs only.
3. **verification with the known poses**: a match is kept when its Sampson distance to the epipolar
   geometry of the two given cameras is at most ``max_epipolar_error`` pixels (no RANSAC: the relative
   pose is known, so pairs with few matches are not thrown away).
4. **triangulation**: ``pycolmap.triangulate_points`` on a reconstruction built from our cameras and
   world-to-camera poses; poses and intrinsics stay fixed (only points are refined by its bundle
   adjustment). Points are then filtered by track length, reprojection error and (inside COLMAP)
   triangulation angle.

Conventions: cameras are world-to-camera ``R, t`` with OpenCV axes and pixel centres at ``i + 0.5``,
which is COLMAP's convention too, so intrinsics and poses are passed through unchanged.

Results are cached as ``.npz`` (no pickle) in ``cache_dir``, keyed by a hash of the cameras, image names,
image bytes and the :class:`SfmConfig`, so the work runs once per scene. Memory: the temporary PNGs and
the SQLite database live on disk; pycolmap holds the features of one matching block at a time.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import tempfile
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..camera import Camera
from ..errors import GofError, SceneError
from ..io_utils import atomic_path
from ..scene import Scene, View

log = logging.getLogger(__name__)

CACHE_ENV = "GOF_WARP_CACHE"
CACHE_VERSION = 1  # bump when the pipeline changes what it computes for the same inputs
MATCHING_MODES = ("exhaustive", "pose", "auto")
MIN_PAIR_MATCHES = 4  # fewer raw matches than this in a pair are mostly chance (ratio-test survivors)


class SfmError(SceneError):
    """Triangulation from known poses failed (too few views, no matches, no points)."""


@dataclass
class SfmConfig:
    """How to triangulate sparse points from known poses.

    Defaults were measured on a 2-core CPU (``benchmarks/sfm``): DTU scan 24 (49 views, 800x600) takes
    38 s and gives 6,094 points; pose-chosen pairs (12 per view, 342 pairs) keep 99 % of the points of
    exhaustive matching (1,176 pairs, 6,151 points) at 29 % of its matching time (13 s vs 44 s).

    Attributes:
        max_image_size: SIFT runs on a copy whose longer side is at most this (pixels); keypoints are
            mapped back to full resolution. 1000 keeps DTU (800x600) and the fox (540x960) at full size.
        max_features: SIFT features kept per image (the largest-scale ones).
        matching: ``"exhaustive"`` (all pairs), ``"pose"`` (``pose_neighbors`` nearest overlapping views
            per view, chosen from the poses) or ``"auto"`` (exhaustive up to ``exhaustive_max_views``).
        pose_neighbors: partners per view for ``"pose"`` matching (pairs are symmetric, so a view ends
            up matched with at least this many).
        exhaustive_max_views: the view count up to which ``"auto"`` matches all pairs.
        max_epipolar_error: pixels; a match is kept when its Sampson distance to the epipolar geometry
            of the known poses is at most this (COLMAP's RANSAC default threshold is 4 px).
        min_track_length: a point must be seen in at least this many views (2 keeps two-view points,
            which are noisier; 3 is what COLMAP's triangulator keeps by default).
        max_reprojection_error: pixels; points whose mean reprojection error is larger are dropped.
        min_triangulation_angle: degrees; points whose largest ray angle is smaller are dropped.
        max_ratio: Lowe's ratio test threshold for SIFT matching.
        max_points: keep at most this many points (a random subset, seeded), 0 = all.
    """

    max_image_size: int = 1000
    max_features: int = 4096
    matching: str = "auto"
    pose_neighbors: int = 12
    exhaustive_max_views: int = 40
    max_epipolar_error: float = 4.0
    min_track_length: int = 3
    max_reprojection_error: float = 2.0
    min_triangulation_angle: float = 1.5
    max_ratio: float = 0.8
    max_points: int = 0

    def __post_init__(self):
        def positive_int(name, minimum=1):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < minimum:
                raise GofError(f"SfmConfig.{name} must be an integer >= {minimum}, got {v!r}")
            setattr(self, name, int(v))

        def positive_float(name, upper=None):
            v = getattr(self, name)
            ok = isinstance(v, (int, float, np.floating)) and not isinstance(v, bool) and np.isfinite(v) and v > 0
            if not ok or (upper is not None and v >= upper):
                bound = f" and < {upper}" if upper is not None else ""
                raise GofError(f"SfmConfig.{name} must be a finite number > 0{bound}, got {v!r}")
            setattr(self, name, float(v))

        positive_int("max_image_size", 32)
        positive_int("max_features", 16)
        if self.matching not in MATCHING_MODES:
            raise GofError(f"SfmConfig.matching must be one of {MATCHING_MODES}, got {self.matching!r}")
        positive_int("pose_neighbors")
        positive_int("exhaustive_max_views", 2)
        positive_float("max_epipolar_error")
        positive_int("min_track_length", 2)
        positive_float("max_reprojection_error")
        positive_float("min_triangulation_angle", upper=90.0)
        positive_float("max_ratio", upper=1.0 + 1e-12)
        positive_int("max_points", 0)


@dataclass
class SfmResult:
    """Triangulated points.

    Attributes:
        points: ``[P, 3]`` float64 world coordinates (the scene's frame).
        colors: ``[P, 3]`` uint8 RGB.
        stats: plain data: ``views``, ``pairs`` (matched), ``pairs_verified``, ``features`` (total),
            ``features_per_view``, ``matches``, ``inlier_matches``, ``points``, ``points_raw`` (before
            filtering), ``mean_track_length``, ``mean_reprojection_error_px``, ``seconds`` (per stage),
            ``matching`` (the mode used), ``cached``.
    """

    points: np.ndarray
    colors: np.ndarray
    stats: dict = field(default_factory=dict)


# ------------------------------------------------------------------------------------------ cache keys
def _views_digest(views: list[View]) -> str:
    h = hashlib.sha256()
    for v in views:
        c = v.camera
        h.update(v.name.encode("utf-8") + b"\0")
        h.update(np.ascontiguousarray(c.R, np.float64).tobytes() + np.ascontiguousarray(c.t, np.float64).tobytes())
        h.update(np.array([c.fx, c.fy, c.cx, c.cy, c.width, c.height], np.float64).tobytes())
        h.update(hashlib.sha256(np.ascontiguousarray(v.image).tobytes()).digest())
    return h.hexdigest()


def cache_key(views: list[View], config: SfmConfig) -> str:
    """Hex digest of everything the result depends on: cameras, names, image bytes, config, version."""
    h = hashlib.sha256(f"gof_warp.sfm v{CACHE_VERSION}\0".encode())
    h.update(json.dumps(dataclasses.asdict(config), sort_keys=True).encode())
    h.update(_views_digest(views).encode())
    return h.hexdigest()


def default_cache_dir(scene: Scene) -> Path:
    """Where :func:`triangulate_known_poses` results of ``scene`` are cached (the folder is not created).

    ``$GOF_WARP_CACHE/sfm/<hash>`` when that variable is set; else ``<scene.source>/sfm_known_poses``
    when the scene folder is writable; else ``~/.cache/gof_warp/sfm/<hash>`` (hash of the source path,
    or of the cameras for an in-memory scene).
    """
    src = str(scene.source or "")
    tag = hashlib.sha256((os.path.abspath(src) if src else _views_digest(scene.train)).encode()).hexdigest()[:16]
    root = os.environ.get(CACHE_ENV)
    if root:
        return Path(root).expanduser() / "sfm" / tag
    if src and os.path.isdir(src) and os.access(src, os.W_OK | os.X_OK):
        return Path(src) / "sfm_known_poses"
    return Path.home() / ".cache" / "gof_warp" / "sfm" / tag


def _load_cache(path: Path, key: str) -> SfmResult | None:
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z["key"]) != key:
                raise ValueError("its key does not match this scene and config (stale)")
            points = np.asarray(z["points"], np.float64)
            colors = np.asarray(z["colors"], np.uint8)
            stats = json.loads(str(z["stats"]))
        if points.ndim != 2 or points.shape[1] != 3 or colors.shape != points.shape or not np.all(np.isfinite(points)):
            raise ValueError(f"bad arrays (points {points.shape}, colours {colors.shape})")
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError, EOFError) as e:
        log.warning("sfm cache %s is unusable (%s); recomputing", path, e)
        return None
    stats["cached"] = True
    return SfmResult(points=points, colors=colors, stats=stats)


def _save_cache(path: Path, key: str, result: SfmResult) -> None:
    stats = dict(result.stats, cached=False)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, key=np.array(key), points=result.points, colors=result.colors, stats=np.array(json.dumps(stats)))


# ------------------------------------------------------------------------------------------ pairs
def _viewing_focus(cams: list[Camera]) -> np.ndarray:
    """Least-squares closest point to all principal axes (what an object-centric rig looks at)."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in cams:
        d = c.R[2]
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c.center
    return np.linalg.lstsq(A, b, rcond=None)[0]


def pose_pairs(cams: list[Camera], neighbors: int) -> list[tuple[int, int]]:
    """Index pairs ``(i, j), i < j``: for each view its ``neighbors`` nearest views whose frusta overlap.

    Distance = centre distance / (median camera distance to the focus) + (1 − cos of the angle between
    the viewing directions). Overlap: the point each camera looks at (on its principal axis, at its depth
    of the common focus, or of the median depth when it looks away from it) projects into the other image
    (with a half-image margin). Views with fewer overlapping partners are filled up with the nearest ones.
    """
    n = len(cams)
    centres = np.stack([c.center for c in cams])
    axes = np.stack([c.R[2] for c in cams])
    focus = _viewing_focus(cams) if n > 1 else centres[0] + axes[0]
    depth = np.einsum("ij,ij->i", focus - centres, axes)
    fallback = np.median(depth[depth > 0]) if np.any(depth > 0) else 1.0
    depth = np.where(depth > 1e-6 * max(fallback, 1e-12), depth, fallback)
    targets = centres + depth[:, None] * axes
    scale = max(float(np.median(np.linalg.norm(centres - focus, axis=1))), 1e-12)
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=2) / scale + (1.0 - axes @ axes.T)
    sees = np.zeros((n, n), bool)  # sees[i, j]: target of j inside view i (with margin)
    for i, c in enumerate(cams):
        uv, z = c.project(targets)
        mx, my = 0.5 * c.width, 0.5 * c.height
        sees[i] = (z > 0) & (uv[:, 0] > -mx) & (uv[:, 0] < c.width + mx) & (uv[:, 1] > -my) & (uv[:, 1] < c.height + my)
    overlap = sees | sees.T
    pairs = set()
    k = min(neighbors, n - 1)
    for i in range(n):
        order = [j for j in np.argsort(dist[i], kind="stable") if j != i]
        chosen = [j for j in order if overlap[i, j]][:k]
        chosen += [j for j in order if j not in chosen][: k - len(chosen)]
        pairs.update((min(i, j), max(i, j)) for j in chosen)
    return sorted(pairs)


def _fundamental(c1: Camera, c2: Camera) -> np.ndarray:
    """``F`` with ``x2ᵀ F x1 = 0`` for pixel coordinates of cameras ``c1`` → ``c2``."""
    R = c2.R @ c1.R.T
    t = c2.t - R @ c1.t
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(c2.K).T @ (tx @ R) @ np.linalg.inv(c1.K)


def sampson_distance(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Sampson (first-order geometric) distance in pixels of correspondences ``x1 [M, 2] ↔ x2 [M, 2]``."""
    h1 = np.concatenate([x1, np.ones((len(x1), 1))], axis=1)
    h2 = np.concatenate([x2, np.ones((len(x2), 1))], axis=1)
    Fx1 = h1 @ F.T
    Ftx2 = h2 @ F
    num = np.einsum("ij,ij->i", h2, Fx1) ** 2
    den = Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-300))


# ------------------------------------------------------------------------------------------ pipeline
@contextlib.contextmanager
def _quiet_colmap():
    """Keep COLMAP's (glog) INFO chatter off stderr while it runs; restore the level afterwards."""
    import pycolmap

    old = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = max(old, 1)
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = old


def _write_images(views: list[View], folder: Path) -> list[str]:
    from PIL import Image

    names = []
    for i, v in enumerate(views):
        name = f"{i:05d}.png"  # view names may repeat or hold path characters; ours are unique and flat
        Image.fromarray(v.image).save(folder / name, compress_level=1)
        names.append(name)
    return names


def _run(views: list[View], config: SfmConfig, work: Path, num_threads: int) -> SfmResult:
    import pycolmap

    seconds: dict[str, float] = {}
    tick = time.perf_counter()

    def lap(stage):
        nonlocal tick
        now = time.perf_counter()
        seconds[stage] = round(now - tick, 3)
        tick = now

    image_dir, db_path, out_dir = work / "images", work / "database.db", work / "out"
    image_dir.mkdir()
    out_dir.mkdir()
    names = _write_images(views, image_dir)
    lap("write_images")

    n = len(views)
    log.info("sfm: SIFT on %d views (max side %d px, %d features)", n, config.max_image_size, config.max_features)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = config.max_image_size
    extraction.num_threads = num_threads
    extraction.sift.max_num_features = config.max_features
    reader = pycolmap.ImageReaderOptions(camera_model="PINHOLE")
    pycolmap.extract_features(db_path, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.PER_IMAGE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)  # fmt: skip
    db = pycolmap.Database.open(db_path)
    try:
        by_name = {im.name: im for im in db.read_all_images()}
        missing = [nm for nm in names if nm not in by_name]
        if missing:
            raise SfmError(f"COLMAP feature extraction skipped {len(missing)} image(s) (e.g. view {views[names.index(missing[0])].name!r})")
        image_ids = [by_name[nm].image_id for nm in names]
        camera_ids = [by_name[nm].camera_id for nm in names]
        for v, cid in zip(views, camera_ids):
            cam = db.read_camera(cid)
            c = v.camera
            cam.params = [c.fx, c.fy, c.cx, c.cy]
            cam.has_prior_focal_length = True
            db.update_camera(cam)
        features = [int(db.num_keypoints_for_image(i)) for i in image_ids]
    finally:
        db.close()
    lap("extract")

    mode = config.matching
    if mode == "auto":
        mode = "exhaustive" if n <= config.exhaustive_max_views else "pose"
    cams = [v.camera for v in views]
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)] if mode == "exhaustive" else pose_pairs(cams, config.pose_neighbors)
    pairs_file = work / "pairs.txt"
    pairs_file.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    log.info("sfm: matching %d pairs (%s)", len(pairs), mode)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = num_threads
    matching.skip_geometric_verification = True
    matching.sift.max_ratio = config.max_ratio
    # COLMAP drops the matches of a pair with fewer than min_num_inliers even when it skips verification;
    # with known poses a pair with a handful of matches is still useful.
    verification = pycolmap.TwoViewGeometryOptions()
    verification.min_num_inliers = MIN_PAIR_MATCHES
    pycolmap.match_image_pairs(db_path, matching_options=matching,
                               pairing_options=pycolmap.ImportedPairingOptions(match_list_path=pairs_file),
                               verification_options=verification, device=pycolmap.Device.cpu)  # fmt: skip
    lap("match")

    # Verification against the known epipolar geometry (replaces RANSAC).
    db = pycolmap.Database.open(db_path)
    n_matches = n_inliers = n_verified = 0
    try:
        keypoints = [np.asarray(db.read_keypoints(i))[:, :2].astype(np.float64) for i in image_ids]
        for i, j in pairs:
            # columns: keypoint index in view i, in view j (pycolmap swaps stored pairs as needed)
            m = np.asarray(db.read_matches(image_ids[i], image_ids[j]), dtype=np.uint32).reshape(-1, 2)
            n_matches += len(m)
            if len(m) == 0:
                continue
            F = _fundamental(cams[i], cams[j])
            err = sampson_distance(F, keypoints[i][m[:, 0]], keypoints[j][m[:, 1]])
            inl = np.ascontiguousarray(m[err <= config.max_epipolar_error])
            if len(inl) == 0:
                continue
            geometry = pycolmap.TwoViewGeometry()
            geometry.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
            geometry.inlier_matches = inl
            geometry.F = F
            db.write_two_view_geometry(image_ids[i], image_ids[j], geometry)
            n_inliers += len(inl)
            n_verified += 1
    finally:
        db.close()
    lap("verify")
    if n_inliers == 0:
        raise SfmError(
            f"no feature matches agree with the known poses among {len(pairs)} pairs of {n} views "
            f"({n_matches} raw matches, {sum(features)} features): textureless images or wrong poses? "
            f"Use model.init=random instead"
        )

    log.info("sfm: triangulating %d verified matches in %d pairs", n_inliers, n_verified)
    rec = pycolmap.Reconstruction()
    db = pycolmap.Database.open(db_path)
    try:
        for k, c in enumerate(cams):
            rec.add_camera_with_trivial_rig(db.read_camera(camera_ids[k]))
            image = pycolmap.Image(name=names[k], camera_id=camera_ids[k], image_id=image_ids[k])
            rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(c.R), c.t))
    finally:
        db.close()
    options = pycolmap.IncrementalPipelineOptions()
    options.num_threads = num_threads
    options.ba_refine_focal_length = False
    options.ba_refine_principal_point = False
    options.ba_refine_extra_params = False
    options.min_num_matches = 1
    options.triangulation.ignore_two_view_tracks = config.min_track_length > 2
    options.triangulation.min_angle = config.min_triangulation_angle
    options.mapper.filter_min_tri_angle = config.min_triangulation_angle
    options.mapper.filter_max_reproj_error = max(config.max_reprojection_error, 1e-3)
    rec = pycolmap.triangulate_points(rec, db_path, image_dir, out_dir, clear_points=True, options=options,
                                      refine_intrinsics=False)  # fmt: skip
    lap("triangulate")

    _check_poses_unchanged(rec, image_ids, cams)
    pts = list(rec.points3D.values())
    raw = len(pts)
    keep = [p for p in pts if p.track.length() >= config.min_track_length and p.error <= config.max_reprojection_error]
    if not keep:
        raise SfmError(
            f"no points triangulated from {n} views ({n_inliers} verified matches, {raw} points before filtering "
            f"by track length >= {config.min_track_length} and reprojection error <= {config.max_reprojection_error} px); "
            f"use model.init=random instead"
        )
    points = np.array([p.xyz for p in keep], np.float64).reshape(-1, 3)
    colors = np.array([p.color for p in keep], np.uint8).reshape(-1, 3)
    tracks = np.array([p.track.length() for p in keep], np.float64)
    errors = np.array([p.error for p in keep], np.float64)
    if config.max_points and len(points) > config.max_points:
        sel = np.sort(np.random.default_rng(0).choice(len(points), config.max_points, replace=False))
        points, colors, tracks, errors = points[sel], colors[sel], tracks[sel], errors[sel]
    stats = {
        "views": n,
        "matching": mode,
        "pairs": len(pairs),
        "pairs_verified": n_verified,
        "features": int(sum(features)),
        "features_per_view": round(sum(features) / n, 1),
        "matches": int(n_matches),
        "inlier_matches": int(n_inliers),
        "points_raw": raw,
        "points": int(len(points)),
        "mean_track_length": round(float(tracks.mean()), 3),
        "mean_reprojection_error_px": round(float(errors.mean()), 4),
        "seconds": seconds,
        "cached": False,
    }
    return SfmResult(points=points, colors=colors, stats=stats)


def _check_poses_unchanged(rec, image_ids: list[int], cams: list[Camera]) -> None:
    """Known poses are inputs: fail loudly if the triangulator's bundle adjustment moved any of them."""
    worst = 0.0
    for iid, c in zip(image_ids, cams):
        cfw = rec.images[iid].cam_from_world
        m = np.asarray((cfw() if callable(cfw) else cfw).matrix())
        worst = max(worst, float(np.abs(m[:, :3] - c.R).max()), float(np.abs(m[:, 3] - c.t).max() / max(1.0, np.abs(c.t).max())))
    if worst > 1e-6:
        raise SfmError(f"COLMAP changed the known camera poses during triangulation (by up to {worst:.3g})")


def triangulate_known_poses(views: list[View], config: SfmConfig | None = None, *, cache_dir: Path | None = None,
                            num_threads: int = -1) -> SfmResult:  # fmt: skip
    """Sparse points and colours triangulated from ``views`` with their poses held fixed.

    Args:
        views: posed, undistorted images (e.g. ``scene.train``); all pixels are used (no masks), since
            background points are what random initialisation cannot reach.
        config: :class:`SfmConfig` (defaults if None).
        cache_dir: folder for the cached result (``sfm_<key>.npz``); None = no caching. See
            :func:`default_cache_dir`.
        num_threads: CPU threads for SIFT, matching and triangulation (-1 = all cores).

    Returns:
        :class:`SfmResult` with ``points [P, 3]`` float64 world, ``colors [P, 3]`` uint8 and ``stats``.

    Raises:
        SfmError: fewer than 2 views, no verified matches, or no point survives filtering.
    """
    config = config or SfmConfig()
    if not isinstance(config, SfmConfig):
        raise TypeError(f"config must be an SfmConfig, got {type(config).__name__}")
    views = list(views)
    if len(views) < 2:
        raise SfmError(f"triangulation needs at least 2 views, got {len(views)}; use model.init=random instead")
    if isinstance(num_threads, bool) or not isinstance(num_threads, int) or num_threads == 0 or num_threads < -1:
        raise GofError(f"num_threads must be -1 (all cores) or a positive integer, got {num_threads!r}")

    key = cache_key(views, config)
    path = Path(cache_dir) / f"sfm_{key[:24]}.npz" if cache_dir is not None else None
    if path is not None:
        cached = _load_cache(path, key)
        if cached is not None:
            log.info("sfm: %d points from cache %s", len(cached.points), path)
            return cached

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="gof_warp_sfm_") as tmp, _quiet_colmap():
        result = _run(views, config, Path(tmp), num_threads)
    result.stats["seconds"]["total"] = round(time.perf_counter() - t0, 3)
    s = result.stats
    log.info("sfm: %d points (mean track %.2f, reprojection %.3f px) from %d views in %.1f s",
             s["points"], s["mean_track_length"], s["mean_reprojection_error_px"], s["views"], s["seconds"]["total"])  # fmt: skip
    if path is not None:
        try:
            _save_cache(path, key, result)
        except (OSError, GofError) as e:
            log.warning("sfm: could not write cache %s (%s); continuing without it", path, e)
    return result


__all__ = ["SfmConfig", "SfmError", "SfmResult", "cache_key", "default_cache_dir", "pose_pairs", "triangulate_known_poses"]
