"""Forward rasterisation: per pixel, front-to-back ray–Gaussian compositing over its tile's sorted list.

The per-(pixel, Gaussian) rule (GOF Sec. 3.1–3.2, ``docs/rendering.md``) is in :func:`gaussian_alpha`,
shared with the backward kernel so both make identical skip decisions.

Threads are numbered tile by tile (``tid = tile * tile_size² + local``) so that the threads of one CUDA
block work on one tile and read the same Gaussians at the same time (cache broadcast). Pixels of the
right/bottom border tiles outside the image return at once.

Per pixel the kernel writes the outputs (``rgb, alpha, accum_depth = Σ w t*, median_depth, normal,
distortion``) and what the backward needs: the final transmittance, the list position after the last
blended entry, the list position of the median Gaussian (−1 if none) and ``A_N = Σ w``.
"""

from __future__ import annotations

import warp as wp

from .gaussian_math import RayHit, normal_direction, pixel_ray, ray_gaussian, safe_normalize
from .render_types import CameraParams, PixelAux, PixelMaps, RasterSettings, Splats, TileLists

wp.set_module_options({"enable_backward": False})


@wp.func
def gaussian_alpha(h: RayHit, opacity: float, settings: RasterSettings) -> float:
    """Alpha of one (pixel, Gaussian) pair, or −1 when the pair is skipped (near, k_max, alpha_min)."""
    if not (h.t > settings.near):
        return -1.0
    if not (h.d2 <= settings.k_max * settings.k_max):
        return -1.0
    alpha = wp.min(settings.alpha_max, opacity * wp.exp(-0.5 * h.d2))
    if alpha < settings.alpha_min:
        return -1.0
    return alpha


@wp.func
def ray_outside(conic: wp.vec3, centre: wp.vec2, r: wp.vec3) -> bool:
    """The early reject: the camera-space ray ``r`` (``r.z = 1``) passes outside a Gaussian's silhouette
    (``project.ray_conics``), so the exact test would drop the pair; a few operations instead of
    :func:`~.gaussian_math.ray_gaussian`."""
    db = r[1] - centre[1]
    t = r[0] - centre[0] + conic[1] * db  # conic = (A, β, γ): A (da + β db)² + γ db² (tile_overlap.RayConic)
    return conic[0] * t * t + conic[2] * db * db > 1.0


@wp.func
def tile_pixel(tid: int, settings: RasterSettings) -> wp.vec3i:
    """``(tile, px, py)`` of thread ``tid`` in the tile-major numbering."""
    n = settings.tile_size * settings.tile_size
    tile = tid / n
    local = tid - tile * n
    ty = tile / settings.tiles_x
    tx = tile - ty * settings.tiles_x
    return wp.vec3i(tile, tx * settings.tile_size + local % settings.tile_size, ty * settings.tile_size + local / settings.tile_size)


@wp.struct
class PixelState:
    """Running sums of one pixel's front-to-back walk."""

    T: float  # transmittance before the next Gaussian
    c: wp.vec3  # Σ w c
    n: wp.vec3  # Σ w n̂
    A: float  # Σ w
    B: float  # Σ w t*
    D: float  # distortion
    Bf: float  # Σ w f (f = distortion_depth(t*))
    Cf: float  # Σ w f²
    med: float  # median depth candidate
    med_p: int  # its list position (−1: none)
    med_found: int  # 1 once T crossed 0.5
    last: int  # list position after the last blended entry
    done: int  # 1 once the transmittance stop was hit (or the pixel is outside the image)


@wp.func
def pixel_state_init(start: int, done: int) -> PixelState:
    s = PixelState()
    s.T = 1.0
    s.med_p = -1
    s.last = start
    s.done = done
    return s


@wp.func
def ndc_depth(t: float, settings: RasterSettings) -> float:
    """GOF's NDC depth ``m(t) = far (t − n) / ((far − n) t)``, ``n = settings.ndc_near``."""
    return settings.far * (t - settings.ndc_near) / ((settings.far - settings.ndc_near) * t)


@wp.func
def ndc_depth_slope(t: float, settings: RasterSettings) -> float:
    """``m'(t) = far n / ((far − n) t²)``, ``n = settings.ndc_near``."""
    return settings.far * settings.ndc_near / ((settings.far - settings.ndc_near) * t * t)


