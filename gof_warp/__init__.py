"""gof_warp: Gaussian Opacity Fields (Yu, Sattler, Geiger 2024) on NVIDIA Warp.

Public API (torch-facing, host side). The pure Warp kernels live in :mod:`gof_warp.kernels`.
"""

from .camera import Camera, camera_extent, look_at
from .errors import GofError, ModelError, PlyError, SceneError
from .scene import Scene, View

__version__ = "0.1.0"

__all__ = [
    "Camera",
    "GofError",
    "ModelError",
    "PlyError",
    "Scene",
    "SceneError",
    "View",
    "camera_extent",
    "look_at",
]
