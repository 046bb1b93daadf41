"""Tile binning: one (tile, depth) key per Gaussian per touched tile, radix-sorted, then per-tile ranges.

A Gaussian is binned into the tiles of its bounding rectangle (``screen_bounds``) that its projected
ellipse meets (exact and conservative: :mod:`.tile_overlap`), row by row from the first to the last such
tile; an ellipsoid crossing the near plane (whole-image rectangle, ``exact = 2``) into the tiles that its
general conic meets, found per 8 × 8 block of tiles as a bit mask (:func:`conic_block_mask`). Variable-size output in two passes (``docs/rendering.md``): :func:`count_tile_keys` counts the tiles
of each Gaussian, an inclusive ``array_scan`` gives offsets, :func:`write_tile_keys` runs the same per-row
test and writes the keys ``tile_id << 32 | float_bits(μ_v.z)`` (view depth > near > 0, so its IEEE bits
sort like the float) and the Gaussian index as value. Both passes call :func:`row_tile_span`, compiled in
this module without floating-point contraction (``fuse_fp``: no FMA), so the float64 test takes the same
decisions bit for bit in both kernels and the counts size the lists exactly (likewise
:func:`conic_block_mask`). ``radix_sort_pairs`` is stable and the keys are written in index order, so
equal depths stay in ascending index order (the spec's tie rule). :func:`tile_ranges` finds where each
tile's run starts and ends by comparing neighbouring keys.
"""

from __future__ import annotations

import math

import warp as wp

from .render_types import CameraParams, RasterSettings
from .tile_overlap import CONIC_BLOCK, TileEllipse, TileEllipses, conic_block_mask, conic_test, empty_tile_ellipses, load_ellipse, row_tile_span

# no FMA contraction: the count and write kernels must evaluate the float64 tile test identically
wp.set_module_options({"fuse_fp": False, "enable_backward": False})


@wp.func
def conic_tile_count(r: wp.vec4i, e: TileEllipse, cam: CameraParams, settings: RasterSettings) -> int:
    """``exact = 2``: the number of tiles of ``r`` that the general conic meets (set bits of
    :func:`conic_block_mask` over its 8 × 8 blocks)."""
    t = conic_test(e, cam)
    n = int(0)
    for by in range(r[1], r[3], CONIC_BLOCK):
        for bx in range(r[0], r[2], CONIC_BLOCK):
            m = conic_block_mask(t, bx, by, r[2], r[3], cam, settings)
            while m != wp.uint64(0):
                m = m & (m - wp.uint64(1))
                n += 1
    return n


@wp.kernel
def count_tile_keys(
    rect: wp.array(dtype=wp.vec4i),
    ellipse: TileEllipses,
    cam: CameraParams,
    settings: RasterSettings,
    tiles_touched: wp.array(dtype=wp.int32),
):
    """Inputs ``rect, ellipse [N]`` from ``screen_bounds``; output ``tiles_touched [N]``: the number of tiles
    of ``rect`` that the Gaussian is binned into (per row, the span of :func:`row_tile_span`; for
    ``exact = 2`` the set bits of :func:`conic_block_mask` over the 8 × 8 blocks of ``rect``)."""
    k = wp.tid()
    r = rect[k]
    e = load_ellipse(ellipse, k)
    n = int(0)
    if e.exact == 2:
        n = conic_tile_count(r, e, cam, settings)
    else:
        for ty in range(r[1], r[3]):
            span = row_tile_span(e, ty, r[0], r[2], cam, settings)
            n += span[1] - span[0]
    tiles_touched[k] = n


