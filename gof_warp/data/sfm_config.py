"""The settings, result and error of triangulation from known poses (:mod:`gof_warp.data.sfm`).

Plain data, shared by the pipeline (:mod:`gof_warp.data.sfm_colmap`), the cache and the public entry
:func:`gof_warp.data.sfm.triangulate_known_poses` (which re-exports these names).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import GofError, SceneError

MATCHING_MODES = ("exhaustive", "pose", "auto")


class SfmError(SceneError):
    """Triangulation from known poses failed (too few views, no matches, no points)."""


@dataclass
class SfmConfig:
    """How to triangulate sparse points from known poses.

    Defaults were measured on a 2-core CPU (``benchmarks/RESULTS.md``, section 7): DTU scan 24 (49 views, 800x600)
    takes 38 s and gives 6,094 points; pose-chosen pairs (12 per view, 342 pairs) keep 99 % of the points of
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
