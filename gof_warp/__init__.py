"""gof_warp: Gaussian Opacity Fields (Yu, Sattler, Geiger 2024) on NVIDIA Warp.

Public API (torch-facing, host side); the pure Warp kernels live in :mod:`gof_warp.kernels`.

* scenes: :class:`Camera`, :class:`Scene`, :class:`View`, :func:`load_scene`, :class:`DataConfig`,
  :func:`make_scene` (synthetic scenes with exact ground truth)
* model: :class:`Gaussians` (3DGS PLY in/out)
* rendering: :func:`render`, :func:`rasterize`, :class:`RenderConfig`, :class:`DensifyStats`, :func:`opacity_field`
* training: :class:`Trainer`, :class:`TrainConfig`
* surfaces: :func:`extract_mesh`, :class:`MeshConfig`
* evaluation: :func:`evaluate_mesh`, :func:`image_metrics`

The subpackages follow the data flow (``docs/architecture.md``): ``core`` ← ``data``/``synthetic`` ←
``rendering`` ← ``eval`` ← ``training`` ← ``mesh`` ← ``viz`` ← ``benchmarking`` ← ``cli``.
Names are imported on first use, so ``import gof_warp`` stays cheap (torch and Warp load when needed).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

from .core.camera import Camera, camera_extent, look_at
from .core.errors import GofError, ModelError, PlyError, SceneError
from .core.scene import Scene, View

__version__ = "0.1.0"

# Pillow's C module must load before pycolmap's wheel, or Pillow's PNG writer aborts the process ("double free",
# pycolmap 4.2.1): importing it here makes any later pycolmap import safe; an earlier one gets a warning.
if "pycolmap" in sys.modules and "PIL._imaging" not in sys.modules:
    warnings.warn("pycolmap was imported before Pillow: writing PNG files (gof_warp's pictures) may abort the "
                  "process; import gof_warp (or PIL.Image) before pycolmap", RuntimeWarning, stacklevel=2)
import PIL.Image  # noqa: E402,F401

_LAZY = {
    "load_scene": "data", "DataConfig": "data", "detect_format": "data",
    "Gaussians": "core.model",
    "render": "rendering.render", "rasterize": "rendering.render", "RenderConfig": "rendering.render",
    "DensifyStats": "rendering.render",
    "opacity_field": "rendering.opacity_field", "OpacityFieldConfig": "rendering.opacity_field",
    "Trainer": "training.trainer", "TrainConfig": "training.trainer",
    "extract_mesh": "mesh.extraction", "MeshConfig": "mesh.extraction",
    "evaluate_mesh": "eval.geometry_metrics", "mesh_statistics": "eval.geometry_metrics",
    "image_metrics": "eval.image_metrics", "psnr": "eval.image_metrics", "ssim": "eval.image_metrics",
    "make_scene": "synthetic",
}

__all__ = ["Camera", "GofError", "ModelError", "PlyError", "Scene", "SceneError", "View", "camera_extent", "look_at",
           *_LAZY]

# Where each module of the first, one-floor layout lives now: ``import gof_warp.render`` (and ``from
# gof_warp.render import render``) still work and give the same module object as ``gof_warp.rendering.render``.
_MOVED = {
    "appearance": "training.appearance",
    "arrays": "core.arrays",
    "bench_report": "benchmarking.report",
    "bench_runs": "benchmarking.runs",
    "camera": "core.camera",
    "checkpoint": "training.checkpoint",
    "config": "core.config",
    "curves": "viz.curves",
    "decimate": "mesh.decimate",
    "delaunay": "mesh.delaunay",
    "delaunay_cgal": "mesh.delaunay_cgal",
    "densify": "training.densify",
    "devices": "core.devices",
    "distributed": "training.distributed",
    "errors": "core.errors",
    "extraction": "mesh.extraction",
    "filter3d": "training.filter3d",
    "forked": "core.forked",
    "geometry_metrics": "eval.geometry_metrics",
    "hidden": "training.hidden",
    "init_points": "data.init_points",
    "interrupts": "training.interrupts",
    "io_utils": "core.io_utils",
    "loss_monitor": "training.loss_monitor",
    "losses": "training.losses",
    "marching": "mesh.marching",
    "marching_inputs": "mesh.marching_inputs",
    "metrics": "eval.image_metrics",
    "model": "core.model",
    "multiview": "training.multiview",
    "near_camera": "training.near_camera",
    "octree_tets": "mesh.octree_tets",
    "opacity_field": "rendering.opacity_field",
    "optim": "training.optim",
    "panels": "viz.panels",
    "ply": "core.ply",
    "preset_choice": "training.presets",
    "progress": "core.progress",
    "reach": "mesh.reach",
    "region_metrics": "eval.region_metrics",
    "render": "rendering.render",
    "run_folder": "training.run_folder",
    "scene": "core.scene",
    "stability": "benchmarking.stability",
    "stability_inputs": "benchmarking.stability_inputs",
    "stability_scenes": "benchmarking.stability_scenes",
    "step_scalars": "training.step_scalars",
    "tetra": "mesh.tetra",
    "trainer": "training.trainer",
    "tsdf": "mesh.tsdf",
    "viewer": "viz.viewer",
    "visibility": "mesh.visibility",
    "volume": "mesh.volume",
    "volume_mesh": "mesh.volume_mesh",
}


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves an old module path to its module's new place (one module object, never a copy)."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname.startswith(__name__ + ".") and fullname[len(__name__) + 1:] in _MOVED:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        new = importlib.import_module(f"{__name__}.{_MOVED[module.__name__[len(__name__) + 1:]]}")
        sys.modules[module.__name__] = new  # the import system returns what sys.modules holds at the end


if not any(isinstance(f, _MovedModules) for f in sys.meta_path):
    sys.meta_path.append(_MovedModules())


def __getattr__(name):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'gof_warp' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