@wp.kernel
def write_tile_keys(
    rect: wp.array(dtype=wp.vec4i),
    ellipse: TileEllipses,
    offsets: wp.array(dtype=wp.int32),
    tiles_touched: wp.array(dtype=wp.int32),
    depth_bits: wp.array(dtype=wp.int32),
    cam: CameraParams,
    settings: RasterSettings,
    limit: int,
    keys: wp.array(dtype=wp.int64),
    values: wp.array(dtype=wp.int32),
):
    """``offsets`` = inclusive scan of ``tiles_touched`` (``[N]`` each, from :func:`count_tile_keys`); writes
    the keys of the same tiles to ``keys/values[offsets[k] − tiles_touched[k] : offsets[k]]`` (never more), and
    none at or past ``limit`` (the entries allocated)."""
    k = wp.tid()
    r = rect[k]
    e = load_ellipse(ellipse, k)
    end = wp.min(offsets[k], limit)
    idx = end - tiles_touched[k]
    d = wp.int64(depth_bits[k])
    if e.exact == 2:
        t = conic_test(e, cam)
        for by in range(r[1], r[3], CONIC_BLOCK):
            for bx in range(r[0], r[2], CONIC_BLOCK):
                m = conic_block_mask(t, bx, by, r[2], r[3], cam, settings)
                if m != wp.uint64(0):
                    for bit in range(CONIC_BLOCK * CONIC_BLOCK):
                        if ((m >> wp.uint64(bit)) & wp.uint64(1)) != wp.uint64(0) and idx < end:
                            tx = bx + bit % CONIC_BLOCK
                            ty = by + bit / CONIC_BLOCK
                            keys[idx] = (wp.int64(ty * settings.tiles_x + tx) << wp.int64(32)) | d
                            values[idx] = k
                            idx += 1
    else:
        for ty in range(r[1], r[3]):
            span = row_tile_span(e, ty, r[0], r[2], cam, settings)
            for tx in range(span[0], span[1]):
                if idx < end:
                    keys[idx] = (wp.int64(ty * settings.tiles_x + tx) << wp.int64(32)) | d
                    values[idx] = k
                    idx += 1


@wp.kernel
def tile_ranges(keys: wp.array(dtype=wp.int64), count: int, range_start: wp.array(dtype=wp.int32), range_end: wp.array(dtype=wp.int32)):
    """For sorted ``keys[:count]``: ``[range_start[t], range_end[t])`` = entries of tile ``t`` (zeroed before);
    keys of tile ``num_tiles`` (padding) are skipped."""
    i = wp.tid()
    num_tiles = range_start.shape[0]
    tile = int(keys[i] >> wp.int64(32))  # padding entries (tile = num_tiles) sort last and own no range
    if i == 0:
        if tile < num_tiles:
            range_start[tile] = 0
    else:
        prev = int(keys[i - 1] >> wp.int64(32))
        if prev != tile:
            if prev < num_tiles:
                range_end[prev] = i
            if tile < num_tiles:
                range_start[tile] = i
    if i == count - 1 and tile < num_tiles:
        range_end[tile] = count


def float_bits_view(a: wp.array) -> wp.array:
    """An ``int32`` view of a ``float32`` array's memory (bit reinterpretation, no copy)."""
    return wp.array(ptr=a.ptr, dtype=wp.int32, shape=a.shape, device=a.device, copy=False)


