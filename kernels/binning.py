"""Tile binning: one (tile, depth) key per Gaussian per touched tile, radix-sorted, then per-tile ranges.

Variable-size output in two passes (``docs/rendering.md``): ``screen_bounds`` counts the tiles of each
Gaussian, an inclusive ``array_scan`` gives offsets, :func:`write_tile_keys` writes the keys
``tile_id << 32 | float_bits(μ_v.z)`` (view depth > near > 0, so its IEEE bits sort like the float) and
the Gaussian index as value. ``radix_sort_pairs`` is stable and the keys are written in index order, so
equal depths stay in ascending index order (the spec's tie rule). :func:`tile_ranges` finds where each
tile's run starts and ends by comparing neighbouring keys.
"""

from __future__ import annotations

import warp as wp


@wp.kernel
def write_tile_keys(
    rect: wp.array(dtype=wp.vec4i),
    offsets: wp.array(dtype=wp.int32),
    depth_bits: wp.array(dtype=wp.int32),
    tiles_x: int,
    keys: wp.array(dtype=wp.int64),
    values: wp.array(dtype=wp.int32),
):
    """``offsets`` = inclusive scan of the tile counts; writes ``keys/values[offsets[k]-count_k : offsets[k]]``."""
    k = wp.tid()
    r = rect[k]
    n = (r[2] - r[0]) * (r[3] - r[1])
    idx = offsets[k] - n
    d = wp.int64(depth_bits[k])
    for ty in range(r[1], r[3]):
        for tx in range(r[0], r[2]):
            keys[idx] = (wp.int64(ty * tiles_x + tx) << wp.int64(32)) | d
            values[idx] = k
            idx += 1


@wp.kernel
def tile_ranges(keys: wp.array(dtype=wp.int64), count: int, range_start: wp.array(dtype=wp.int32), range_end: wp.array(dtype=wp.int32)):
    """For sorted ``keys[:count]``: ``[range_start[t], range_end[t])`` = entries of tile ``t`` (zeroed before)."""
    i = wp.tid()
    tile = int(keys[i] >> wp.int64(32))
    if i == 0:
        range_start[tile] = 0
    else:
        prev = int(keys[i - 1] >> wp.int64(32))
        if prev != tile:
            range_end[prev] = i
            range_start[tile] = i
    if i == count - 1:
        range_end[tile] = count


def float_bits_view(a: wp.array) -> wp.array:
    """An ``int32`` view of a ``float32`` array's memory (bit reinterpretation, no copy)."""
    return wp.array(ptr=a.ptr, dtype=wp.int32, shape=a.shape, device=a.device, copy=False)


def bin_gaussians(rect: wp.array, tiles_touched: wp.array, depth: wp.array, tiles_x: int, num_tiles: int):
    """Sorted per-tile lists of Gaussian indices.

    Args:
        rect, tiles_touched, depth: ``[N]`` outputs of ``screen_bounds``.
        tiles_x: tiles per image row; num_tiles: tiles in the image.

    Returns:
        ``(values, range_start, range_end, count)``: ``values [count]`` int32 Gaussian indices, sorted by
        (tile, depth, index); tile ``t`` owns ``values[range_start[t]:range_end[t]]``.
    """
    device = rect.device
    n = rect.shape[0]
    range_start = wp.zeros(num_tiles, dtype=wp.int32, device=device)
    range_end = wp.zeros(num_tiles, dtype=wp.int32, device=device)
    if n == 0:
        return wp.zeros(0, dtype=wp.int32, device=device), range_start, range_end, 0
    offsets = wp.empty(n, dtype=wp.int32, device=device)
    wp.utils.array_scan(tiles_touched, offsets, inclusive=True)
    count = int(offsets[n - 1 : n].numpy()[0])  # one small device-to-host copy (sizes the lists)
    if count == 0:
        return wp.zeros(0, dtype=wp.int32, device=device), range_start, range_end, 0
    keys = wp.empty(2 * count, dtype=wp.int64, device=device)  # radix sort needs 2x scratch
    values = wp.empty(2 * count, dtype=wp.int32, device=device)
    wp.launch(write_tile_keys, dim=n, inputs=[rect, offsets, float_bits_view(depth), tiles_x], outputs=[keys, values], device=device)
    wp.utils.radix_sort_pairs(keys, values, count, begin_bit=0, end_bit=32 + max(1, int(num_tiles - 1).bit_length()))
    wp.launch(tile_ranges, dim=count, inputs=[keys, count], outputs=[range_start, range_end], device=device)
    return values[:count], range_start, range_end, count
