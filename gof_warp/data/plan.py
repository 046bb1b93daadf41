"""From what a reader parsed to a :class:`~gof_warp.core.scene.Scene`: check every file, budget, then decode once.

Readers (``colmap.py``, ``blender.py``, ``ingp.py``, ``dtu.py``) only parse cameras and list files; they
return a :class:`ScenePlan`. :func:`build_scene` then

1. reads every image and mask header (missing/unreadable files fail here, before any decoding), fits
   cameras to images stored at another resolution than the camera file says (same aspect ratio only),
2. estimates the decoded size and refuses a plan over the memory budget (saying which downscale fits),
3. decodes each image once: alpha compositing, downscaling (BICUBIC), undistortion (Warp),
4. splits train/test and adds scene-level warnings.

Nothing is written anywhere.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.camera import Camera, camera_extent
from ..core.errors import SceneError
from ..core.scene import ImageSource, Scene, View
from . import images as imio
from .undistort import LensCamera, undistort_image

log = logging.getLogger(__name__)

_ASPECT_TOL_PX = 1.0  # an image may differ from the camera's size × factor by rounding (≤ 1 px)


@dataclass
class ViewPlan:
    """One view before decoding.

    Attributes:
        name: unique view name: image path relative to the image folder, without suffix (the scene's views
            are named by :func:`unique_names` of these).
        camera: pinhole camera at the camera file's resolution (already the undistorted K if ``lens``).
        image_path: the image file.
        lens: the distorted camera the image was taken with, or None (image is pinhole already).
        mask_path: a mask file, or None.
        mask_threshold: binarise the mask at ``> threshold`` (DTU), or None to keep grey values.
        composite_alpha: blend RGBA images on the background (NeRF formats); if False the RGB is used as is
            (3DGS's COLMAP reader). Either way alpha becomes the mask when there is no mask file.
        split: ``"train"``/``"test"`` when the format fixes it (Blender), else None.
    """

    name: str
    camera: Camera
    image_path: Path
    lens: LensCamera | None = None
    mask_path: Path | None = None
    mask_threshold: int | None = None
    composite_alpha: bool = True
    split: str | None = None


@dataclass
class ScenePlan:
    """What a reader found: views (sorted as they should be split), initial points, model names, warnings."""

    format: str
    source: Path
    views: list[ViewPlan]
    points: np.ndarray | None = None
    point_colors: np.ndarray | None = None
    camera_models: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


@dataclass
class _Checked:
    view: ViewPlan
    camera: Camera  # at the decoded image's native resolution
    lens: LensCamera | None
    has_mask: bool


def _fit_to_image(v: ViewPlan, header: imio.ImageHeader, notes: set) -> tuple[Camera, LensCamera | None]:
    """Scale the camera (and lens) to the image's stored size when only the resolution differs."""
    cam, w, h = v.camera, header.width, header.height
    if (w, h) == (cam.width, cam.height):
        return cam, v.lens
    sx, sy = w / cam.width, h / cam.height
    if abs(cam.height * sx - h) > _ASPECT_TOL_PX and abs(cam.width * sy - w) > _ASPECT_TOL_PX:
        raise SceneError(
            f"{v.image_path}: image is {w}x{h} but its camera is {cam.width}x{cam.height} (different aspect ratio)"
        )
    notes.add(f"images are stored at {w}x{h}, cameras at {cam.width}x{cam.height}: intrinsics scaled to the images")
    scaled = dataclasses.replace(cam, fx=cam.fx * sx, fy=cam.fy * sy, cx=cam.cx * sx, cy=cam.cy * sy, width=w, height=h)
    return scaled, (v.lens.scaled(w, h) if v.lens is not None else None)


def check_files(plan: ScenePlan, use_masks: bool) -> list[_Checked]:
    """Read every header; raise :class:`SceneError` naming the first missing/unreadable/mismatched file."""
    notes: set = set()
    out = []
    for v in plan.views:
        header = imio.read_header(v.image_path)
        cam, lens = _fit_to_image(v, header, notes)
        has_mask = False
        if use_masks and v.mask_path is not None:
            mh = imio.read_header(v.mask_path, "mask")
            if (mh.width, mh.height) != (header.width, header.height):
                raise SceneError(f"{v.mask_path}: mask is {mh.width}x{mh.height} but its image is {header.width}x{header.height}")
            has_mask = True
        elif use_masks:
            has_mask = header.has_alpha
        out.append(_Checked(v, cam, lens, has_mask))
    plan.warnings.extend(sorted(notes))
    return out


# The scene extents (:attr:`Scene.extent`) training handles: outside, float32 tolerances (depths, scales, the
# near plane) are no longer small against the scene, and a run collapses or fails (``DataConfig.scale`` fixes it).
EXTENT_MIN = 1e-3
EXTENT_MAX = 1e5


def _scaled_pose(camera: Camera, scale: float) -> Camera:
    """``camera`` in world coordinates multiplied by ``scale``: its centre (so ``t``) and near depth scale."""
    return dataclasses.replace(camera, t=np.asarray(camera.t, np.float64) * scale, near=camera.near * scale)


def check_extent(cameras: list[Camera], source, scale: float = 1.0) -> None:
    """Raise :class:`SceneError` when the extent of ``cameras`` (:func:`~gof_warp.core.camera.camera_extent`, as
    :attr:`Scene.extent`) lies outside ``[EXTENT_MIN, EXTENT_MAX]``, naming the ``data.scale`` (a power of ten,
    times the one already applied) that brings it to 1–10."""
    extent = camera_extent(cameras)
    if EXTENT_MIN <= extent <= EXTENT_MAX:
        return
    fix = scale * 10.0 ** -math.floor(math.log10(extent))
    raise SceneError(
        f"{source}: the scene's extent (1.1 x the largest distance of a camera centre from their mean) is "
        f"{extent:.3g} world units, outside the {EXTENT_MIN:g}-{EXTENT_MAX:g} that training handles in float32; pass "
        f"data.scale={fix:.3g} to scale the scene to an extent of {extent * fix / scale:.3g} (the model and meshes are "
        f"then in the scaled units)")


def _output_cameras(checked: list[_Checked], downscale: float) -> list[Camera]:
    return [c.camera if downscale == 1 else c.camera.scaled(1.0 / downscale) for c in checked]


def estimate_bytes(checked: list[_Checked], downscale: float) -> int:
    """Decoded size of all images (3 bytes/pixel) and masks (1 byte/pixel) at ``downscale``."""
    cams = _output_cameras(checked, downscale)
    return sum(c.width * c.height * (4 if k.has_mask else 3) for c, k in zip(cams, checked))


def check_budget(checked: list[_Checked], downscale: float, budget_gb: float, source) -> None:
    """Raise :class:`SceneError` if the decoded images would exceed ``budget_gb``, naming a downscale that fits."""
    need = estimate_bytes(checked, downscale)
    budget = budget_gb * 1e9
    if need <= budget:
        return
    fit = math.ceil(downscale * math.sqrt(need / budget) * 10) / 10
    while estimate_bytes(checked, fit) > budget:
        fit = round(fit + 0.1, 1)
    raise SceneError(
        f"{source}: {len(checked)} decoded images would take {need / 1e9:.2f} GB at downscale {downscale:g}, "
        f"over the image memory budget of {budget_gb:g} GB; use downscale >= {fit:g} (or raise the budget)"
    )


def _decode_view(k: _Checked, out_cam: Camera, background, use_masks: bool, undistort_device) -> View:
    v = k.view
    img = imio.decode(v.image_path)
    if (img.shape[1], img.shape[0]) != (k.camera.width, k.camera.height):  # header lied (rare)
        raise SceneError(f"{v.image_path}: decoded size {img.shape[1]}x{img.shape[0]} differs from its header")
    alpha = None
    if img.shape[2] == 4:
        if v.composite_alpha:
            img, alpha = imio.composite(img, background)
        else:
            img, alpha = np.ascontiguousarray(img[:, :, :3]), np.ascontiguousarray(img[:, :, 3])
    mask = None
    if use_masks:
        mask = imio.decode_mask(v.mask_path, v.mask_threshold) if v.mask_path is not None else alpha
    # Downscale first, then undistort at the output resolution: the remap is the costly step, and
    # BICUBIC-then-bilinear differs from bilinear-then-BICUBIC by far less than either filter's blur.
    if (out_cam.width, out_cam.height) != (k.camera.width, k.camera.height):
        img = imio.resize(img, out_cam.width, out_cam.height)
        if mask is not None:
            mask = imio.resize(mask, out_cam.width, out_cam.height)
    if k.lens is not None:
        lens = k.lens.scaled(out_cam.width, out_cam.height)
        K = (out_cam.fx, out_cam.fy, out_cam.cx, out_cam.cy)
        img = undistort_image(img, lens, *K, background=background, device=undistort_device)
        if mask is not None:
            mask = undistort_image(mask, lens, *K, background=0.0, device=undistort_device)
    if mask is not None and v.mask_threshold is not None:
        mask = np.where(mask > v.mask_threshold, 255, 0).astype(np.uint8)
    settings = f"composite_alpha={v.composite_alpha} background={tuple(map(float, background))!r} lens={k.lens!r}"
    return View(camera=out_cam, image=img, mask=mask, name=out_cam.name, source=ImageSource(v.image_path, settings))


def unique_names(rel_names: list[str]) -> list[str]:
    """View names from image paths relative to their folder, without suffix: the file stems when those are
    unique (``images/0001`` → ``0001``), else the whole relative path with ``/`` → ``_`` (``train_r_0``)."""
    stems = [n.rsplit("/", 1)[-1] for n in rel_names]
    if len(set(stems)) == len(stems):
        return stems
    return [n.replace("/", "_") for n in rel_names]


def _visibility_warnings(cameras: list[Camera], names: list[str], points: np.ndarray) -> list[str]:
    blind = []
    for cam, name in zip(cameras, names):
        if not cam.in_image(points)[2].any():
            blind.append(name)
    if not blind:
        return []
    shown = ", ".join(blind[:5]) + (", ..." if len(blind) > 5 else "")
    return [f"{len(blind)} camera(s) see none of the {len(points)} initial points: {shown}"]


def split_views(plan: ScenePlan, views: list[View], test_every: int) -> tuple[list[View], list[View]]:
    """Train/test split: the format's own (Blender) when given, else ``index % test_every == 0`` → test.

    ``test_every = 0``: everything trains (Blender test views are merged into train, as GOF without ``--eval``).
    """
    if any(v.split is not None for v in plan.views):
        if test_every == 0:
            return views, []
        train = [x for x, v in zip(views, plan.views) if v.split != "test"]
        return train, [x for x, v in zip(views, plan.views) if v.split == "test"]
    if test_every == 0:
        return views, []
    return [x for i, x in enumerate(views) if i % test_every != 0], views[::test_every]


def build_scene(plan: ScenePlan, config, device=None) -> Scene:
    """Decode a checked plan into a :class:`Scene` following ``config`` (a :class:`~gof_warp.data.DataConfig`)."""
    if not plan.views:
        raise SceneError(f"{plan.source}: no views found")
    checked = check_files(plan, config.use_masks)
    check_budget(checked, config.downscale, config.image_memory_budget_gb, plan.source)
    names = unique_names([v.name for v in plan.views])
    out_cams = [dataclasses.replace(c, name=n) for c, n in zip(_output_cameras(checked, config.downscale), names)]
    scale = getattr(config, "scale", 1.0)
    if scale != 1.0:
        out_cams = [_scaled_pose(c, scale) for c in out_cams]
    check_extent(out_cams, plan.source, scale)  # before decoding: the extent needs only the poses
    log.info("decoding %d images from %s (downscale %g)", len(checked), plan.source, config.downscale)
    views = [_decode_view(k, cam, config.background, config.use_masks, device) for k, cam in zip(checked, out_cams)]

    warnings = list(plan.warnings)
    sizes = sorted({(v.camera.width, v.camera.height) for v in views})
    if len(sizes) > 1:
        warnings.append(f"images have {len(sizes)} different sizes: " + ", ".join(f"{w}x{h}" for w, h in sizes[:4]))
    n_masks = sum(v.mask is not None for v in views)
    if 0 < n_masks < len(views):
        warnings.append(f"masks missing for {len(views) - n_masks} of {len(views)} views")
    points = plan.points
    if scale != 1.0 and points is not None:
        points = np.asarray(points, np.float64) * scale
    if points is not None and len(points):
        warnings += _visibility_warnings([v.camera for v in views], [v.name for v in views], points)
    train, test = split_views(plan, views, config.test_every)
    if not train:
        raise SceneError(f"{plan.source}: the test split leaves no training views (test_every={config.test_every})")
    scene = Scene(
        train=train,
        test=test,
        points=points,
        point_colors=plan.point_colors,
        background=tuple(float(c) for c in config.background),
        format=plan.format,
        source=str(plan.source),
        camera_models=sorted(set(plan.camera_models)),
        warnings=warnings,
    )
    return scene
