"""Where the first Gaussians go: SfM points, triangulated points, background points or a random box.

3DGS and GOF start from the sparse points of structure-from-motion; scenes without them (Blender,
instant-ngp, DTU/NeuS) get points triangulated from their known poses (:mod:`gof_warp.data.sfm`), and a
random box only where asked. Sparse points rarely reach the far background of a capture (sky, distant walls),
which a box around the object cannot reach either: :func:`background_points` adds points on a sphere beyond
the cameras in the directions the cameras see and the initial points do not cover, coloured from the photos.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from ..core.camera import Camera
from ..core.errors import GofError
from ..core.scene import Scene

log = logging.getLogger(__name__)

# Triangulation that finds fewer points than this is not a usable start ("auto" then stops with an error).
MIN_SFM_POINTS = 100
# How to go on when "auto" cannot get measured points. A random start is never taken silently: on real captures it
# costs many dB of PSNR, so the user must ask for it.
_FIX = ("Install pycolmap (pip install pycolmap), or give the scene a COLMAP model with points3D (or a points3d.ply), "
        "or pass model.init=random to accept a random start.")


def camera_focus(cameras: list[Camera]) -> np.ndarray:
    """``[3]`` the least-squares closest point to all principal axes (what an inward-facing rig looks at);
    one camera: a unit in front of it."""
    centres = np.stack([c.center for c in cameras])
    axes = np.stack([c.R[2] for c in cameras])  # viewing directions in world space
    if len(cameras) == 1:
        return centres[0] + axes[0]
    projectors = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    A, b = projectors.sum(0), np.einsum("nij,nj->i", projectors, centres)
    return np.linalg.lstsq(A, b, rcond=None)[0]


def default_init_box(scene: Scene) -> np.ndarray:
    """``[6]`` a box around what the cameras look at: :func:`camera_focus` ± 0.5 × the mean camera distance
    to it (object-centric captures)."""
    cams = scene.train_cameras
    focus = camera_focus(cams)
    half = 0.5 * float(np.mean(np.linalg.norm(np.stack([c.center for c in cams]) - focus, axis=1)))
    return np.concatenate([focus - half, focus + half])


def fibonacci_sphere(n: int) -> np.ndarray:
    """``[n, 3]`` unit vectors spread evenly over the sphere."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _sample_colours(points: np.ndarray, scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Mean photo colour of each point over the train views that see it: ``(colours [P, 3] uint8,
    seen count [P])`` (occlusion is not tested: background points lie behind everything)."""
    acc = np.zeros((len(points), 3))
    count = np.zeros(len(points), dtype=np.int64)
    for v in scene.train:
        uv, _, ok = v.camera.in_image(points)
        ij = np.floor(uv[ok]).astype(np.int64)
        acc[ok] += v.image[ij[:, 1], ij[:, 0]].astype(np.float64)
        count[ok] += 1
    colours = np.where(count[:, None] > 0, acc / np.maximum(count, 1)[:, None], 127.0)
    return np.clip(np.rint(colours), 0, 255).astype(np.uint8), count


def background_points(scene: Scene, n: int, existing: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points for the far background: ``(points [P, 3], colours [P, 3] uint8)`` with ``P ≤ n``.

    Candidates are ``n`` directions spread over the sphere around the cameras' focus, placed at radius
    ``R = max(2 × the largest camera distance from the focus, 1.05 × the farthest initial point)``. A
    candidate is kept when some train camera sees it and no initial point farther than the cameras lies
    within its angular spacing (there SfM has already found background). Colours: the mean photo colour of
    the views that see it.
    """
    if n <= 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    cams = scene.train_cameras
    focus = camera_focus(cams)
    cam_radius = float(np.max(np.linalg.norm(np.stack([c.center for c in cams]) - focus, axis=1)))
    radius = 2.0 * max(cam_radius, 1e-6)
    dirs = fibonacci_sphere(n)
    keep = np.ones(n, dtype=bool)
    if existing is not None and len(existing):
        rel = np.asarray(existing, np.float64) - focus
        dist = np.linalg.norm(rel, axis=1)
        radius = max(radius, 1.05 * float(dist.max()))
        far = rel[dist > cam_radius] / dist[dist > cam_radius, None]
        if len(far):
            from scipy.spatial import cKDTree

            spacing = math.sqrt(4.0 * math.pi / n)  # chord ≈ angle between neighbouring candidates
            keep &= ~np.isfinite(cKDTree(far).query(dirs, k=1, distance_upper_bound=spacing)[0])
    pts = focus + radius * dirs[keep]
    colours, seen = _sample_colours(pts, scene)
    return pts[seen > 0], colours[seen > 0]


def views_seeing_points(points: np.ndarray, cameras) -> np.ndarray:
    """``[P]`` int: how many of ``cameras`` hold each of ``points [P, 3]`` in their image, in front of them."""
    count = np.zeros(len(points), dtype=np.int64)
    for cam in cameras:
        count += cam.in_image(points)[2]
    return count


#: rounds of redrawing the random points that too few cameras see; those still unseen after them are left out
_REDRAW_ROUNDS = 256
#: far random points (``random_far_fraction``) reach this many times the largest camera distance from the focus
FAR_REACH = 20.0


def _in_box(box: np.ndarray, rng):
    """A sampler ``n -> [n, 3]``: uniform in ``box`` (xmin, ymin, zmin, xmax, ymax, zmax)."""
    return lambda n: box[:3] + (box[3:] - box[:3]) * rng.random((n, 3))


