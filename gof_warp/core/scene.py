"""Scenes: posed images (+ optional masks and initial points) ready for training.

A :class:`Scene` is what every reader in :mod:`gof_warp.data` returns and what training, extraction and
evaluation consume. Images are decoded once into ``uint8`` arrays (``[H, W, 3]``) and kept in memory;
masks are ``uint8`` ``[H, W]`` (255 = object / foreground, 0 = background).
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .camera import Camera, camera_extent
from .errors import SceneError

log = logging.getLogger(__name__)
SAME_POSE_TOL = 1e-6  # centres closer than this × (1 + their distance from the origin) coincide; rotations likewise


@dataclass(frozen=True)
class ImageSource:
    """Where a view's pixels came from: the image file and how it was decoded.

    JPEG decoders need not agree bit for bit (the standard allows each IDCT its rounding), so what
    identifies a view's image across machines (e.g. for a cache carried with the scene) is the file's bytes and the
    decoding settings, not the decoded array.

    Attributes:
        path: the image file.
        settings: every setting of the decoding that changes the pixels besides the output size (which the camera
            carries): alpha compositing and its background, the lens undistorted.
    """

    path: Path
    settings: str = ""

    def digest(self) -> str | None:
        """Hex SHA-256 of the file's bytes and the settings, or None if the file can no longer be read."""
        h = hashlib.sha256()
        try:
            with open(self.path, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
        except OSError:
            return None
        h.update(b"\0" + self.settings.encode("utf-8"))
        return h.hexdigest()


@dataclass(eq=False)
class View:
    """One posed image.

    Attributes:
        camera: its :class:`~gof_warp.core.camera.Camera` (pinhole, undistorted).
        image: ``[H, W, 3]`` uint8 RGB, already composited on the scene background where it had alpha.
        mask: ``[H, W]`` uint8 (255 inside), or None. Blender alpha and DTU object masks land here.
        name: image name (file stem).
        source: the file and decoding the image came from (:class:`ImageSource`), or None for an image made in memory.
    """

    camera: Camera
    image: np.ndarray
    mask: np.ndarray | None = None
    name: str = ""
    source: ImageSource | None = None

    def __post_init__(self):
        h, w = self.camera.height, self.camera.width
        if self.image.dtype != np.uint8 or self.image.ndim != 3 or self.image.shape[2] != 3:
            raise SceneError(f"view {self.name!r}: image must be uint8 [H, W, 3], got {self.image.dtype} {self.image.shape}")
        if self.image.shape[:2] != (h, w):
            raise SceneError(
                f"view {self.name!r}: image is {self.image.shape[1]}x{self.image.shape[0]} but its camera says {w}x{h}"
            )
        if self.mask is not None and (self.mask.shape != (h, w) or self.mask.dtype != np.uint8):
            raise SceneError(f"view {self.name!r}: mask must be uint8 [{h}, {w}], got {self.mask.dtype} {self.mask.shape}")

    def image_float(self) -> np.ndarray:
        """``[H, W, 3]`` float32 in ``[0, 1]``."""
        return self.image.astype(np.float32) / 255.0


def pose_warnings(cameras: list[Camera]) -> list[str]:
    """Warnings about training poses that leave the geometry undetermined (training can still run).

    One view: nothing constrains depth. Every centre the same: no parallax — the views differ at most by a
    rotation about that centre, which no multi-view method can turn into depth.
    """
    if len(cameras) == 1:
        return ["only 1 training view: no parallax: geometry cannot be recovered (training runs, but fits "
                "a flat, view-dependent model)"]
    centres = np.stack([c.center for c in cameras])
    tol = SAME_POSE_TOL * (1.0 + float(np.abs(centres).max()))
    if np.abs(centres - centres[0]).max() > tol:
        return []
    same_r = all(np.abs(c.R - cameras[0].R).max() <= SAME_POSE_TOL for c in cameras)
    what = "the same centre and orientation (identical cameras)" if same_r else "the same centre (rotation only)"
    return [f"all {len(cameras)} training cameras have {what}: no parallax: geometry cannot be recovered"]


@dataclass(eq=False)
class Scene:
    """Train/test views, optional initial points and the scene's extent.

    Attributes:
        train, test: lists of :class:`View`.
        points: ``[P, 3]`` float64 initial points (e.g. COLMAP's sparse points), or None.
        point_colors: ``[P, 3]`` uint8, or None.
        extent: 1.1 × the largest distance of a train camera centre from their mean (3DGS's
            ``cameras_extent``); scales learning rates and pruning.
        background: RGB in ``[0, 1]`` that alpha images were composited on.
        format: detected format name (``colmap``, ``blender``, ``ingp``, ``dtu``).
        source: the folder it was read from.
        camera_models: the camera model(s) as stored in the files (e.g. ``OPENCV``), before undistortion.
        warnings: things the reader noticed that a user should know (printed by ``gof_warp.cli.inspect_scene``).
    """

    train: list[View]
    test: list[View] = field(default_factory=list)
    points: np.ndarray | None = None
    point_colors: np.ndarray | None = None
    extent: float = 0.0
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    format: str = ""
    source: str = ""
    camera_models: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def __post_init__(self):
        if not self.train:
            raise SceneError(f"scene {self.source or '(in memory)'} has no training views")
        if self.points is not None:
            self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
            if not np.all(np.isfinite(self.points)):
                raise SceneError(f"scene {self.source}: initial points contain NaN/inf")
        if self.point_colors is not None:
            self.point_colors = np.asarray(self.point_colors, dtype=np.uint8).reshape(-1, 3)
            if self.points is None or len(self.point_colors) != len(self.points):
                raise SceneError(f"scene {self.source}: point colours do not match the points")
        if not self.extent:
            self.extent = camera_extent([v.camera for v in self.train])
        for w in pose_warnings(self.train_cameras):
            if w not in self.warnings:
                self.warnings.append(w)
                log.warning("warning: %s: %s", self.source or "scene", w)

    @property
    def train_cameras(self) -> list[Camera]:
        return [v.camera for v in self.train]

    @property
    def test_cameras(self) -> list[Camera]:
        return [v.camera for v in self.test]

    @property
    def all_views(self) -> list[View]:
        return list(self.train) + list(self.test)

    def image_bytes(self) -> int:
        """Memory held by decoded images and masks."""
        return sum(v.image.nbytes + (v.mask.nbytes if v.mask is not None else 0) for v in self.all_views)

    def summary(self) -> dict:
        """Plain-data description (what ``python -m gof_warp.inspect`` prints)."""
        res = sorted({(v.camera.width, v.camera.height) for v in self.all_views})
        return {
            "source": self.source,
            "format": self.format,
            "camera_models": sorted(set(self.camera_models)),
            "train_views": len(self.train),
            "test_views": len(self.test),
            "resolutions": [f"{w}x{h}" for w, h in res],
            "masks": sum(v.mask is not None for v in self.all_views),
            "initial_points": 0 if self.points is None else int(len(self.points)),
            "extent": round(float(self.extent), 6),
            "background": list(self.background),
            "image_memory_mb": round(self.image_bytes() / 2**20, 1),
            "warnings": list(self.warnings),
        }
