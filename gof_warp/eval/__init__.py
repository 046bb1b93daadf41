"""Scores: geometry against a ground-truth mesh or point cloud, images against photos.

``evaluate_mesh`` (accuracy, completeness, Chamfer, precision/recall/F-score at τ), ``evaluate_region``
(only the surfaces some camera sees, sampled inside the scored region, with the exact-vs-exact floor beside
each score), ``image_metrics`` (PSNR, SSIM, LPIPS). Imports no stage above ``rendering``: training uses SSIM.

Memory: point samples and one KD-tree per surface.
"""

from ..core.lazy import lazy_exports

_PUBLIC = {
    "evaluate_mesh": "geometry_metrics",
    "mesh_statistics": "geometry_metrics",
    "evaluate_region": "region_metrics",
    "psnr": "image_metrics",
    "ssim": "image_metrics",
}
__all__ = sorted(_PUBLIC)
__getattr__, __dir__ = lazy_exports(__name__, _PUBLIC)
