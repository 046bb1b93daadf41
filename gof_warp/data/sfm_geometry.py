"""The two-view geometry of triangulation from known poses (numpy only): which view pairs to match, and how
far a match lies from the epipolar geometry of the two given cameras.

* :func:`pose_pairs` chooses, for each view, its nearest views whose frusta overlap (``SfmConfig.matching =
  "pose"``), from the poses alone.
* :func:`sampson_distance` with the fundamental matrix of two known cameras (:func:`_fundamental`) is the
  test that replaces RANSAC in :mod:`gof_warp.data.sfm_colmap` (the relative pose is known).

Conventions (:mod:`gof_warp.core.camera`): world-to-camera ``R, t``, OpenCV axes, pixel centres at ``i + 0.5``.
"""

from __future__ import annotations

import numpy as np

from ..core.camera import Camera


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