def _far(box: np.ndarray, scene: Scene, rng):
    """A sampler ``n -> [n, 3]``: around the box's centre ``c``, in uniformly random directions, at distances
    log-uniform in ``[r0, r1]``: ``r0`` the box's half-diagonal, ``r1 = FAR_REACH`` × the largest distance of a training
    camera from ``c`` (as many points per doubling of the distance: the far background a capture sees, where SfM
    finds points and a box start has none)."""
    c = 0.5 * (box[:3] + box[3:])
    r0 = 0.5 * float(np.linalg.norm(box[3:] - box[:3]))
    r1 = max(FAR_REACH * float(np.max(np.linalg.norm(np.stack([v.center for v in scene.train_cameras]) - c, axis=1))),
             2.0 * r0)

    def draw(n: int) -> np.ndarray:
        d = rng.normal(size=(n, 3))
        d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
        return c + d * np.exp(rng.uniform(math.log(r0), math.log(r1), size=(n, 1)))
    return draw


def _redraw_unseen(points: np.ndarray, draw, scene: Scene, min_views: int, where: str) -> np.ndarray:
    """``points`` with each one that fewer than ``min_views`` training cameras see drawn again by ``draw(n)`` (which
    continues the run's generator: nothing is drawn where every point is seen already). Points still unseen after
    :data:`_REDRAW_ROUNDS` rounds are left out (a region mostly outside the views); none seen at all is an error
    naming ``where`` they were drawn."""
    cams = scene.train_cameras
    points = points.copy()
    todo = np.flatnonzero(views_seeing_points(points, cams) < min_views)
    for _ in range(_REDRAW_ROUNDS):
        if not len(todo):
            return points
        points[todo] = draw(len(todo))
        todo = todo[views_seeing_points(points[todo], cams) < min_views]
    if len(todo) == len(points):
        raise GofError(f"model.init=random: no point {where} is seen by {min_views} training cameras "
                       f"(model.random_min_views): set model.init_box to the region the cameras look at, or "
                       f"model.random_min_views=0")
    log.info("model.init=random: %d of %d random points left out: fewer than %d training cameras see them",
             len(todo), len(points), min_views)
    return np.delete(points, todo, axis=0)


def initial_point_cloud(scene: Scene, init: str, *, random_points: int, init_box=None, background: int = 0,
                        seed: int = 0, sfm_config=None, min_views: int = 0, far_fraction: float = 0.0) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """The initial points of a run: ``(points [P, 3], colours [P, 3] (uint8, or float in [0, 1]) or None, info)``.

    ``init`` is ``ModelConfig.init`` (``"auto" | "sfm" | "random"``, see there); ``info`` says what was used
    (``source``: ``scene`` / ``triangulated`` / ``random``, counts, and the triangulation's statistics), for
    the run's ``metrics.json`` and log. ``min_views > 0``: random points are drawn only where at least that many
    training cameras see them (:func:`views_seeing_points`), as SfM points are seen by two views or more.
    ``far_fraction``: that fraction of the random points lies beyond the box, out to the far background
    (:func:`_far`: log-uniform distances), where a capture's background is.
    """
    info: dict = {"init": init}
    points = colours = None
    if init in ("auto", "sfm"):
        if scene.points is not None and len(scene.points) > 0:
            points, colours, info["source"] = scene.points, scene.point_colors, "scene"
        else:
            from .sfm import default_cache_dir, triangulate_known_poses

            try:
                result = triangulate_known_poses(scene.train, sfm_config, cache_dir=default_cache_dir(scene))
            except GofError as e:
                if init == "sfm":
                    raise
                raise GofError(f"model.init=auto: the scene has no sparse points and triangulation from its known "
                               f"poses failed ({e}). {_FIX}") from None
            info["sfm"] = result.stats
            if len(result.points) < MIN_SFM_POINTS and init == "auto":
                raise GofError(f"model.init=auto: triangulation from the known poses found only {len(result.points)} "
                               f"points (< {MIN_SFM_POINTS}). Pass model.init=sfm to start from them anyway; or "
                               f"{_FIX[0].lower()}{_FIX[1:]}")
            points, colours, info["source"] = result.points, result.colors, "triangulated"
    if points is None:
        box = np.asarray(init_box, float) if init_box is not None else default_init_box(scene)
        if box.shape != (6,) or np.any(box[3:] <= box[:3]):
            raise GofError(f"model.init_box must be (xmin, ymin, zmin, xmax, ymax, zmax) with max > min, got {box.tolist()}")
        rng = np.random.default_rng(seed)
        n_far = int(round(far_fraction * random_points))
        in_box = _in_box(box, rng)
        points = in_box(random_points - n_far)
        if min_views > 0:
            points = _redraw_unseen(points, in_box, scene, min_views, f"of model.init_box {box.tolist()}")
        if n_far:
            far = _far(box, scene, rng)
            far_points = far(n_far)
            if min_views > 0:
                far_points = _redraw_unseen(far_points, far, scene, min_views, "beyond model.init_box")
            points = np.concatenate([points, far_points])
            info["random_far_points"] = int(len(far_points))
        colours = rng.random((len(points), 3))  # as Gaussians.random_in_box: same draws, same model
        info["source"] = "random"
        if min_views > 0:
            info["random_min_views"] = min_views
    info["points"] = int(len(points))
    if background > 0:
        bg, bg_col = background_points(scene, background, points if info["source"] != "random" else None)
        info["background_points"] = int(len(bg))
        if len(bg):
            points, colours = np.concatenate([points, bg]), np.concatenate([_unit_rgb(colours, len(points)),
                                                                            _unit_rgb(bg_col, len(bg))])
    return np.asarray(points, np.float64), colours, info


def _unit_rgb(colours, n: int) -> np.ndarray:
    """``[n, 3]`` float RGB in [0, 1] from uint8, float or None (grey)."""
    if colours is None:
        return np.full((n, 3), 0.5)
    c = np.asarray(colours)
    return c.astype(np.float64) / 255.0 if c.dtype == np.uint8 else c.astype(np.float64)