@wp.func
def distortion_depth(t: float, settings: RasterSettings) -> float:
    """The depth the distortion compares: GOF's NDC depth ``m(t) = far (t − near) / ((far − near) t)``
    (2DGS/GOF code), or ``t`` itself (the paper's formula). With ``linear_from = L > 0`` the NDC depth is
    continued beyond ``L`` by its tangent there, ``m(L) + m'(L) (t − L)``: layers behind ``L`` keep the weight they
    have at ``L`` instead of fading as ``1/t²``."""
    if settings.distortion_ndc != 0:
        L = settings.linear_from
        if L > 0.0 and t > L:
            return ndc_depth(L, settings) + ndc_depth_slope(L, settings) * (t - L)
        return ndc_depth(t, settings)
    return t


@wp.func
def distortion_depth_grad(t: float, settings: RasterSettings) -> float:
    """``d f / d t`` of :func:`distortion_depth`."""
    if settings.distortion_ndc != 0:
        if settings.linear_from > 0.0 and t > settings.linear_from:
            return ndc_depth_slope(settings.linear_from, settings)
        return ndc_depth_slope(t, settings)
    return 1.0


@wp.func
def composite(s: PixelState, e: int, Pk: wp.mat33, og: wp.vec3, col: wp.vec3, op: float, r: wp.vec3, settings: RasterSettings) -> PixelState:
    """Blend list entry ``e`` (Gaussian ``(Pk, og, col, op)``) into the pixel's state (GOF Sec. 3.1)."""
    h = ray_gaussian(Pk, og, r)
    alpha = gaussian_alpha(h, op, settings)
    if alpha < 0.0:
        return s
    T_next = s.T * (1.0 - alpha)
    if T_next < settings.transmittance_min:
        s.done = 1
        return s
    w = alpha * s.T
    s.c = s.c + w * col
    s.n = s.n + w * safe_normalize(normal_direction(Pk, h.r_g, h.a))
    f = distortion_depth(h.t, settings)
    if settings.distortion_ndc != 0:
        s.D = s.D + w * (f * f * s.A - 2.0 * f * s.Bf + s.Cf)
    else:
        s.D = s.D + 2.0 * w * (f * s.A - s.Bf)
    s.A = s.A + w
    s.B = s.B + w * h.t
    s.Bf = s.Bf + w * f
    s.Cf = s.Cf + w * f * f
    if s.med_found == 0:
        s.med = h.t
        s.med_p = e
        if T_next <= 0.5:
            s.med_found = 1
    s.T = T_next
    s.last = e + 1
    return s


@wp.func
def write_pixel(s: PixelState, pix: int, settings: RasterSettings, out: PixelMaps, aux: PixelAux):
    out.rgb[pix] = s.c + s.T * settings.background
    out.alpha[pix] = 1.0 - s.T
    out.accum_depth[pix] = s.B
    out.median_depth[pix] = s.med
    out.normal[pix] = s.n
    out.distortion[pix] = s.D
    aux.final_T[pix] = s.T
    aux.last_end[pix] = s.last
    aux.median_pos[pix] = s.med_p
    aux.weight_sum[pix] = s.A
    aux.dist_sum[pix] = s.Bf


@wp.kernel
def rasterize_forward(lists: TileLists, splats: Splats, cam: CameraParams, settings: RasterSettings, out: PixelMaps, aux: PixelAux):
    """Launch with ``tiles_x * tiles_y * tile_size²`` threads; per-pixel outputs are ``[H*W]`` row-major."""
    tp = tile_pixel(wp.tid(), settings)
    px = tp[1]
    py = tp[2]
    if px >= cam.width or py >= cam.height:
        return
    r = pixel_ray(px, py, cam.fx, cam.fy, cam.cx, cam.cy)
    start = lists.range_start[tp[0]]
    s = pixel_state_init(start, 0)
    for e in range(start, lists.range_end[tp[0]]):
        g = lists.values[e]
        if ray_outside(splats.conic[g], splats.centre[g], r):
            continue
        s = composite(s, e, splats.P[g], splats.o_g[g], splats.colour[g], splats.opacity[g], r, settings)
        if s.done != 0:
            break
    write_pixel(s, py * cam.width + px, settings, out, aux)
