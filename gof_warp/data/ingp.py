"""instant-ngp / nerfstudio ``transforms.json`` (and the frame parsing shared with Blender files).

Intrinsics, read from the top level and overridden per frame where a frame has its own:

* ``fl_x``, ``fl_y`` (pixels) — else ``camera_angle_x`` (→ ``fx = W / (2 tan(angle_x / 2))``) and
  ``camera_angle_y`` (else ``fy = fx``);
* ``cx``, ``cy`` (pixels, COLMAP's convention: pixel centres at ``i + 0.5``, as instant-ngp's colmap2nerf
  copies them) — else the image centre;
* ``w``, ``h`` — else the image file's size;
* OpenCV distortion ``k1 k2 [k3] p1 p2`` → the images are undistorted (``gof_warp.data.undistort``).
  ``camera_model`` ``OPENCV_FISHEYE``/``EQUIRECTANGULAR``, ``is_fisheye`` or a non-zero ``k4`` are refused.

Poses: ``transform_matrix`` is camera-to-world with OpenGL camera axes (x right, y up, z back), used as is.
instant-ngp itself rescales (``scale``, default 0.33), offsets (``offset``) and cycles the axes of these
poses when it loads them, to fit its unit cube; we do **not** reproduce that: cameras stay in the file's
world frame, which is consistent across views, and ``aabb_scale``, ``scale`` and ``offset`` are ignored.

Per-frame ``mask_path`` (nerfstudio) is loaded as the mask. RGBA images are composited on the background
colour, alpha kept as the mask. Initial points: none (``points3d.ply`` next to the json is used if present).
Frames are sorted by ``file_path``; the test split is every ``test_every``-th of that order.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..core.camera import Camera
from ..core.errors import SceneError
from . import images as imio
from .plan import ScenePlan, ViewPlan
from .undistort import LensCamera, undistorted_intrinsics

_UNSUPPORTED_MODELS = ("OPENCV_FISHEYE", "EQUIRECTANGULAR", "FISHEYE")
_DISTORTION_KEYS = ("k1", "k2", "k3", "p1", "p2")


def read_json(path: Path) -> dict:
    """Load a JSON file; :class:`SceneError` naming the file (and line) when it is missing or invalid."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except FileNotFoundError:
        raise SceneError(f"{path}: file not found") from None
    except json.JSONDecodeError as e:
        raise SceneError(f"{path}: invalid JSON at line {e.lineno}, column {e.colno}: {e.msg}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError(f"{path}: cannot read: {e}") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise SceneError(f"{path}: expected an object with a 'frames' list")
    return data


def _number(d: dict, key: str, where: str):
    v = d.get(key)
    if v is None:
        return None
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise SceneError(f"{where}: '{key}' must be a number, got {v!r}") from None
    if not math.isfinite(v):
        raise SceneError(f"{where}: '{key}' is not finite")
    return v


def frame_camera(top: dict, frame: dict, image_path: Path, where: str, undistort_mode: str):
    """Pinhole camera (undistorted K) and lens (or None) of one frame; returns ``(camera, lens, model)``."""
    merged = {**top, **{k: v for k, v in frame.items() if k != "frames"}}
    model = str(merged.get("camera_model", "")).upper()
    if model in _UNSUPPORTED_MODELS or merged.get("is_fisheye") or (_number(merged, "k4", where) or 0.0) != 0.0:
        raise SceneError(f"{where}: unsupported camera model {model or 'fisheye'!r} (supported: PINHOLE, OPENCV)")
    w, h = _number(merged, "w", where), _number(merged, "h", where)
    if w is None or h is None:
        header = imio.read_header(image_path)
        w, h = float(header.width), float(header.height)
    w, h = int(round(w)), int(round(h))
    fx, fy = _number(merged, "fl_x", where), _number(merged, "fl_y", where)
    if fx is None:
        angle_x = _number(merged, "camera_angle_x", where)
        if angle_x is None:
            raise SceneError(f"{where}: no focal length (need 'fl_x' or 'camera_angle_x')")
        fx = 0.5 * w / math.tan(0.5 * angle_x)
    if fy is None:
        angle_y = _number(merged, "camera_angle_y", where)
        fy = fx if angle_y is None or "fl_x" in merged else 0.5 * h / math.tan(0.5 * angle_y)
    cx = _number(merged, "cx", where)
    cy = _number(merged, "cy", where)
    cx = w / 2.0 if cx is None else cx
    cy = h / 2.0 if cy is None else cy
    dist = {k: _number(merged, k, where) or 0.0 for k in _DISTORTION_KEYS}
    try:
        c2w = np.asarray(frame["transform_matrix"], dtype=np.float64) if "transform_matrix" in frame else None
    except (TypeError, ValueError):  # strings, ragged rows, nested objects
        c2w = None
    if c2w is None or c2w.shape not in ((4, 4), (3, 4)) or not np.all(np.isfinite(c2w)):
        got = frame.get("transform_matrix")
        raise SceneError(f"{where}: 'transform_matrix' must be a finite 4x4 or 3x4 matrix of numbers, "
                         f"got {str(got)[:80] if 'transform_matrix' in frame else 'none'}")
    lens = LensCamera(fx=fx, fy=fy, cx=cx, cy=cy, width=w, height=h, model="OPENCV", **dist)
    name = Path(str(frame.get("file_path", ""))).with_suffix("").as_posix()
    if lens.has_distortion:
        pfx, pfy, pcx, pcy = undistorted_intrinsics(lens, undistort_mode)
    else:
        pfx, pfy, pcx, pcy, lens = fx, fy, cx, cy, None
    try:
        cam = Camera.from_c2w(c2w, pfx, pfy, pcx, pcy, w, h, name=name, opengl=True)
    except SceneError as e:
        raise SceneError(f"{where}: {e}") from None
    return cam, lens, ("OPENCV" if lens is not None else "PINHOLE")


def frames_to_views(json_path: Path, data: dict, config, split: str | None = None) -> tuple[list[ViewPlan], list[str]]:
    """Every frame of a transforms file → :class:`ViewPlan` (in file order); also the camera model names."""
    views, models = [], []
    for i, frame in enumerate(data["frames"]):
        where = f"{json_path} frame {i}"
        if not isinstance(frame, dict) or "file_path" not in frame:
            raise SceneError(f"{where}: frame without 'file_path'")
        allow = config.allow_outside_paths
        rel = imio.check_inside(str(frame["file_path"]), json_path.parent, f"{where} 'file_path'", allow)
        image_path = imio.find_image(json_path.parent, str(rel))
        if not image_path.exists():
            raise SceneError(f"{image_path}: image file not found (frame {i} of {json_path})")
        imio.check_regular_file(image_path)
        cam, lens, model = frame_camera(data, frame, image_path, where, config.undistort)
        mask_path = None
        if frame.get("mask_path"):
            rel = imio.check_inside(str(frame["mask_path"]), json_path.parent, f"{where} 'mask_path'", allow)
            mask_path = imio.find_image(json_path.parent, str(rel))
        views.append(ViewPlan(name=cam.name, camera=cam, image_path=image_path, lens=lens, mask_path=mask_path, split=split))
        models.append(model)
    names = [v.name for v in views]
    if len(set(names)) != len(names):
        raise SceneError(f"{json_path}: some frames share the same file_path")
    return views, models


def load_points_ply(path: Path):
    """``(points [P, 3] float64, colors [P, 3] uint8 or None)`` from a point-cloud PLY (e.g. 3DGS's points3d.ply)."""
    import trimesh

    try:
        pc = trimesh.load(path, process=False)
    except Exception as e:  # trimesh raises many types for bad files
        raise SceneError(f"{path}: cannot read point cloud: {e}") from None
    pts = np.asarray(getattr(pc, "vertices", np.zeros((0, 3))), dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0 or not np.all(np.isfinite(pts)):
        raise SceneError(f"{path}: expected a non-empty point cloud with finite xyz")
    colors = getattr(pc, "colors", None)
    if colors is not None and len(colors) == len(pts):
        colors = np.asarray(colors)[:, :3].astype(np.uint8)
    else:
        colors = None
    return pts, colors


def read_ingp(root: Path, config) -> ScenePlan:
    """Parse ``root/transforms.json`` (see the module docstring)."""
    json_path = root / "transforms.json"
    data = read_json(json_path)
    views, models = frames_to_views(json_path, data, config)
    order = np.argsort([str(v.image_path) for v in views], kind="stable")
    views, models = [views[i] for i in order], [models[i] for i in order]
    plan = ScenePlan(format="ingp", source=root, views=views, camera_models=sorted(set(models)))
    ply = root / "points3d.ply"
    if ply.is_file():
        plan.points, plan.point_colors = load_points_ply(ply)
    if any(v.lens is not None for v in views):
        plan.warnings.append(f"lens distortion removed ({config.undistort!r} pinhole K)")
    return plan
