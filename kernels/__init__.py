"""gof_warp.kernels: pure Warp kernels and ``@wp.func``s (no torch).

Installed as the subpackage ``gof_warp.kernels`` so that other Warp programs can embed them. Every
kernel takes its inputs first and its outputs last; each has a float64 reference in the tests.

The names in ``__all__`` are the stable public surface (``docs/warp_guide.md`` shows them in use); each
is imported from its module on first use, so ``import gof_warp.kernels`` compiles and loads nothing.
Everything else in the submodules is an implementation detail that may change.

Conventions everywhere: float32 on the device; world units for positions; cameras world-to-camera
(``x_c = R x + t``) with OpenCV axes (x right, y down, z forward) and pixel centres at ``i + 0.5``;
quaternions ``wxyz``; per-pixel arrays flat ``[H*W]`` row-major; ``[N]`` means one entry per Gaussian.

Stable names (module, kind):

* structs and their host builders (``render_types``, ``gaussian_math``): ``CameraParams``,
  ``RasterSettings``, ``Splats``, ``TileLists``, ``PixelMaps``, ``PixelAux``, ``SplatGrads``, ``RayHit``;
  ``make_camera_params``, ``camera_params_from``, ``make_raster_settings``, ``make_struct``.
* Gaussian math (``@wp.func``): ``quat_to_rotation``, ``sh_to_color``, ``pixel_ray``, ``ray_gaussian``,
  ``normal_direction``.
* projection and binning: kernels ``preprocess_gaussians`` (its gradient: the adjoint of ``project_frames`` +
  ``sh_colour_backward``), ``screen_bounds``, ``ray_conics`` (the early reject of the per-pixel kernels and the
  field); host ``bin_gaussians`` and its ``TileListSizer`` (tile lists sized without a host–device synchronisation per
  render).
* rendering on ``wp.array``s (host launchers, ``wp.Tape``-aware): ``render_gaussians``,
  ``render_forward``, ``render_backward``, ``prepare_view``, ``RenderOutputs``, ``RenderState``, ``sh_parts`` (the SH
  coefficients as one ``[N, K]`` array or a model's ``(sh_dc, sh_rest)`` pair, as the kernels read them),
  ``ScratchPool`` (finished renders' scratch arrays for the next render of the same sizes: ``pool=``). The
  per-pixel kernels behind them (``rasterize.rasterize_forward``, ``rasterize_backward.rasterize_backward``,
  their shared-memory twins in ``rasterize_tiled``) need the launchers' tile lists and state: use them
  through the launchers. (A kernel named like its module could not be re-exported here anyway: the
  submodule import would shadow it.)
* opacity field: ``opacity_along_ray``, ``opacity_along_ray_bounded``, ``point_view_tile`` (``@wp.func``),
  ``opacity_min_over_view`` and its whole-walk reference ``opacity_min_over_view_whole`` (kernels).
* marching tetrahedra: ``make_field_kernel``, ``field_params_type``, the kernels ``count_triangles``,
  ``write_triangle_edges``, ``write_slot_ids``, ``mark_run_starts``, ``scatter_vertex_ids``,
  ``init_edge_brackets``, ``bracket_midpoints``, ``update_brackets``, ``bracket_tree_midpoints``,
  ``descend_bracket_tree``, ``interpolate_in_brackets``, ``count_nonfinite`` and the funcs ``tet_case``, ``edge_key``,
  ``tree_node``; ``build_case_tables``.
* 3D filter: ``nearest_seen_depth`` (kernel: the nearest depth at which any camera sees each centre).
* reach of the Gaussians: ``oriented_box_bounds`` (kernel: the axis-aligned bounds of oriented boxes, for a
  ``wp.Bvh``), ``points_in_boxes`` (kernel: which points lie in some oriented box) and the func ``in_oriented_box``.
* visibility of a mesh: ``faces_seen`` (kernel: which faces some camera sees, by rays to each face's centroid and,
  for large faces, towards its corners).
* densification: ``accumulate_view_stats`` (kernel: one view's screen-space gradient statistics added into the
  running sums).
* optimisation: ``adam_step`` (kernel: Adam's update of one flat float32 parameter, four floats a thread, in torch's
  fused CUDA arithmetic).
* TSDF: ``integrate_tsdf``, ``sample_grid_trilinear``; ray casting of meshes: ``cast_pinhole_rays``,
  ``shade_hits``, ``resolve_pixels``; lenses: ``distort_opencv``, ``undistort_remap``.
"""

