"""Hand-written backward of :func:`rasterize_forward` (per pixel) and the per-Gaussian chain rule.

Per pixel the list is walked back to front from the last blended entry, recovering the transmittance
before each Gaussian by division, ``T_k = T_{k+1} / (1 − α_k)`` (as 3DGS). For a blended quantity
``F = Σ_k f_k w_k`` with ``w_k = α_k T_k``, ``∂F/∂α_k = T_k f_k − (Σ_{j>k} f_j w_j) / (1 − α_k)``, and
``T_N`` (background, ``alpha = 1 − T_N``) gives ``∂T_N/∂α_k = −T_N / (1 − α_k)``. The per-pixel output
gradients are constant along the walk, so all channels fold into one running scalar suffix ``S``.

The median depth passes gradient only to its Gaussian's ``t*``; the distortion (weights detached) only
through ``∂D/∂t_k = 2 w_k (A_{k−1} − (A_N − A_k))`` with ``A_k = Σ_{j≤k} w_j``.

Geometry (``x_c = o_g + t* r_g``, ``d² = ‖x_c‖²``, ``t* = −(o_g·r_g)/A``; since ``t*`` minimises
``‖o_g + t r_g‖²``, ``∂d²/∂o_g = 2 x_c`` and ``∂d²/∂r_g = 2 t* x_c``):

* ``∂t*/∂o_g = −r_g / A``, ``∂t*/∂r_g = −(x_c + t* r_g) / A``;
* normal ``n̂ = m/‖m‖``, ``m = −Pᵀ r_g``: ``∂L/∂m = (g − n̂(n̂·g))/‖m‖``, ``∂L/∂r_g −= P ∂L/∂m``,
  ``∂L/∂P −= r_g ⊗ ∂L/∂m``;
* ``r_g = P r``: ``∂L/∂P += ∂L/∂r_g ⊗ r``.

Per (pixel, Gaussian) the kernel atomically adds ``∂L/∂P`` (9), ``∂L/∂o_g`` (3), ``∂L/∂colour`` (3),
``∂L/∂opacity`` (1) — one 16-float row of ``SplatGrads.packed``, four vector atomics on sm_90 (H100/H200), 16 scalar
ones elsewhere — and, when densification statistics are requested, the per-pixel norm of the screen-space
gradient (1). The chain to ``means, quats, scales, sh`` is the gradient of the loop-free ``preprocess_gaussians``:
Warp's adjoint of its camera-space half ``project.project_frames`` and the written-out ``project.sh_colour_backward``.
"""

from __future__ import annotations

import warp as wp

from .gaussian_math import normal_direction, pixel_ray, ray_gaussian
from .rasterize import distortion_depth, distortion_depth_grad, gaussian_alpha, ray_outside, tile_pixel
from .render_types import GRAD_COLOUR, GRAD_O_G, GRAD_OPACITY, GRAD_P, CameraParams, PixelAux, PixelMaps, RasterSettings, SplatGrads, Splats, TileLists

wp.set_module_options({"enable_backward": False})


@wp.func
def screen_gradient(P: wp.mat33, dL_dog: wp.vec3, z: float, cam: CameraParams) -> wp.vec2:
    """Gradient w.r.t. the projected mean (u, v) at fixed depth, in NDC units (3DGS's ×W/2, ×H/2).

    ``o_g = −P μ_v`` and ``∂μ_v/∂u = (z/fx, 0, 0)``, ``∂μ_v/∂v = (0, z/fy, 0)``.
    """
    g = -(wp.transpose(P) * dL_dog)
    return wp.vec2(g[0] * z / cam.fx * 0.5 * float(cam.width), g[1] * z / cam.fy * 0.5 * float(cam.height))


@wp.struct
class PixelGrads:
    """Per-pixel constants of the backward walk."""

    gc: wp.vec3  # ∂L/∂rgb
    gD: float  # ∂L/∂accum_depth
    gN: wp.vec3  # ∂L/∂normal
    gDist: float  # ∂L/∂distortion
    gMed: float  # ∂L/∂median_depth
    A_N: float  # Σ w
    Bf_N: float  # Σ w f (distortion depth)
    median_pos: int
    bg_term: float  # T_N (∂L/∂rgb·background − ∂L/∂alpha)


