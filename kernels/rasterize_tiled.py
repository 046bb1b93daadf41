"""CUDA variants of the per-pixel kernels that stage each tile's Gaussians in shared memory.

One thread block per screen tile (``block_dim = TILE_PIXELS = 16 × 16``, launched with
``wp.launch_tiled``). The block walks its tile's sorted list in batches of ``TILE_PIXELS`` entries: the
Gaussian ids are loaded with ``wp.tile_load`` and the per-Gaussian data gathered with
``wp.tile_load_indexed`` into shared-memory tiles, cooperatively (one element per thread), and every
thread then reads the batch from shared memory. The per-entry math is the same ``@wp.func``s as the plain
kernels (:func:`composite`, :func:`backward_step`), so both produce identical results. A block stops
when all its pixels are done (a ``tile_sum`` of per-thread flags; it doubles as the barrier that keeps
the next batch's loads from overwriting data still being read). In the backward each thread also works out, for one
entry of the batch, which of the block's eight warps (two pixel rows each) its silhouette can reach
(:func:`warp_rows_mask`), and a warp that none of its rows can reach skips the entry as a whole.

Only for ``tile_size == 16`` on CUDA; the plain kernels serve every other case (and the CPU).
"""

from __future__ import annotations

import warp as wp

from .gaussian_math import pixel_ray
from .rasterize import composite, pixel_state_init, ray_outside, write_pixel
from .rasterize_backward import BackState, backward_step, pixel_grads
from .render_types import CameraParams, PixelAux, PixelMaps, RasterSettings, SplatGrads, Splats, TileLists

# fast_math (approximate division, square root and exp2, denormals flushed): the per-pair maths is issue-bound and
# its ~15 IEEE divisions per pair in the backward are a large share of its instructions. On an H100 it takes the DTU
# step's GPU time from 15.3 to 12.6 ms; against the float64 reference the CUDA kernels stay within the same tolerances
# as without it (forward ≤ 1.0e-5, gradients ≤ 2.7e-6 relative; ``benchmarks/render/bench_render.py --check``).
wp.set_module_options({"enable_backward": False, "fast_math": True})

TILE_SIZE = 16
TILE_PIXELS = wp.constant(TILE_SIZE * TILE_SIZE)
#: Registers per thread of both kernels: 80 × 256 threads lets three blocks share an SM's 64K registers (two at the
#: ~120 the compiler chooses unbounded). On an H100 this takes the DTU step's forward from 3.30 to 2.88 ms and its
#: backward from 6.8 to 6.3 ms.
MAX_REGISTERS = 80


#: Threads per CUDA warp; warp ``w`` of a tile's block holds its pixel rows ``2w`` and ``2w + 1`` (16 × 2 pixels).
WARP_LANES = 32
#: Slack on the row test of :func:`warp_rows_mask` (the silhouette's value 1): a row is skipped only if its smallest
#: value exceeds ``1 + WARP_ROWS_SLACK``, far above float rounding and far inside the silhouette's own 1 % margin.
WARP_ROWS_SLACK = wp.constant(1.0e-3)


@wp.func
def _block_pixel(tile: int, lane: int, settings: RasterSettings) -> wp.vec2i:
    ty = tile / settings.tiles_x
    tx = tile - ty * settings.tiles_x
    return wp.vec2i(tx * TILE_SIZE + lane % TILE_SIZE, ty * TILE_SIZE + lane / TILE_SIZE)


