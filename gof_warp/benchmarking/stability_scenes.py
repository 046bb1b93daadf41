"""The small world of the stability suites (:mod:`gof_warp.benchmarking.stability`, :mod:`gof_warp.benchmarking.stability_inputs`): a ring of
cameras around the origin and a "good" model, Gaussians on a sphere, that every hand-made case perturbs."""

from __future__ import annotations

import numpy as np

BLOB_RADIUS = 0.5  # the good model: Gaussians on a sphere of this radius (stability.FAR_RADIUS bounds its mesh)
CAMERA_DISTANCE = 2.5


def ring_cameras(n: int = 8, size: int = 32):
    """``n`` cameras around the origin at ``CAMERA_DISTANCE``, alternating elevation, looking at it."""
    from ..core.camera import look_at

    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        e = 0.6 * (-1) ** k
        eye = CAMERA_DISTANCE * np.array([np.cos(a) * np.cos(e), np.sin(a) * np.cos(e), np.sin(e)])
        cams.append(look_at(eye, [0, 0, 0], fx=0.9 * size, width=size, height=size, name=f"s{k:02d}"))
    return cams


def _blob(n: int = 300, seed: int = 0):
    """``(means, rotations, scales, opacities)`` of ``n`` Gaussians on a sphere of radius ``BLOB_RADIUS``."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    q = rng.normal(size=(n, 4))
    return BLOB_RADIUS * d, q / np.linalg.norm(q, axis=1, keepdims=True), np.full((n, 3), 0.08), np.full(n, 0.9)