@wp.struct
class BackState:
    T: float  # transmittance after the current entry (before it, once divided)
    S: float  # Σ_{j>k} w_j f_j
    suffix_w: float  # Σ_{j>k} w_j = A_N − A_k


@wp.func
def pixel_grads(pix: int, settings: RasterSettings, aux: PixelAux, gout: PixelMaps) -> PixelGrads:
    pg = PixelGrads()
    pg.gc = gout.rgb[pix]
    pg.gD = gout.accum_depth[pix]
    pg.gN = gout.normal[pix]
    pg.gDist = gout.distortion[pix]
    pg.gMed = gout.median_depth[pix]
    pg.A_N = aux.weight_sum[pix]
    pg.Bf_N = aux.dist_sum[pix]
    pg.median_pos = aux.median_pos[pix]
    pg.bg_term = aux.final_T[pix] * (wp.dot(pg.gc, settings.background) - gout.alpha[pix])
    return pg


_WARP_SUM = """
#if defined(__CUDA_ARCH__)
for (int o = 16; o > 0; o >>= 1) x += __shfl_xor_sync(0xffffffffu, x, o);
#endif
return x;
"""


@wp.func_native(_WARP_SUM)
def warp_sum(x: float) -> float:
    """Sum of ``x`` over the 32 lanes of the CUDA warp (all lanes must call it); identity on the CPU."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return __popc(__ballot_sync(0xffffffffu, p != 0));
#else
return p != 0 ? 1 : 0;
#endif
""")
def warp_count(p: int) -> int:
    """Number of lanes of the CUDA warp with non-zero ``p`` (all lanes must call it); on the CPU: ``p != 0``."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
return lane & 31;
#else
return 0;
#endif
""")
def lane_in_warp(lane: int) -> int:
    """Lane within the CUDA warp of block thread ``lane`` (0 on the CPU, where every thread adds its own)."""
    ...


@wp.func_native("""
float* p = wp::address(buf, i, j);
#if defined(__CUDA_ARCH__) && (__CUDA_ARCH__ >= 900)
asm volatile("{ .reg .u64 ga; cvta.to.global.u64 ga, %0; red.global.add.v4.f32 [ga], {%1, %2, %3, %4}; }"
             :: "l"(p), "f"(v[0]), "f"(v[1]), "f"(v[2]), "f"(v[3]) : "memory");
#else
for (int c = 0; c < 4; ++c) wp::atomic_add(p + c, v[c]);
#endif
""")
def atomic_add4(buf: wp.array2d(dtype=float), i: int, j: int, v: wp.vec4):
    """``buf[i, j:j+4] += v`` atomically: one 16-byte vector reduction on sm_90 (``buf[i, j]`` 16-byte aligned), four
    scalar atomics on other GPUs and the CPU."""
    ...


