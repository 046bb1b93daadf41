"""COLMAP sparse models (binary or text, read by :mod:`gof_warp.data.colmap_model`: no pycolmap needed).

Layout: ``SCENE/sparse/0/`` (or ``SCENE/sparse/``, or ``SCENE`` itself) holds ``cameras``, ``images``,
``points3D`` as ``.bin`` or ``.txt``; the images are in ``SCENE/<images>/`` (``config.images``, default
``images``; also looked for next to the model folder). Images stored at another resolution than the
cameras (``images_2``, ``images_4`` …) get their intrinsics scaled, when the aspect ratio agrees.

Camera models: ``SIMPLE_PINHOLE``, ``PINHOLE`` are used directly; ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``
and ``FULL_OPENCV`` with ``k4 = k5 = k6 = 0`` are undistorted to a pinhole camera (``gof_warp.data.undistort``).
Fisheye and other models raise :class:`SceneError`. Unlike GOF (which ignores ``cx, cy``), the principal
point is kept.

Registered images only, sorted by name (GOF/3DGS order; the ``--eval`` split is ``index % 8 == 0``);
names containing ``sky_mask`` are skipped as in GOF. RGBA images are used as RGB with alpha as the mask (not
composited), as 3DGS does. Initial points and colours come from ``points3D``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.camera import Camera
from ..core.errors import SceneError
from . import images as imio
from .colmap_model import ColmapImage, quaternion_to_rotation, read_model
from .plan import ScenePlan, ViewPlan
from .undistort import LensCamera, undistorted_intrinsics

PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
DISTORTED_MODELS = ("SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV")
_MODEL_FILES = ("cameras.bin", "cameras.txt")


def find_model_dir(root: Path) -> Path | None:
    """The folder holding the sparse model: ``root/sparse/0``, ``root/sparse`` or ``root``; None if none."""
    for d in (root / "sparse" / "0", root / "sparse", root):
        if any((d / f).is_file() for f in _MODEL_FILES):
            return d
    return None


def lens_from_colmap(model: str, params, width: int, height: int, where: str) -> LensCamera:
    """A COLMAP camera (model name, parameter list) → :class:`LensCamera`; SceneError for unsupported models."""
    p = [float(x) for x in params]
    common = dict(width=int(width), height=int(height), model=model)
    if model == "SIMPLE_PINHOLE":
        return LensCamera(fx=p[0], fy=p[0], cx=p[1], cy=p[2], **common)
    if model == "PINHOLE":
        return LensCamera(fx=p[0], fy=p[1], cx=p[2], cy=p[3], **common)
    if model == "SIMPLE_RADIAL":
        return LensCamera(fx=p[0], fy=p[0], cx=p[1], cy=p[2], k1=p[3], **common)
    if model == "RADIAL":
        return LensCamera(fx=p[0], fy=p[0], cx=p[1], cy=p[2], k1=p[3], k2=p[4], **common)
    if model == "OPENCV":
        return LensCamera(fx=p[0], fy=p[1], cx=p[2], cy=p[3], k1=p[4], k2=p[5], p1=p[6], p2=p[7], **common)
    if model == "FULL_OPENCV" and not any(p[9:12]):
        return LensCamera(fx=p[0], fy=p[1], cx=p[2], cy=p[3], k1=p[4], k2=p[5], p1=p[6], p2=p[7], k3=p[8], **common)
    detail = " with non-zero k4..k6 (rational model)" if model == "FULL_OPENCV" else ""
    raise SceneError(
        f"{where}: unsupported camera model {model}{detail} "
        f"(supported: {', '.join(PINHOLE_MODELS + DISTORTED_MODELS)}; undistort with COLMAP's image_undistorter first)"
    )


def _pose(image: ColmapImage, where: str) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera ``(R, t)`` of a COLMAP image; SceneError for a zero or non-finite quaternion (no rotation:
    normalising it would silently put the camera anywhere)."""
    q = np.asarray(image.qvec, dtype=np.float64)
    if not np.all(np.isfinite(q)) or not np.linalg.norm(q) > 1e-8:
        raise SceneError(f"{where}: the rotation quaternion {q.tolist()} is zero or not finite (no valid pose)")
    t = np.asarray(image.tvec, dtype=np.float64)
    if not np.all(np.isfinite(t)):
        raise SceneError(f"{where}: the translation {t.tolist()} is not finite (no valid pose)")
    return quaternion_to_rotation(q), t


def _images_dir(root: Path, model_dir: Path, images: str) -> Path:
    for d in (root / images, model_dir.parent / images, model_dir.parent.parent / images):
        if d.is_dir():
            return d
    raise SceneError(f"{root / images}: image folder not found (COLMAP model in {model_dir})")


def read_colmap(root: Path, config) -> ScenePlan:
    """Parse a COLMAP scene folder (see the module docstring)."""
    model_dir = find_model_dir(root)
    if model_dir is None:
        raise SceneError(f"{root}: no COLMAP model (cameras.bin/.txt in sparse/0, sparse or the folder)")
    rec = read_model(model_dir)
    cam_file = next((model_dir / f for f in _MODEL_FILES if (model_dir / f).is_file()), model_dir)
    pose_file = next((model_dir / f for f in ("images.bin", "images.txt") if (model_dir / f).is_file()), model_dir)
    image_dir = _images_dir(root, model_dir, config.images)
    warnings = list(rec.warnings)
    registered = [im for im in rec.images.values() if "sky_mask" not in im.name]  # the file holds posed images only
    if not registered:
        raise SceneError(f"{model_dir}: the COLMAP model has no registered images")
    views, models = [], []
    lenses: dict[int, LensCamera] = {}
    for im in sorted(registered, key=lambda im: im.name):
        cam = rec.cameras[im.camera_id]
        if im.camera_id not in lenses:
            where = f"{cam_file} (camera {im.camera_id})"
            lenses[im.camera_id] = lens_from_colmap(cam.model, cam.params, cam.width, cam.height, where)
        lens = lenses[im.camera_id]
        K = undistorted_intrinsics(lens, config.undistort) if lens.has_distortion else lens.pinhole
        R, t = _pose(im, f"{pose_file} (image {im.name})")
        name = Path(im.name).with_suffix("").as_posix()
        try:
            camera = Camera(R=R, t=t, fx=K[0], fy=K[1], cx=K[2], cy=K[3], width=lens.width, height=lens.height, name=name)
        except SceneError as e:
            raise SceneError(f"{model_dir} (image {im.name}): {e}") from None
        rel = imio.check_inside(im.name, image_dir, f"{pose_file} (image {im.name})", config.allow_outside_paths)
        views.append(ViewPlan(name=name, camera=camera, image_path=image_dir / rel,
                              lens=lens if lens.has_distortion else None, composite_alpha=False))  # fmt: skip
        models.append(lens.model)
    n_files = len(imio.list_images(image_dir))
    if n_files > len(views):
        warnings.append(f"{image_dir}: {n_files - len(views)} image file(s) are not in the COLMAP model and are ignored")
    if any(v.lens is not None for v in views):
        warnings.append(f"lens distortion removed ({config.undistort!r} pinhole K)")
    points = colors = None
    if len(rec.xyz):
        points, colors = rec.xyz, rec.rgb
    return ScenePlan(format="colmap", source=root, views=views, points=points, point_colors=colors,
                     camera_models=sorted(set(models)), warnings=warnings)  # fmt: skip
