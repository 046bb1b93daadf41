"""Structs passed to the renderer's kernels, and host helpers that fill them (no torch).

``CameraParams`` holds a pinhole camera in the conventions of ``gof_warp.core.camera.Camera`` (world-to-camera
``R, t``; OpenCV axes; pixel centres at ``i + 0.5``). ``RasterSettings`` holds the thresholds of the
compositing rule (``docs/rendering.md``) and the tile grid.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp


@wp.struct
class CameraParams:
    R: wp.mat33  # world-to-camera rotation
    t: wp.vec3  # world-to-camera translation
    centre: wp.vec3  # camera centre in world space (= -Rᵀ t)
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int


@wp.struct
class RasterSettings:
    near: float  # cull Gaussians with view z <= near, skip intersections with t* <= near
    alpha_min: float  # skip (pixel, Gaussian) pairs with alpha < alpha_min
    alpha_max: float  # alpha = min(alpha_max, opacity * E)
    transmittance_min: float  # stop before a Gaussian that would bring T below this
    k_max: float  # skip pairs whose Mahalanobis ray distance exceeds k_max (binning cap)
    background: wp.vec3
    tile_size: int
    tiles_x: int
    tiles_y: int
    pixel_pad: float  # bin a Gaussian into pixels within this many pixels of its box (0 = pixel centres)
    distortion_ndc: int  # 1: GOF's Σ w_i w_j (m_i − m_j)² on NDC depth m(t); 0: the paper's Σ w_i w_j |t_i − t_j|
    far: float  # far plane of the NDC depth map m(t) = far (t − ndc_near) / ((far − ndc_near) t)
    ndc_near: float  # near plane of that map (GOF: 0.2); ``near`` above may clip further out for one camera
    linear_from: float  # > 0: m(t) continued by its tangent beyond this depth (0: GOF's m(t) everywhere)
    reduce_min_lanes: int  # CUDA backward: sum an entry's gradients over the warp when at least this many of its lanes blend it
    tile_cull: int  # 1: bin into the tiles the projected ellipse meets; 0: every tile of its bounding box


def make_camera_params(R, t, fx, fy, cx, cy, width, height) -> CameraParams:
    """``CameraParams`` from host numbers (``R [3,3]``, ``t [3]`` world-to-camera)."""
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    cam = CameraParams()
    cam.R = wp.mat33(*R.astype(np.float32).ravel())
    cam.t = wp.vec3(*t.astype(np.float32))
    cam.centre = wp.vec3(*(-R.T @ t).astype(np.float32))
    cam.fx, cam.fy, cam.cx, cam.cy = float(fx), float(fy), float(cx), float(cy)
    cam.width, cam.height = int(width), int(height)
    return cam


def camera_params_from(camera) -> CameraParams:
    """``CameraParams`` from any object with ``R, t, fx, fy, cx, cy, width, height`` (e.g. ``Camera``)."""
    return make_camera_params(camera.R, camera.t, camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)


DEFAULT_K_MAX = math.sqrt(2.0 * math.log(255.0))


def make_raster_settings(
    width: int,
    height: int,
    near: float = 0.2,
    alpha_min: float = 1.0 / 255.0,
    alpha_max: float = 0.99,
    transmittance_min: float = 1e-4,
    k_max: float = DEFAULT_K_MAX,
    background=(0.0, 0.0, 0.0),
    tile_size: int = 16,
    reduce_min_lanes: int = 16,
    pixel_pad: float = 0.0,
    distortion: str = "gof",
    far: float = 100.0,
    tile_cull: bool = True,
    distortion_linear_from: float = 0.0,
    ndc_near: float | None = None,
) -> RasterSettings:
    """``RasterSettings`` for a ``width`` × ``height`` image (defaults: GOF's, see ``RenderConfig``).

    ``near`` is the clipping depth (culling and ``t* ≤ near``); ``ndc_near`` (default: ``near``) the near plane of
    the distortion's NDC depth ``m(t)``, so a camera may clip further out without changing what the distortion
    measures."""
    s = RasterSettings()
    s.near, s.alpha_min, s.alpha_max = float(near), float(alpha_min), float(alpha_max)
    s.transmittance_min, s.k_max = float(transmittance_min), float(k_max)
    s.background = wp.vec3(*[float(b) for b in background])
    s.tile_size = int(tile_size)
    s.pixel_pad = float(pixel_pad)
    if distortion not in ("gof", "paper"):
        raise ValueError(f"distortion must be 'gof' or 'paper', got {distortion!r}")
    s.distortion_ndc = 1 if distortion == "gof" else 0
    s.far = float(far)
    s.ndc_near = float(near if ndc_near is None else ndc_near)
    if not 0.0 < s.ndc_near <= s.near:
        raise ValueError(f"ndc_near must be in (0, near = {near}], got {ndc_near}")
    if not (distortion_linear_from == 0.0 or distortion_linear_from > s.ndc_near):
        raise ValueError(f"distortion_linear_from must be 0 (off) or beyond near {s.ndc_near}, got {distortion_linear_from}")
    s.linear_from = float(distortion_linear_from)
    if int(reduce_min_lanes) < 1:
        raise ValueError(f"reduce_min_lanes must be at least 1, got {reduce_min_lanes}")
    s.reduce_min_lanes = int(reduce_min_lanes)
    s.tile_cull = 1 if tile_cull else 0
    s.tiles_x = (int(width) + s.tile_size - 1) // s.tile_size
    s.tiles_y = (int(height) + s.tile_size - 1) // s.tile_size
    return s


@wp.struct
class Splats:
    """Per-Gaussian data the per-pixel kernels read (``[N]`` each)."""

    P: wp.array(dtype=wp.mat33)  # S⁻¹ R_vᵀ
    o_g: wp.array(dtype=wp.vec3)  # −P μ_v
    colour: wp.array(dtype=wp.vec3)
    opacity: wp.array(dtype=float)
    mu_v: wp.array(dtype=wp.vec3)  # camera-space means (depth for the densification statistics)
    radius: wp.array(dtype=wp.int32)  # screen radius in pixels
    conic: wp.array(dtype=wp.vec3)  # early reject: silhouette (A, β, γ) in normalised coordinates (project.ray_conics)
    centre: wp.array(dtype=wp.vec2)  # … and its centre (x/z, y/z); conic 0: nothing rejected


@wp.struct
class TileLists:
    """Sorted Gaussian indices per tile: tile ``t`` owns ``values[range_start[t]:range_end[t]]``."""

    values: wp.array(dtype=wp.int32)
    range_start: wp.array(dtype=wp.int32)
    range_end: wp.array(dtype=wp.int32)


@wp.struct
class PixelMaps:
    """Per-pixel outputs (or their gradients), flat ``[H*W]`` row-major."""

    rgb: wp.array(dtype=wp.vec3)
    alpha: wp.array(dtype=float)
    accum_depth: wp.array(dtype=float)
    median_depth: wp.array(dtype=float)
    normal: wp.array(dtype=wp.vec3)
    distortion: wp.array(dtype=float)


@wp.struct
class PixelAux:
    """Per-pixel forward state kept for the backward (``[H*W]``)."""

    final_T: wp.array(dtype=float)
    last_end: wp.array(dtype=wp.int32)  # list position after the last blended entry
    median_pos: wp.array(dtype=wp.int32)  # list position of the median Gaussian, −1 if none
    weight_sum: wp.array(dtype=float)  # A_N = Σ w
    dist_sum: wp.array(dtype=float)  # Σ w f(t*), f the distortion's depth map (NDC m or t)


#: Columns of ``SplatGrads.packed``: ∂L/∂P (9, row-major), ∂L/∂o_g (3), ∂L/∂colour (3), ∂L/∂opacity (1) — 16 floats,
#: four 16-byte groups, so the CUDA backward adds a pair's gradients with four vector atomics (sm_90) instead of 16.
GRAD_P = wp.constant(0)
GRAD_O_G = wp.constant(9)
GRAD_COLOUR = wp.constant(12)
GRAD_OPACITY = wp.constant(15)
GRAD_WIDTH = 16


@wp.struct
class SplatGrads:
    """Per-Gaussian gradient accumulators of the per-pixel backward (added into)."""

    packed: wp.array2d(dtype=float)  # [N, GRAD_WIDTH], 16-byte aligned rows (see GRAD_* above)
    grad2d_abs: wp.array(dtype=float)  # [N] Σ_p ‖g_p‖ (written only when statistics are requested)


def make_struct(cls, **arrays):
    """A Warp struct instance with its array fields set."""
    s = cls()
    for k, v in arrays.items():
        setattr(s, k, v)
    return s
