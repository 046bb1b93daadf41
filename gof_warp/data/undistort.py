"""Lens cameras with OpenCV radial-tangential distortion, and their undistortion to pinhole cameras.

A :class:`LensCamera` is the intrinsics of a distorted camera as a file stores them (COLMAP SIMPLE_RADIAL,
RADIAL, OPENCV, FULL_OPENCV with k4 = k5 = k6 = 0; instant-ngp/nerfstudio ``k1 k2 [k3] p1 p2``). All
those models are the OpenCV model (``kernels/undistort.py`` writes it out) with some terms zero.

The undistorted camera keeps the image size and the principal point; its focal lengths are the file's
multiplied by one factor ``s`` (:func:`undistorted_intrinsics`):

* ``mode="valid"`` (default): the smallest ``s`` such that every output pixel's ray lands inside the
  distorted input image — no blank (invented) pixels, as COLMAP's ``image_undistorter`` does by default
  with ``blank_pixels=0``, but keeping the image size instead of changing it, so all views of a camera rig
  stay the same size. ``s > 1`` (zoom in) for pincushion-like distortion (``k1 > 0``) and ``s < 1`` for
  barrel distortion; clamped to ``[0.5, 2]``.
* ``mode="same"``: ``s = 1``, the file's K; corners whose rays leave the input are filled with the
  background colour.

Images are resampled by :func:`undistort_image` with the Warp kernel ``undistort_remap`` (bilinear,
forward mapping — no inversion needed). Point coordinates go the other way with
:func:`undistort_normalized` (Newton's method, float64).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..core.camera import Intrinsics
from ..core.errors import SceneError

log = logging.getLogger(__name__)

UNDISTORT_MODES = ("valid", "same")
_SCALE_LIMITS = (0.5, 2.0)  # a sane zoom range for the "valid" focal factor (COLMAP uses 0.2..2)
_NEWTON_ITERATIONS = 20
_NEWTON_TOL = 1e-12  # normalised units; far below a pixel for any focal length < 1e9


def default_device() -> str:
    """Warp's name of the default device (:func:`gof_warp.core.devices.resolve_device`'s rule)."""
    from ..core.devices import warp_device

    return warp_device(None)


@dataclass(frozen=True)
class LensCamera(Intrinsics):
    """A distorted camera (OpenCV model): pinhole :class:`~gof_warp.core.camera.Intrinsics` (``fx fy cx cy width
    height``, keyword-only, declared once there) plus the distortion coefficients, in pixels of a
    ``width × height`` image.

    Pixel coordinates follow :mod:`gof_warp.core.camera` (pixel centres at ``i + 0.5``). ``k1 k2 k3`` (radial) and
    ``p1 p2`` (tangential) are in normalised camera units; ``model`` is the file's camera model name, for
    messages. Compared by value.
    """

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    model: str = "OPENCV"

    def _what(self) -> str:
        return f"lens camera ({self.model})"

    def __post_init__(self):
        super().__post_init__()
        self._finite_numbers(("k1", "k2", "p1", "p2", "k3"), label="distortion ")

    @property
    def has_distortion(self) -> bool:
        return any(v != 0.0 for v in (self.k1, self.k2, self.p1, self.p2, self.k3))

    def scaled(self, width: int, height: int) -> "LensCamera":
        """The same lens for the image resized to ``width × height`` (:meth:`~gof_warp.core.camera.Intrinsics.resized`;
        distortion is in normalised units and does not change)."""
        return self.resized(width, height)


def distort_normalized(xy: np.ndarray, lens: LensCamera) -> np.ndarray:
    """Undistorted normalised coordinates ``[N, 2]`` → distorted ones (float64; formula in ``kernels/undistort.py``)."""
    xy = np.asarray(xy, dtype=np.float64)
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (lens.k1 + r2 * (lens.k2 + r2 * lens.k3))
    xd = x * radial + 2.0 * lens.p1 * x * y + lens.p2 * (r2 + 2.0 * x * x)
    yd = y * radial + lens.p1 * (r2 + 2.0 * y * y) + 2.0 * lens.p2 * x * y
    return np.stack([xd, yd], axis=1)


def _distortion_jacobian(xy: np.ndarray, lens: LensCamera) -> np.ndarray:
    """``[N, 2, 2]`` derivative of :func:`distort_normalized`."""
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (lens.k1 + r2 * (lens.k2 + r2 * lens.k3))
    dradial_dr2 = lens.k1 + r2 * (2.0 * lens.k2 + 3.0 * r2 * lens.k3)
    J = np.empty((len(xy), 2, 2))
    J[:, 0, 0] = radial + 2.0 * x * x * dradial_dr2 + 2.0 * lens.p1 * y + 6.0 * lens.p2 * x
    J[:, 0, 1] = 2.0 * x * y * dradial_dr2 + 2.0 * lens.p1 * x + 2.0 * lens.p2 * y
    J[:, 1, 0] = 2.0 * x * y * dradial_dr2 + 2.0 * lens.p1 * x + 2.0 * lens.p2 * y
    J[:, 1, 1] = radial + 2.0 * y * y * dradial_dr2 + 6.0 * lens.p1 * y + 2.0 * lens.p2 * x
    return J


def undistort_normalized(xy_d: np.ndarray, lens: LensCamera) -> np.ndarray:
    """Distorted normalised coordinates ``[N, 2]`` → undistorted ones (Newton's method, float64).

    Starts from ``xy_d`` and converges in a few steps for the distortions real lenses have; points where
    the distortion is not invertible (far outside the calibrated field of view) come back as NaN.
    """
    xy_d = np.asarray(xy_d, dtype=np.float64).reshape(-1, 2)
    xy = xy_d.copy()
    for _ in range(_NEWTON_ITERATIONS):
        residual = distort_normalized(xy, lens) - xy_d
        if np.all(np.abs(residual) < _NEWTON_TOL):
            break
        step = np.linalg.solve(_distortion_jacobian(xy, lens), residual[:, :, None])[:, :, 0]
        xy -= step
    bad = np.abs(distort_normalized(xy, lens) - xy_d).max(axis=1) > 1e-6
    xy[bad] = np.nan
    return xy


def undistort_pixels(uv: np.ndarray, lens: LensCamera, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Pixel coordinates ``[N, 2]`` in the distorted image → pixel coordinates in the pinhole image with
    intrinsics ``(fx, fy, cx, cy)`` (e.g. a :class:`~gof_warp.core.camera.Camera` from :func:`undistorted_intrinsics`)."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    xy_d = np.stack([(uv[:, 0] - lens.cx) / lens.fx, (uv[:, 1] - lens.cy) / lens.fy], axis=1)
    xy = undistort_normalized(xy_d, lens)
    return np.stack([fx * xy[:, 0] + cx, fy * xy[:, 1] + cy], axis=1)


def _border_pixels(width: int, height: int, n: int = 101):
    """Points along the four edges of the image rectangle (continuous coordinates): left, right, top, bottom."""
    ys = np.linspace(0.0, height, n)
    xs = np.linspace(0.0, width, n)
    left = np.stack([np.zeros(n), ys], axis=1)
    right = np.stack([np.full(n, float(width)), ys], axis=1)
    top = np.stack([xs, np.zeros(n)], axis=1)
    bottom = np.stack([xs, np.full(n, float(height))], axis=1)
    return left, right, top, bottom


def undistorted_intrinsics(lens: LensCamera, mode: str = "valid") -> tuple[float, float, float, float]:
    """``(fx, fy, cx, cy)`` of the pinhole camera that :func:`undistort_image` renders (same image size).

    See the module docstring for the two modes. For ``"valid"``: the distorted image's border, undistorted,
    bounds the region of rays we have data for; the output's normalised rectangle
    ``[-cx/(s fx), (W-cx)/(s fx)] × [-cy/(s fy), (H-cy)/(s fy)]`` must fit inside it, which fixes ``s``.
    """
    if mode not in UNDISTORT_MODES:
        raise SceneError(f"undistortion mode must be one of {UNDISTORT_MODES}, got {mode!r}")
    if mode == "same" or not lens.has_distortion:
        return lens.fx, lens.fy, lens.cx, lens.cy
    left, right, top, bottom = (
        undistort_normalized(np.stack([(b[:, 0] - lens.cx) / lens.fx, (b[:, 1] - lens.cy) / lens.fy], axis=1), lens)
        for b in _border_pixels(lens.width, lens.height)
    )
    if any(np.isnan(b).any() for b in (left, right, top, bottom)):
        raise SceneError(f"lens distortion {lens} cannot be inverted at the image border")
    # Inner-most extent of the data on each side, in normalised units (negative on the left/top).
    x_left, x_right = left[:, 0].max(), right[:, 0].min()
    y_top, y_bottom = top[:, 1].max(), bottom[:, 1].min()
    need = []
    if lens.cx > 0:
        need.append((-lens.cx / lens.fx) / x_left)
    if lens.cx < lens.width:
        need.append(((lens.width - lens.cx) / lens.fx) / x_right)
    if lens.cy > 0:
        need.append((-lens.cy / lens.fy) / y_top)
    if lens.cy < lens.height:
        need.append(((lens.height - lens.cy) / lens.fy) / y_bottom)
    s = float(max(need))
    if not _SCALE_LIMITS[0] <= s <= _SCALE_LIMITS[1]:
        log.warning("undistortion zoom %.3f clamped to %s: some output pixels will be blank (%s)", s, _SCALE_LIMITS, lens)
        s = float(np.clip(s, *_SCALE_LIMITS))
    return lens.fx * s, lens.fy * s, lens.cx, lens.cy


def undistort_image(image: np.ndarray, lens: LensCamera, fx, fy, cx, cy, background=0.0, device=None) -> np.ndarray:
    """Resample a distorted ``uint8`` image onto the pinhole camera ``(fx, fy, cx, cy)`` of the same size.

    Args:
        image: ``[H, W]`` (a mask) or ``[H, W, C]`` uint8, ``H × W == lens.height × lens.width``.
        lens: the distorted camera the image was taken with.
        fx, fy, cx, cy: the output pinhole intrinsics (usually from :func:`undistorted_intrinsics`).
        background: scalar or ``[C]`` values in ``[0, 1]`` for output pixels that see outside the input.
        device: Warp device (default: CUDA if available, else CPU).

    Returns:
        Array of the same shape and dtype as ``image``.
    """
    from ..kernels.undistort import undistort_remap

    device = device or default_device()
    img = np.ascontiguousarray(image, dtype=np.uint8)
    squeeze = img.ndim == 2
    if squeeze:
        img = img[:, :, None]
    channels = img.shape[2]
    bg = np.broadcast_to(np.asarray(background, dtype=np.float32) * 255.0, (channels,)).copy()
    src = wp.array(img, dtype=wp.uint8, device=device)
    dst = wp.empty(img.shape, dtype=wp.uint8, device=device)
    wp.launch(
        undistort_remap,
        dim=img.shape[:2],
        inputs=[
            src,
            wp.vec4(lens.fx, lens.fy, lens.cx, lens.cy),
            wp.vec3(lens.k1, lens.k2, lens.k3),
            wp.vec2(lens.p1, lens.p2),
            wp.vec4(fx, fy, cx, cy),
            wp.array(bg, dtype=wp.float32, device=device),
        ],
        outputs=[dst],
        device=device,
    )
    out = dst.numpy()
    return out[:, :, 0] if squeeze else out
