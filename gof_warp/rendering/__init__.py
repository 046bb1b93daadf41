"""Differentiable ray–Gaussian rendering and the Gaussian opacity field, for torch callers.

:func:`gof_warp.rendering.render` (``render.render``) validates torch inputs, launches the Warp renderer of ``gof_warp.kernels.renderer`` (project →
tile binning → per-pixel ray–Gaussian compositing) and wraps its hand-written backward in a
``torch.autograd.Function``; :func:`gof_warp.rendering.opacity_field` evaluates GOF's field (the minimum over views of the
opacity along each camera's ray, paper Eq. 9) at 3D points, reusing projection and binning.

No files, no CLI. Memory: one render's tile lists grow with the Gaussians' screen footprint (sized from the
previous render on a GPU); the opacity field runs in chunks of points and views.
"""

from ..core.lazy import lazy_exports

_PUBLIC = {
    "rasterize": "render",
    "RenderConfig": "render",
    "DensifyStats": "render",
    "OpacityFieldConfig": "opacity_field",
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