from __future__ import annotations

import importlib

_MODULES = {
    "render_types": ("CameraParams", "RasterSettings", "Splats", "TileLists", "PixelMaps", "PixelAux", "SplatGrads",
                     "make_camera_params", "camera_params_from", "make_raster_settings", "make_struct"),
    "gaussian_math": ("RayHit", "quat_to_rotation", "sh_to_color", "pixel_ray", "ray_gaussian", "normal_direction"),
    "project": ("preprocess_gaussians", "project_frames", "sh_colour_backward", "screen_bounds", "ray_conics"),
    "binning": ("bin_gaussians", "TileListSizer"),
    "renderer": ("render_gaussians", "render_forward", "render_backward", "prepare_view", "RenderOutputs",
                 "RenderState", "sh_parts", "ScratchPool"),
    "opacity_field": ("opacity_along_ray", "opacity_along_ray_bounded", "point_view_tile", "opacity_min_over_view",
                      "opacity_min_over_view_whole"),
    "marching_tets": ("make_field_kernel", "field_params_type", "count_triangles", "write_triangle_edges",
                      "write_slot_ids", "mark_run_starts", "scatter_vertex_ids", "init_edge_brackets",
                      "bracket_midpoints", "update_brackets", "bracket_tree_midpoints", "descend_bracket_tree",
                      "tree_node", "interpolate_in_brackets", "count_nonfinite", "tet_case", "edge_key",
                      "build_case_tables"),
    "filter3d": ("nearest_seen_depth",),
    "reach": ("in_oriented_box", "oriented_box_bounds", "points_in_boxes"),
    "visibility": ("faces_seen",),
    "tsdf": ("integrate_tsdf", "sample_grid_trilinear"),
    "raycast": ("cast_pinhole_rays", "shade_hits", "resolve_pixels"),
    "undistort": ("distort_opencv", "undistort_remap"),
    "volume": ("store_voxels", "sample_volume_world", "lookup_stored_voxels"),
    "adam": ("adam_step",),
    "densify_stats": ("accumulate_view_stats",),
}
_WHERE = {name: module for module, names in _MODULES.items() for name in names}

# Documentation for stable names whose definition carries none (structs declared field by field).
_DOCS = {
    "CameraParams": """Pinhole camera (``wp.struct``), conventions of ``gof_warp.core.camera.Camera``.

    Fields: ``R: mat33`` world-to-camera rotation, ``t: vec3`` world-to-camera translation (world units),
    ``centre: vec3`` camera centre in world space (``-Rᵀ t``), ``fx, fy, cx, cy: float`` in pixels,
    ``width, height: int`` in pixels. Build it with ``make_camera_params`` or ``camera_params_from``.
    """,
    "RasterSettings": """Compositing thresholds and the tile grid (``wp.struct``), see ``docs/rendering.md``.

    Fields: ``near`` (view depth, world units), ``alpha_min``, ``alpha_max``, ``transmittance_min``,
    ``k_max`` (Mahalanobis cut-off), ``background: vec3`` (RGB in [0, 1]), ``tile_size`` (pixels),
    ``tiles_x, tiles_y``, ``pixel_pad`` (pixels), ``distortion_ndc`` (1 = GOF's NDC depth), ``far``,
    ``reduce_min_lanes``. Build it with ``make_raster_settings(width, height, ...)``.
    """,
}

__all__ = sorted(_WHERE)
assert not set(__all__) & set(_MODULES), "a public name may not be a submodule's name (the import would shadow it)"


def __getattr__(name):
    if name in _WHERE:
        value = getattr(importlib.import_module(f".{_WHERE[name]}", __name__), name)
        if not getattr(value, "__doc__", None) and name in _DOCS:
            value.__doc__ = _DOCS[name]
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_WHERE))