class TileListSizer:
    """Sizes the tile lists of successive renders without a host–device synchronisation per render.

    Without a sizer, :func:`bin_gaussians` reads the number of (Gaussian, tile) entries back to the host to
    allocate the lists: the host waits until the GPU has finished all work queued before it, so it cannot queue the
    next kernels while the GPU runs the previous ones. With a sizer it allocates ``size`` entries planned on the
    host instead, pads the unused ones with keys that sort after every tile and own no range, and copies the true
    count into pinned host memory without waiting; later calls read those counts once they have arrived.

    - ``size`` is ``margin ×`` the largest count seen since the Gaussians last changed in number.
    - Each view (camera pose, intrinsics and image size: :func:`view_key`) also keeps the count of its latest render
      and the number of Gaussians then. A call for a view seen before gets at least ``margin ×`` that count, scaled
      up by how much the number of Gaussians grew since (never down: pruning removes mostly transparent Gaussians,
      which own few entries). Views see very different numbers of entries (a close-up against a wide shot of an
      unbounded capture): with one size for all, the first views after each densification overflowed whenever they
      needed more than ``margin ×`` the one view measured so far (11–595 renders of a 30k run on the real
      captures).
    - A call with no estimate (nothing seen yet for this number of Gaussians, and its view never rendered) measures
      exactly: one synchronisation.
    - A count over the size it was given is an **overflow**: that render dropped the entries past the size (the
      highest-index Gaussians' in some tiles). It is counted in ``overflows`` (found a call or two later) and the
      size grows. Renders without an overflow are bit-identical to exact sizing (stable sort, padding last).

    Warp only (no torch); on the CPU the count is read at once (nothing to overlap there).
    """

    PENDING = 8  # counts in flight before the oldest is waited for

    def __init__(self, margin: float = 1.25):
        if not margin >= 1.0:
            raise ValueError(f"TileListSizer: margin must be >= 1, got {margin}")
        self.margin = float(margin)
        self.size = 0  # entries for the next call (0: measure exactly)
        self.num_gaussians = -1
        self.largest = 0  # largest count seen for the current number of Gaussians
        self.calls = 0
        self.measured = 0  # calls that synchronised to measure
        self.overflows = 0
        self.entries_allocated = 0  # over the padded calls whose counts have been read: entries given ...
        self.entries_needed = 0  # ... and entries their true counts needed (the padding's cost: their ratio)
        self._pending: list = []  # (slot, entries allocated, number of Gaussians, view key, event), CUDA only
        self._host = None  # pinned int32[PENDING] landing slots (CUDA)
        self._next_slot = 0
        self._views: dict = {}  # view key -> (count, number of Gaussians) of the view's latest render

    def stats(self) -> dict:
        return {**self.state_dict(), "size": self.size}

    def state_dict(self) -> dict:
        """The counters (a checkpoint's; the size is measured again after a resume)."""
        return {"calls": self.calls, "measured": self.measured, "overflows": self.overflows,
                "entries_allocated": self.entries_allocated, "entries_needed": self.entries_needed}

    def load_state_dict(self, state: dict) -> None:
        self.calls, self.measured, self.overflows = (int(state[k]) for k in ("calls", "measured", "overflows"))
        # absent from checkpoints written before these counters existed
        self.entries_allocated, self.entries_needed = (int(state.get(k, 0)) for k in ("entries_allocated", "entries_needed"))

    def plan(self, n: int, view=None) -> int:
        """Entries to allocate for a call with ``n`` Gaussians (0: measure exactly); ``view``: the call's
        :func:`view_key` (None: no per-view estimate)."""
        self._settle()
        self.calls += 1
        if n != self.num_gaussians:
            self.num_gaussians, self.size, self.largest = n, 0, 0
        return max(self.size, self.view_estimate(n, view))

    def view_estimate(self, n: int, view) -> int:
        """``margin ×`` ``view``'s latest count scaled to ``n`` Gaussians (0: no count of that view, or it was 0)."""
        count, n_then = self._views.get(view, (0, 0)) if view is not None else (0, 0)
        if count == 0:
            return 0
        # scaled up with more Gaussians, never down: pruning removes mostly transparent ones, which own few entries
        return int(math.ceil(self.margin * count * max(1.0, n / max(n_then, 1))))

    def observe(self, count: int, n: int, view=None) -> None:
        """A true count for ``n`` Gaussians (of ``view``): grows ``size`` to ``margin ×`` the largest one and
        keeps it as the view's latest."""
        if n == self.num_gaussians and count > self.largest:
            self.largest = count
            self.size = max(self.size, int(math.ceil(count * self.margin)), 1)
        if view is not None:
            self._views[view] = (count, n)

    def measure(self, count: int, n: int, view=None) -> None:
        """The count of a call that read it back at once (exact sizing)."""
        self.measured += 1
        self.observe(count, n, view)

    def record(self, offsets: wp.array, n: int, allocated: int, view=None) -> None:
        """Queue the read-back of the true count ``offsets[n − 1]`` of a call given ``allocated`` entries (on the CPU
        it is read at once)."""
        if offsets.device.is_cpu:
            self._take(int(offsets[n - 1 : n].numpy()[0]), allocated, n, view)
            return
        if self._host is None:
            self._host = wp.empty(self.PENDING, dtype=wp.int32, device="cpu", pinned=True)
        if len(self._pending) >= self.PENDING:
            self._settle(wait_oldest=True)
        slot = self._next_slot
        self._next_slot = (slot + 1) % self.PENDING
        wp.copy(self._host, offsets, dest_offset=slot, src_offset=n - 1, count=1)
        self._pending.append((slot, allocated, n, view, wp.record_event()))

    def _settle(self, wait_oldest: bool = False) -> None:
        """Take the counts that have arrived, in order (waiting for the oldest one if asked)."""
        while self._pending:
            slot, allocated, n, view, event = self._pending[0]
            if wait_oldest:
                wp.synchronize_event(event)
                wait_oldest = False
            elif not event.is_complete:
                return
            self._pending.pop(0)
            self._take(int(self._host.numpy()[slot]), allocated, n, view)

    def _take(self, count: int, allocated: int, n: int, view) -> None:
        """A call's true count against the entries it was given: an overflow when over, then :meth:`observe`."""
        if count > allocated:
            self.overflows += 1
        self.entries_allocated += allocated
        self.entries_needed += count
        self.observe(count, n, view)