vec16 = wp.types.vector(length=16, dtype=float)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
float a[16];
#pragma unroll
for (int k = 0; k < 16; ++k) a[k] = v.c[k];
const int ln = lane & 31;
#pragma unroll
for (int m = 8, off = 16; m >= 1; m >>= 1, off >>= 1) {
    const bool up = (ln & off) != 0;
#pragma unroll
    for (int k = 0; k < m; ++k) {
        const float send = up ? a[k] : a[k + m];
        const float keep = up ? a[k + m] : a[k];
        a[k] = keep + __shfl_xor_sync(0xffffffffu, send, off);
    }
}
const float s = a[0] + __shfl_xor_sync(0xffffffffu, a[0], 1);
if ((ln & 1) == 0) atomicAdd(wp::address(buf, i, ln >> 1), s);
#else
for (int k = 0; k < 16; ++k) wp::atomic_add(wp::address(buf, i, k), v.c[k]);
#endif
""")
def warp_add16(buf: wp.array2d(dtype=float), i: int, v: vec16, lane: int):
    """``buf[i, 0:16] += Σ_lanes v`` for the whole CUDA warp (every lane must call it, with the same ``i``).

    Recursive halving: at each of the offsets 16, 8, 4, 2 a lane keeps half of its values and sends the other half to
    its partner, so after 16 shuffles (not 16 × 5) lane ``2c`` holds the warp's sum of value ``c`` and adds it: one
    16-lane atomic instruction on 16 consecutive floats. On the CPU (one lane per warp) it adds ``v``.
    """
    ...


@wp.func
def backward_step(b: BackState, pg: PixelGrads, e: int, g: int, active: int, Pk: wp.mat33, og: wp.vec3, col: wp.vec3, op: float,
                  r: wp.vec3, z: float, cam: CameraParams, settings: RasterSettings, with_stats: int, reduce: int, lane: int,
                  grads: SplatGrads) -> BackState:  # fmt: skip
    """Un-blend list entry ``e`` (Gaussian ``g``) if ``active`` and add the pair's gradients into ``grads``
    (see the module docstring); ``z`` is the Gaussian's view depth (used only for the statistics).

    With ``reduce`` (the CUDA shared-memory kernel: every lane of the warp makes the call, active or not, for the same
    entry), when at least ``settings.reduce_min_lanes`` lanes of the warp blend the entry, the gradients are summed over
    the warp first (:func:`warp_add16`): fewer atomics on one address for Gaussians that many pixels of the warp blend.
    """
    hit = int(0)
    dP = wp.mat33(0.0)
    dog = wp.vec3(0.0)
    dcol = wp.vec3(0.0)
    dop = float(0.0)
    dabs = float(0.0)
    if active != 0:  # a warp whose pixels all ended before this entry skips the ray–Gaussian maths
        h = ray_gaussian(Pk, og, r)
        alpha = gaussian_alpha(h, op, settings)
        if alpha >= 0.0:
            hit = 1
            b.T = b.T / (1.0 - alpha)
            w = alpha * b.T
            m = normal_direction(Pk, h.r_g, h.a)  # = −Pᵀ r_g / √A
            m_len = wp.max(wp.length(m), 1.0e-30)
            n_hat = m / m_len
            f = wp.dot(pg.gc, col) + pg.gD * h.t + wp.dot(pg.gN, n_hat)
            dL_dalpha = b.T * f - (b.S + pg.bg_term) / (1.0 - alpha)
            b.S = b.S + w * f
            A_km1 = pg.A_N - b.suffix_w - w
            # distortion, weights detached: paper ∂D/∂f_k = 2 w_k (A_{k−1} − (A_N − A_k)); GOF (squared)
            # ∂D/∂f_k = 2 w_k (f_k A_N − Σ_j w_j f_j); then the chain through f(t)
            dD_df = 2.0 * w * (A_km1 - b.suffix_w)
            if settings.distortion_ndc != 0:
                dD_df = 2.0 * w * (distortion_depth(h.t, settings) * pg.A_N - pg.Bf_N)
            dL_dt = w * pg.gD + dD_df * distortion_depth_grad(h.t, settings) * pg.gDist
            if e == pg.median_pos:
                dL_dt += pg.gMed
            b.suffix_w = b.suffix_w + w

            E = wp.exp(-0.5 * h.d2)
            dL_dd2 = float(0.0)
            if op * E <= settings.alpha_max:  # true derivative of the clamp: 0 where it is active
                dop = E * dL_dalpha
                dL_dd2 = -0.5 * op * E * dL_dalpha

            # normal: ∂L/∂m for the unnormalised m = −Pᵀ r_g (= √A · normal_direction)
            gn = w * pg.gN
            dL_dm = (gn - n_hat * wp.dot(n_hat, gn)) / (m_len * wp.sqrt(h.a))
            dog = 2.0 * dL_dd2 * h.x_c - (dL_dt / h.a) * h.r_g
            dL_drg = (2.0 * dL_dd2 * h.t) * h.x_c - (dL_dt / h.a) * (h.x_c + h.t * h.r_g) - Pk * dL_dm
            dP = wp.outer(dL_drg, r) - wp.outer(h.r_g, dL_dm)
            dcol = w * pg.gc
            if with_stats != 0:
                dabs = wp.length(screen_gradient(Pk, dog, z, cam))

    add = hit
    if reduce != 0:
        lanes = warp_count(hit)  # warp-uniform
        if lanes >= settings.reduce_min_lanes:
            add = 0
            # the row's layout: render_types.GRAD_* (GRAD_OPACITY = GRAD_COLOUR + 3)
            warp_add16(grads.packed, g, vec16(dP[0, 0], dP[0, 1], dP[0, 2], dP[1, 0], dP[1, 1], dP[1, 2], dP[2, 0], dP[2, 1],
                                              dP[2, 2], dog[0], dog[1], dog[2], dcol[0], dcol[1], dcol[2], dop), lane)  # fmt: skip
            if with_stats != 0:
                dabs = warp_sum(dabs)
                if lane_in_warp(lane) == 0:
                    wp.atomic_add(grads.grad2d_abs, g, dabs)
    if add != 0:
        atomic_add4(grads.packed, g, GRAD_P, wp.vec4(dP[0, 0], dP[0, 1], dP[0, 2], dP[1, 0]))
        atomic_add4(grads.packed, g, GRAD_P + 4, wp.vec4(dP[1, 1], dP[1, 2], dP[2, 0], dP[2, 1]))
        atomic_add4(grads.packed, g, GRAD_P + 8, wp.vec4(dP[2, 2], dog[0], dog[1], dog[2]))
        atomic_add4(grads.packed, g, GRAD_COLOUR, wp.vec4(dcol[0], dcol[1], dcol[2], dop))
        if with_stats != 0:
            wp.atomic_add(grads.grad2d_abs, g, dabs)
    return b


@wp.kernel
def rasterize_backward(lists: TileLists, splats: Splats, cam: CameraParams, settings: RasterSettings, aux: PixelAux,
                       gout: PixelMaps, with_stats: int, grads: SplatGrads):  # fmt: skip
    """Same launch as ``rasterize_forward``; ``gout`` holds the ``[H*W]`` output gradients; ``grads`` ``[N]`` (+=)."""
    tp = tile_pixel(wp.tid(), settings)
    px = tp[1]
    py = tp[2]
    if px >= cam.width or py >= cam.height:
        return
    pix = py * cam.width + px
    start = lists.range_start[tp[0]]
    r = pixel_ray(px, py, cam.fx, cam.fy, cam.cx, cam.cy)
    pg = pixel_grads(pix, settings, aux, gout)
    b = BackState()
    b.T = aux.final_T[pix]
    for e in range(aux.last_end[pix] - 1, start - 1, -1):
        g = lists.values[e]
        z = float(0.0)
        if with_stats != 0:
            z = splats.mu_v[g][2]
        active = wp.where(ray_outside(splats.conic[g], splats.centre[g], r), 0, 1)
        b = backward_step(b, pg, e, g, active, splats.P[g], splats.o_g[g], splats.colour[g], splats.opacity[g], r, z,
                          cam, settings, with_stats, 0, 0, grads)  # fmt: skip


@wp.kernel
def finish_splat_grads(
    packed: wp.array2d(dtype=float),
    P: wp.array(dtype=wp.mat33),
    mu_v: wp.array(dtype=wp.vec3),
    cam: CameraParams,
    with_stats: int,
    grad_opacity: wp.array(dtype=float),
    grad2d: wp.array(dtype=wp.vec2),
):
    """``grad_opacity[k] += packed[k, GRAD_OPACITY]``; with statistics ``grad2d[k] += Σ_p g_p``, which is linear in
    ``∂L/∂o_g`` and so taken from its per-Gaussian total."""
    k = wp.tid()
    grad_opacity[k] = grad_opacity[k] + packed[k, GRAD_OPACITY]
    if with_stats != 0:
        dog = wp.vec3(packed[k, GRAD_O_G], packed[k, GRAD_O_G + 1], packed[k, GRAD_O_G + 2])
        grad2d[k] = grad2d[k] + screen_gradient(P[k], dog, mu_v[k][2], cam)
