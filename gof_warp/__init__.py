"""gof_warp: Gaussian Opacity Fields (Yu, Sattler, Geiger 2024) on NVIDIA Warp.

Public API (torch-facing, host side); the pure Warp kernels live in :mod:`gof_warp.kernels`.

* scenes: :class:`Camera`, :class:`Scene`, :class:`View`, :func:`load_scene`, :class:`DataConfig`
* model: :class:`Gaussians` (3DGS PLY in/out)
* rendering: :func:`render`, :func:`rasterize`, :class:`RenderConfig`, :class:`DensifyStats`
* surfaces: :func:`opacity_field`, :func:`extract_mesh`
* evaluation: :func:`evaluate_mesh`, :func:`image_metrics`

Names are imported on first use, so ``import gof_warp`` stays cheap (torch and Warp load when needed).
"""

from __future__ import annotations

import importlib
import sys
import warnings

from .camera import Camera, camera_extent, look_at
from .errors import GofError, ModelError, PlyError, SceneError
from .scene import Scene, View

__version__ = "0.1.0"

# Pillow's C module must load before pycolmap's wheel, or Pillow's PNG writer aborts the process ("double free",
# pycolmap 4.2.1): importing it here makes any later pycolmap import safe; an earlier one gets a warning.
if "pycolmap" in sys.modules and "PIL._imaging" not in sys.modules:
    warnings.warn("pycolmap was imported before Pillow: writing PNG files (gof_warp's pictures) may abort the "
                  "process; import gof_warp (or PIL.Image) before pycolmap", RuntimeWarning, stacklevel=2)
import PIL.Image  # noqa: E402,F401

_LAZY = {
    "load_scene": "data", "DataConfig": "data", "detect_format": "data",
    "Gaussians": "model",
    "render": "render", "rasterize": "render", "RenderConfig": "render", "DensifyStats": "render",
    "opacity_field": "opacity_field", "OpacityFieldConfig": "opacity_field",
    "extract_mesh": "extraction", "MeshConfig": "extraction",
    "evaluate_mesh": "geometry_metrics", "mesh_statistics": "geometry_metrics",
    "image_metrics": "metrics", "psnr": "metrics", "ssim": "metrics",
    "make_scene": "synthetic",
}

__all__ = ["Camera", "GofError", "ModelError", "PlyError", "Scene", "SceneError", "View", "camera_extent", "look_at",
           *_LAZY]


def __getattr__(name):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'gof_warp' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
