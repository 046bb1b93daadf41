"""Scene readers: one :func:`load_scene` for every supported folder layout, detected automatically.

==========  =======================================================  ==================================
format      what marks the folder                                    reader
==========  =======================================================  ==================================
``blender`` ``transforms_train.json`` (NeRF-synthetic, synthetic)    :func:`~.blender.read_blender`
``ingp``    ``transforms.json`` (instant-ngp, nerfstudio)            :func:`~.ingp.read_ingp`
``dtu``     ``cameras_sphere.npz`` (NeuS/IDR)                        :func:`~.dtu.read_dtu`
``colmap``  ``sparse/0/cameras.bin|txt`` (or ``sparse/``, or here)   :func:`~.colmap.read_colmap`
==========  =======================================================  ==================================

Every reader checks all files before decoding any image and never writes anything. Cameras come out as
undistorted pinhole :class:`~gof_warp.core.camera.Camera` s; images are decoded once into ``uint8`` arrays.

Example::

    from gof_warp.data import DataConfig, load_scene
    scene = load_scene("../shared/data/fox", DataConfig(downscale=2))
    print(scene.summary())
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from ..core.config import ConfigError
from ..core.errors import GofError, SceneError
from ..core.scene import Scene
from .blender import read_blender
from .colmap import find_model_dir, read_colmap
from .dtu import read_dtu
from .ingp import read_ingp
from .plan import ScenePlan, ViewPlan, build_scene
from .undistort import UNDISTORT_MODES, LensCamera, undistort_image, undistorted_intrinsics

FORMATS = ("blender", "ingp", "dtu", "colmap")


@dataclass
class DataConfig:
    """How to load a scene.

    Attributes:
        downscale: factor ≥ 1 that divides the resolution: each image becomes
            ``round(W / downscale) × round(H / downscale)`` (GOF's ``-r 2`` ≙ 2.0), resampled with Pillow's
            BICUBIC filter (as GOF), intrinsics scaled exactly. There is no target-width mode: pass
            ``W / target_width``.
        test_every: every ``test_every``-th view of the name-sorted list (index % N == 0) is a test view,
            3DGS/GOF's ``--eval`` convention; 0 = no test split. Blender scenes use
            ``transforms_test.json`` instead (0 merges those test views into training, as GOF without ``--eval``).
        background: RGB in ``[0, 1]`` that RGBA images are composited on (NeRF formats), and the colour of
            pixels that see outside a distorted image (``undistort="same"`` only).
        image_memory_budget_gb: upper bound on decoded image + mask memory, estimated from the file
            headers before decoding; a scene over it raises :class:`SceneError` naming a downscale that fits.
        use_masks: load masks (DTU ``mask/``, alpha channels, ``mask_path``); False drops them.
        undistort: ``"valid"`` (pinhole K zoomed so that no output pixel is blank) or ``"same"`` (keep the
            file's K; blank corners get ``background``). See :mod:`gof_warp.data.undistort`.
        images: COLMAP image folder name (``images``, ``images_2`` …).
        allow_outside_paths: read image and mask paths of the scene files (``transforms*.json`` ``file_path`` /
            ``mask_path``, COLMAP image names) that resolve outside the scene folder (COLMAP: its image folder),
            e.g. ``../other/img.png``, absolute paths or links to elsewhere. False (default): such a path is an
            error naming the entry, and the file is not touched.
        scale: factor applied to the scene's world coordinates when it is loaded (every camera centre and scene
            point is multiplied by it about the origin; rotations and intrinsics are unchanged). Training works in
            float32 with absolute tolerances: a scene whose extent (:attr:`Scene.extent`) lies outside
            ``[EXTENT_MIN, EXTENT_MAX]`` is refused with the ``scale`` that brings it to an extent of 1–10. The
            model, its ``cameras.json`` and the meshes extracted from it are in the scaled units (divide by
            ``scale`` to return to the scene's own).
    """

    downscale: float = 1.0
    test_every: int = 8
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    image_memory_budget_gb: float = 8.0
    use_masks: bool = True
    undistort: str = "valid"
    images: str = "images"
    allow_outside_paths: bool = False
    scale: float = 1.0

    def __post_init__(self):
        if not (isinstance(self.downscale, (int, float)) and math.isfinite(self.downscale) and self.downscale >= 1):
            raise ConfigError(f"data.downscale must be a number >= 1, got {self.downscale!r}")
        self.downscale = float(self.downscale)
        if isinstance(self.test_every, bool) or not isinstance(self.test_every, int) or self.test_every < 0:
            raise ConfigError(f"data.test_every must be an integer >= 0, got {self.test_every!r}")
        if len(tuple(self.background)) != 3 or not all(0.0 <= float(c) <= 1.0 for c in self.background):
            raise ConfigError(f"data.background must be 3 values in [0, 1], got {self.background!r}")
        self.background = tuple(float(c) for c in self.background)
        if not self.image_memory_budget_gb > 0:
            raise ConfigError(f"data.image_memory_budget_gb must be > 0, got {self.image_memory_budget_gb!r}")
        if self.undistort not in UNDISTORT_MODES:
            raise ConfigError(f"data.undistort must be one of {UNDISTORT_MODES}, got {self.undistort!r}")
        if isinstance(self.scale, bool) or not (isinstance(self.scale, (int, float)) and math.isfinite(self.scale)
                                                and self.scale > 0):
            raise ConfigError(f"data.scale must be a finite number > 0, got {self.scale!r}")
        self.scale = float(self.scale)


def _scene_root(path) -> Path:
    p = Path(path).expanduser()
    if not p.exists():
        raise SceneError(f"{p}: scene folder does not exist")
    if p.is_file():  # e.g. .../transforms.json or .../cameras_sphere.npz: its folder
        p = p.parent
    return p.resolve()


def detect_format(path) -> str:
    """Name of the format of the scene folder ``path`` (one of :data:`FORMATS`); SceneError if none."""
    root = _scene_root(path)
    if (root / "transforms_train.json").is_file():
        return "blender"
    if (root / "transforms.json").is_file():
        return "ingp"
    if (root / "cameras_sphere.npz").is_file():
        return "dtu"
    if find_model_dir(root) is not None:
        return "colmap"
    from .prepare import folder_has_photos

    if folder_has_photos(root):
        raise SceneError(
            f"{root}: this folder holds photos but no camera poses: run `gof-warp prepare PHOTOS --out SCENE` "
            f"first (python -m gof_warp.prepare {root} --out SCENE), then train on SCENE"
        )
    raise SceneError(
        f"{root}: no known scene format (looked for transforms_train.json, transforms.json, "
        f"cameras_sphere.npz, sparse/0/cameras.bin|txt)"
    )


_READERS = {"blender": read_blender, "ingp": read_ingp, "dtu": read_dtu, "colmap": read_colmap}


def read_plan(path, config: DataConfig | None = None) -> ScenePlan:
    """Parse cameras and list files without decoding images (what :func:`load_scene` does first)."""
    config = config or DataConfig()
    root = _scene_root(path)
    return _READERS[detect_format(root)](root, config)


def load_scene(path, config: DataConfig | None = None, device=None) -> Scene:
    """Load the scene folder ``path`` (format auto-detected) into a :class:`~gof_warp.core.scene.Scene`.

    Args:
        path: scene folder (or a file inside it, e.g. its ``transforms.json``).
        config: :class:`DataConfig` (defaults if None).
        device: Warp device for undistortion (default: CUDA if available, else CPU).

    Raises:
        SceneError: unknown format, missing/unreadable/corrupt files, count mismatches, unsupported
            camera models, over the memory budget — the message names the file and the problem.
    """
    config = config or DataConfig()
    return build_scene(read_plan(path, config), config, device=device)


__all__ = [
    "FORMATS",
    "DataConfig",
    "LensCamera",
    "ScenePlan",
    "ViewPlan",
    "detect_format",
    "load_scene",
    "read_blender",
    "read_colmap",
    "read_dtu",
    "read_ingp",
    "read_plan",
    "undistort_image",
    "undistorted_intrinsics",
]
