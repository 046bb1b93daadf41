"""Lens undistortion: the OpenCV radial-tangential distortion and a bilinear remap of ``uint8`` images.

Pure Warp (no torch). The host-side launcher, the inverse distortion and the choice of the output
pinhole camera live in :mod:`gof_warp.data.undistort`.

Conventions (``gof_warp/camera.py``): continuous pixel coordinates with the centre of pixel ``(i, j)`` at
``(i + 0.5, j + 0.5)``; normalised camera coordinates ``x = X/Z, y = Y/Z``.

Distortion (OpenCV, also COLMAP's SIMPLE_RADIAL / RADIAL / OPENCV with the missing terms zero), applied to
undistorted normalised coordinates ``(x, y)``, ``r² = x² + y²``::

    radial = 1 + k1 r² + k2 r⁴ + k3 r⁶
    x_d = x · radial + 2 p1 x y + p2 (r² + 2 x²)
    y_d = y · radial + p1 (r² + 2 y²) + 2 p2 x y

The remap is the forward direction, which needs no inversion: each pixel of the undistorted (pinhole)
output casts its normalised ray, distorts it, and samples the distorted input there bilinearly.
"""

from __future__ import annotations

import warp as wp


@wp.func
def distort_opencv(xy: wp.vec2, k: wp.vec3, p: wp.vec2) -> wp.vec2:
    """Undistorted normalised ``xy`` → distorted normalised coordinates; ``k = (k1, k2, k3)``, ``p = (p1, p2)``."""
    x = xy[0]
    y = xy[1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[2]))
    xd = x * radial + 2.0 * p[0] * x * y + p[1] * (r2 + 2.0 * x * x)
    yd = y * radial + p[0] * (r2 + 2.0 * y * y) + 2.0 * p[1] * x * y
    return wp.vec2(xd, yd)


@wp.func
def _round_u8(value: float) -> wp.uint8:
    """Round to the nearest integer and clamp to ``[0, 255]``."""
    return wp.uint8(int(wp.clamp(wp.floor(value + 0.5), 0.0, 255.0)))


@wp.kernel
def undistort_remap(
    src: wp.array3d(dtype=wp.uint8),
    src_K: wp.vec4,
    k: wp.vec3,
    p: wp.vec2,
    dst_K: wp.vec4,
    background: wp.array(dtype=wp.float32),
    dst: wp.array3d(dtype=wp.uint8),
):
    """Resample a distorted image onto an undistorted pinhole grid.

    Launch with ``dim = (H_dst, W_dst)``.

    Args:
        src: ``[H_src, W_src, C]`` distorted image (RGB, RGBA or a mask with ``C = 1``).
        src_K: ``(fx, fy, cx, cy)`` of the distorted camera, pixels.
        k, p: distortion coefficients ``(k1, k2, k3)`` and ``(p1, p2)``.
        dst_K: ``(fx, fy, cx, cy)`` of the pinhole output camera, pixels.
        background: ``[C]`` values in ``[0, 255]`` for output pixels whose ray lands outside the input
            image rectangle ``[0, W_src] × [0, H_src]``.
        dst: ``[H_dst, W_dst, C]`` output; values rounded to nearest.
    """
    j, i = wp.tid()
    xy = wp.vec2((float(i) + 0.5 - dst_K[2]) / dst_K[0], (float(j) + 0.5 - dst_K[3]) / dst_K[1])
    xy_d = distort_opencv(xy, k, p)
    u = src_K[0] * xy_d[0] + src_K[2]
    v = src_K[1] * xy_d[1] + src_K[3]
    h = src.shape[0]
    w = src.shape[1]
    if u < 0.0 or u > float(w) or v < 0.0 or v > float(h):
        for c in range(dst.shape[2]):
            dst[j, i, c] = _round_u8(background[c])
        return
    # Bilinear taps in index space (pixel centres at integers), edges clamped.
    x = u - 0.5
    y = v - 0.5
    x0f = wp.floor(x)
    y0f = wp.floor(y)
    ax = x - x0f
    ay = y - y0f
    x0 = wp.clamp(int(x0f), 0, w - 1)
    x1 = wp.clamp(int(x0f) + 1, 0, w - 1)
    y0 = wp.clamp(int(y0f), 0, h - 1)
    y1 = wp.clamp(int(y0f) + 1, 0, h - 1)
    for c in range(dst.shape[2]):
        top = (1.0 - ax) * float(src[y0, x0, c]) + ax * float(src[y0, x1, c])
        bottom = (1.0 - ax) * float(src[y1, x0, c]) + ax * float(src[y1, x1, c])
        val = (1.0 - ay) * top + ay * bottom
        dst[j, i, c] = _round_u8(val)