@wp.func
def warp_rows_mask(conic: wp.vec3, centre: wp.vec2, tile: int, cam: CameraParams, settings: RasterSettings) -> int:
    """Which warps of ``tile``'s 16 × 16 block may meet a Gaussian (the backward's warp-wide skip): bit ``w`` (0–7) is
    set unless the silhouette conic of :func:`~.rasterize.ray_outside` (``conic``, ``centre``: ``project.ray_conics``)
    leaves every pixel of rows ``2w`` and ``2w + 1`` outside. Per row the conic's smallest value over the segment
    through the row's 16 pixel centres (normalised image coordinates ``u = (x + ½ − cx)/fx``, ``v = (y + ½ − cy)/fy``)
    is, in float64, ``q(u*)`` with ``u* = clamp(−β Δv, u₀, u₁)`` (``conic = (A, β, γ)``:
    ``q = A (Δu + β Δv)² + γ Δv²``); the row is skipped if it exceeds ``1 + WARP_ROWS_SLACK``. No pixel of a skipped
    row passes :func:`ray_outside`, so skipping the entry for the whole warp changes nothing. A zero conic (no
    silhouette: nothing rejected) sets every bit."""
    a = wp.float64(conic[0])
    beta = wp.float64(conic[1])
    gamma = wp.float64(conic[2])
    if not (a > wp.float64(0.0)):
        return 0xFF
    origin = _block_pixel(tile, 0, settings)  # the tile's first pixel
    fx = wp.float64(cam.fx)
    fy = wp.float64(cam.fy)
    cu = wp.float64(centre[0])
    cv = wp.float64(centre[1])
    u0 = (wp.float64(origin[0]) + wp.float64(0.5) - wp.float64(cam.cx)) / fx - cu
    u1 = (wp.float64(origin[0] + TILE_SIZE - 1) + wp.float64(0.5) - wp.float64(cam.cx)) / fx - cu
    limit = wp.float64(1.0) + wp.float64(WARP_ROWS_SLACK)
    mask = int(0)
    for row in range(TILE_SIZE):
        dv = (wp.float64(origin[1] + row) + wp.float64(0.5) - wp.float64(cam.cy)) / fy - cv
        t = wp.clamp(-beta * dv, u0, u1) + beta * dv
        if a * t * t + gamma * dv * dv <= limit:
            mask = mask | (1 << (row / 2))
    return mask