def view_key(cam: CameraParams) -> bytes:
    """A hashable key of one view: the bytes of its :class:`CameraParams` (pose, intrinsics, image size), the same
    for every render of that camera."""
    return bytes(cam.__ctype__())


def bin_gaussians(rect: wp.array, tiles_touched: wp.array, depth: wp.array, tiles_x: int, num_tiles: int,
                  ellipse: TileEllipses | None = None, cam: CameraParams | None = None, settings: RasterSettings | None = None,
                  sizer: TileListSizer | None = None, *, offsets: wp.array | None = None,
                  ranges: tuple | None = None):  # fmt: skip
    """Sorted per-tile lists of Gaussian indices.

    Args:
        rect, tiles_touched, depth: ``[N]`` outputs of ``screen_bounds``. With ``ellipse``,
            ``tiles_touched`` is overwritten by the count pass (the tiles each Gaussian is binned into).
        tiles_x: tiles per image row; num_tiles: tiles in the image.
        ellipse, cam, settings: the ``[N]`` ``ellipse`` output of ``screen_bounds`` and the camera and
            settings it ran with: bin into the tiles the ellipse meets. ``None``: every tile of ``rect``.
        sizer: size the lists from earlier calls' counts instead of reading this call's back (no host–device
            synchronisation; see :class:`TileListSizer`). ``None``: exact, one synchronisation.
        offsets: ``[N]`` int32 array to hold the scan of the counts; ranges: ``(range_start, range_end)``,
            ``[num_tiles]`` int32 arrays holding zeros, returned filled (each allocated when ``None``).

    Returns:
        ``(values, range_start, range_end, count)``: ``values [count]`` int32 Gaussian indices, sorted by
        (tile, depth, index); tile ``t`` owns ``values[range_start[t]:range_end[t]]``. With a sizer ``count`` is
        the entries allocated (the true count or more; the rest are padding no tile owns).
    """
    device = rect.device
    n = rect.shape[0]
    if ranges is None:
        ranges = tuple(wp.zeros(num_tiles, dtype=wp.int32, device=device) for _ in range(2))
    range_start, range_end = ranges
    if n == 0:
        return wp.zeros(0, dtype=wp.int32, device=device), range_start, range_end, 0
    view = view_key(cam) if sizer is not None and cam is not None else None
    if ellipse is None:  # exact = 0 everywhere: the whole rectangle, counted by screen_bounds
        ellipse = empty_tile_ellipses(n, device, whole_rect=True)
        cam = CameraParams()
        settings = RasterSettings()
        settings.tiles_x = int(tiles_x)
    else:
        wp.launch(count_tile_keys, dim=n, inputs=[rect, ellipse, cam, settings], outputs=[tiles_touched], device=device, record_tape=False)
    if offsets is None:
        offsets = wp.empty(n, dtype=wp.int32, device=device)
    wp.utils.array_scan(tiles_touched, offsets, inclusive=True)
    count = sizer.plan(n, view) if sizer is not None else 0
    padded = count > 0
    if not padded:
        count = int(offsets[n - 1 : n].numpy()[0])  # one small device-to-host copy (sizes the lists): a sync
        if sizer is not None:
            sizer.measure(count, n, view)
    if count == 0:
        return wp.zeros(0, dtype=wp.int32, device=device), range_start, range_end, 0
    keys = wp.empty(2 * count, dtype=wp.int64, device=device)  # radix sort needs 2x scratch
    values = wp.empty(2 * count, dtype=wp.int32, device=device)
    if padded:
        keys[:count].fill_(num_tiles << 32)  # after every tile's keys; owned by no tile
        sizer.record(offsets, n, count, view)
    wp.launch(write_tile_keys, dim=n, inputs=[rect, ellipse, offsets, tiles_touched, float_bits_view(depth), cam, settings,
              count], outputs=[keys, values], device=device, record_tape=False)  # fmt: skip
    wp.utils.radix_sort_pairs(keys, values, count, begin_bit=0, end_bit=32 + max(1, int(num_tiles).bit_length()))
    wp.launch(tile_ranges, dim=count, inputs=[keys, count], outputs=[range_start, range_end], device=device, record_tape=False)
    return values[:count], range_start, range_end, count
