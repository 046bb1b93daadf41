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

Modules: this one (the entry :func:`triangulate_known_poses` and the cache); :mod:`~gof_warp.data.sfm_config`
(:class:`SfmConfig`, :class:`SfmResult`, :class:`SfmError`); :mod:`~gof_warp.data.sfm_geometry` (pairs,
epipolar distance; numpy); :mod:`~gof_warp.data.sfm_colmap` (the pycolmap pipeline). The public names of all
four are importable from here.

Results are cached as ``.npz`` (no pickle) in ``cache_dir``, keyed by a hash of the cameras, image names,
image bytes and the :class:`SfmConfig`, so the work runs once per scene. Memory: the temporary PNGs and
the SQLite database live on disk; pycolmap holds the features of one matching block at a time.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

from ..core.errors import GofError
from ..core.io_utils import atomic_path
from ..core.scene import Scene, View
from .sfm_colmap import MIN_PAIR_MATCHES, _quiet_colmap, _run  # noqa: F401 - MIN_PAIR_MATCHES re-exported
from .sfm_config import MATCHING_MODES, SfmConfig, SfmError, SfmResult  # noqa: F401 - re-exported
from .sfm_geometry import pose_pairs, sampson_distance  # noqa: F401 - re-exported

log = logging.getLogger(__name__)

CACHE_ENV = "GOF_WARP_CACHE"
CACHE_VERSION = 1  # bump when the pipeline changes what it computes for the same inputs


# ------------------------------------------------------------------------------------------ cache keys
CAMERA_DIGITS = 7  # decimals of the camera values in the cache key


def _views_digest(views: list[View]) -> str:
    """Digest of the views' names, cameras and images. A cache carried with the scene must be found on another
    machine, so cameras are rounded to ``CAMERA_DIGITS`` decimals (the same poses read there can differ in the last
    bits: the pose inversion's floating-point order) and negative zeros made positive (a tiny negative value there
    rounds to ``-0.0``, whose bytes differ from ``0.0``), and an image decoded from a file is identified by the file's
    bytes and decoding settings (:class:`~gof_warp.core.scene.ImageSource`: another JPEG decoder may round some pixels the
    other way). An image made in memory, or whose file is gone, is identified by its pixels."""
    h = hashlib.sha256()
    for v in views:
        c = v.camera
        h.update(v.name.encode("utf-8") + b"\0")
        pose = np.concatenate([np.asarray(c.R, np.float64).ravel(), np.asarray(c.t, np.float64).ravel(),
                               np.array([c.fx, c.fy, c.cx, c.cy, c.width, c.height], np.float64)])
        h.update((np.round(pose, CAMERA_DIGITS) + 0.0).tobytes())  # + 0.0: -0.0 (and what rounds to it) → 0.0
        file_digest = v.source.digest() if v.source is not None else None
        if file_digest is not None:
            h.update(b"file\0" + file_digest.encode())
        else:
            h.update(b"pixels\0" + hashlib.sha256(np.ascontiguousarray(v.image).tobytes()).digest())
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


__all__ = ["SfmConfig", "SfmError", "SfmResult", "cache_key", "default_cache_dir", "pose_pairs", "sampson_distance",
           "triangulate_known_poses"]