@wp.kernel(cuda_max_registers=MAX_REGISTERS)
def rasterize_forward_tiled(lists: TileLists, splats: Splats, cam: CameraParams, settings: RasterSettings, out: PixelMaps, aux: PixelAux):
    """``wp.launch_tiled(dim=num_tiles, block_dim=TILE_PIXELS)``; same outputs as ``rasterize_forward``."""
    tile, lane = wp.tid()
    p = _block_pixel(tile, lane, settings)
    inside = p[0] < cam.width and p[1] < cam.height
    r = pixel_ray(p[0], p[1], cam.fx, cam.fy, cam.cx, cam.cy)
    start = lists.range_start[tile]
    end = lists.range_end[tile]
    s = pixel_state_init(start, wp.where(inside, 0, 1))
    # struct members as locals: tile_load_indexed does not accept struct fields directly (Warp 1.19)
    values = lists.values
    sP = splats.P
    sO = splats.o_g
    sC = splats.colour
    sA = splats.opacity
    sK = splats.conic
    sM = splats.centre
    for batch in range(start, end, TILE_PIXELS):
        alive = wp.tile_sum(wp.tile(1 - s.done))
        if wp.tile_extract(alive, 0) == 0:
            break
        ids = wp.tile_load(values, shape=(TILE_PIXELS,), offset=(batch,), storage="shared")
        tP = wp.tile_load_indexed(sP, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        tO = wp.tile_load_indexed(sO, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        tC = wp.tile_load_indexed(sC, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        tA = wp.tile_load_indexed(sA, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        tK = wp.tile_load_indexed(sK, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        tM = wp.tile_load_indexed(sM, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        if s.done == 0:
            for i in range(wp.min(TILE_PIXELS, end - batch)):
                if ray_outside(wp.tile_extract(tK, i), wp.tile_extract(tM, i), r):
                    continue
                s = composite(s, batch + i, wp.tile_extract(tP, i), wp.tile_extract(tO, i), wp.tile_extract(tC, i),
                              wp.tile_extract(tA, i), r, settings)  # fmt: skip
                if s.done != 0:
                    break
    if inside:
        write_pixel(s, p[1] * cam.width + p[0], settings, out, aux)


@wp.kernel(cuda_max_registers=MAX_REGISTERS)
def rasterize_backward_tiled(lists: TileLists, splats: Splats, cam: CameraParams, settings: RasterSettings, aux: PixelAux,
                             gout: PixelMaps, with_stats: int, grads: SplatGrads):  # fmt: skip
    """``wp.launch_tiled(dim=num_tiles, block_dim=TILE_PIXELS)``; same result as ``rasterize_backward``."""
    tile, lane = wp.tid()
    p = _block_pixel(tile, lane, settings)
    inside = p[0] < cam.width and p[1] < cam.height
    pix = wp.where(inside, p[1] * cam.width + p[0], 0)
    start = lists.range_start[tile]
    my_last = wp.where(inside, aux.last_end[pix], start)
    r = pixel_ray(p[0], p[1], cam.fx, cam.fy, cam.cx, cam.cy)
    pg = pixel_grads(pix, settings, aux, gout)
    b = BackState()
    b.T = aux.final_T[pix]
    block_last = wp.tile_extract(wp.tile_max(wp.tile(my_last)), 0)
    mu_v = splats.mu_v
    # struct members as locals: tile_load_indexed does not accept struct fields directly (Warp 1.19)
    values = lists.values
    sP = splats.P
    sO = splats.o_g
    sC = splats.colour
    sA = splats.opacity
    sK = splats.conic
    sM = splats.centre
    warp_bit = 1 << (lane / WARP_LANES)
    tW = wp.tile_zeros(shape=(TILE_PIXELS,), dtype=int, storage="shared")
    for batch_end in range(block_last, start, -TILE_PIXELS):
        batch = wp.max(start, batch_end - TILE_PIXELS)
        ids = wp.tile_load(values, shape=(TILE_PIXELS,), offset=(batch,), storage="shared")
        tP = wp.tile_load_indexed(sP, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        tO = wp.tile_load_indexed(sO, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        tC = wp.tile_load_indexed(sC, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        tA = wp.tile_load_indexed(sA, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        tK = wp.tile_load_indexed(sK, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        tM = wp.tile_load_indexed(sM, indices=ids, shape=(TILE_PIXELS,), axis=0, storage="shared")
        # thread `lane` works out entry batch + lane's warp mask once for the block (warp_rows_mask); the forward does
        # not: it measured slower there, where a skipped pair costs one test
        wp.tile_assign(tW, wp.tile(wp.where(batch + lane < batch_end, warp_rows_mask(wp.tile_extract(tK, lane),
                                                                                     wp.tile_extract(tM, lane), tile,
                                                                                     cam, settings), 0)))  # fmt: skip
        for i in range(batch_end - batch - 1, -1, -1):
            e = batch + i
            if (wp.tile_extract(tW, i) & warp_bit) == 0:  # no pixel of this warp meets it: the whole warp moves on
                continue
            g = wp.tile_extract(ids, i)
            active = 0
            if e < my_last:
                if not ray_outside(wp.tile_extract(tK, i), wp.tile_extract(tM, i), r):
                    active = 1
            # a lane the early reject (or its pixel's end) leaves out reads nothing more of the entry
            z = float(0.0)
            Pk = wp.mat33(0.0)
            og = wp.vec3(0.0)
            col = wp.vec3(0.0)
            op = float(0.0)
            if active != 0:
                Pk = wp.tile_extract(tP, i)
                og = wp.tile_extract(tO, i)
                col = wp.tile_extract(tC, i)
                op = wp.tile_extract(tA, i)
                if with_stats != 0:
                    z = mu_v[g][2]
            # every lane of the block is here (block-uniform loop), so backward_step may reduce over the warp
            b = backward_step(b, pg, e, g, active, Pk, og, col, op, r, z, cam, settings, with_stats, 1, lane, grads)
        # keep the next batch's loads from overwriting shared data other threads still read
        wp.tile_sum(wp.tile(0))
