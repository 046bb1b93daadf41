"""Host entry points of the differentiable ray–Gaussian renderer, on ``wp.array``s only (no torch).

Pipeline (``docs/rendering.md``): ``preprocess_gaussians`` → ``screen_bounds`` → ``bin_gaussians``
(scan, keys, radix sort, tile ranges) → ``rasterize_forward``. The backward is
``rasterize_backward`` (hand-written, per pixel) → ``finish_splat_grads`` → the automatic adjoint of
``preprocess_gaussians``.

Pure-Warp use with a tape (see ``examples/warp_tape_render.py``)::

    tape = wp.Tape()
    out = render_gaussians(means, quats, scales, opacities, sh, 0, cam, settings, tape=tape)
    with tape:
        wp.launch(my_loss, dim=..., inputs=[out.rgb], outputs=[loss])
    tape.backward(loss)          # fills means.grad, quats.grad, scales.grad, opacities.grad, sh.grad

The inputs must be created with ``requires_grad=True`` for their gradients to be written (gradients are
accumulated, as everywhere in Warp). Per-pixel outputs are flat ``[H*W]`` arrays, row-major.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, fields

import warp as wp

from .binning import TileListSizer, bin_gaussians
from .project import SH_LANES, preprocess_gaussians, project_frames, ray_conics, screen_bounds, sh_colour_backward
from .rasterize import rasterize_forward
from .rasterize_backward import finish_splat_grads, rasterize_backward
from .rasterize_tiled import TILE_PIXELS, TILE_SIZE, rasterize_backward_tiled, rasterize_forward_tiled
from .render_types import (GRAD_COLOUR, GRAD_O_G, GRAD_P, GRAD_WIDTH, CameraParams, PixelAux, PixelMaps, RasterSettings,
                           SplatGrads, Splats, TileLists, make_struct)
from .tile_overlap import empty_tile_ellipses

#: Bytes of per-Gaussian renderer state (mu_v 12, P 36, o_g 12, colour 12, ray conic/centre 12 + 8, rect 16,
#: counts/radii/depth/offsets 16, tile-test exact/conic/centre 4 + 48 + 16) and per (Gaussian, tile) entry (int64 key
#: + int32 value, ×2 for the radix sort's scratch).
BYTES_PER_GAUSSIAN = 192
BYTES_PER_TILE_ENTRY = 24


@dataclass
class RenderOutputs:
    """Per-pixel outputs, flat ``[H*W]`` (row-major), float32."""

    rgb: wp.array  # vec3: Σ w c + T_N · background
    alpha: wp.array  # 1 − T_N
    accum_depth: wp.array  # Σ w t*
    median_depth: wp.array  # t* where T crosses 0.5 (last blended if never, 0 if none)
    normal: wp.array  # vec3: Σ w n̂ (camera space)
    distortion: wp.array  # Σ_k 2 w_k (t_k A_{k−1} − B_{k−1}), weights detached

    @classmethod
    def allocate(cls, num_pixels: int, device, requires_grad: bool = False) -> "RenderOutputs":
        def arr(dtype):
            return wp.empty(num_pixels, dtype=dtype, device=device, requires_grad=requires_grad)

        return cls(arr(wp.vec3), arr(float), arr(float), arr(float), arr(wp.vec3), arr(float))

    def arrays(self) -> list:
        return [getattr(self, f.name) for f in fields(self)]

    def as_struct(self) -> PixelMaps:
        return make_struct(PixelMaps, **{f.name: getattr(self, f.name) for f in fields(self)})


@dataclass
class RenderState:
    """Everything the backward needs from the forward (kept alive between the two)."""

    inputs: tuple  # (means, quats, scales, opacities, (sh_dc, sh_rest))
    sh_degree: int
    cam: CameraParams
    settings: RasterSettings
    mu_v: wp.array
    P: wp.array
    o_g: wp.array
    colour: wp.array
    radii: wp.array  # [N] int32, 0 = not visible
    lists: TileLists  # sorted Gaussian indices per tile
    splats: Splats
    aux: PixelAux
    num_entries: int  # Σ tiles touched
    tiled: bool  # shared-memory (CUDA) kernels
    # the ScratchPool's SplatScratch and PixelScratch the arrays above live in (empty without a pool): given back to the
    # pool once the backward ran (ScratchPool.give(*state.scratch)); the state must not be used after that
    scratch: tuple = ()

    @property
    def device(self):
        return self.mu_v.device


class SplatScratch:
    """The per-Gaussian arrays one render works in (``[n]`` each), besides its inputs: ``mu_v, P, o_g, colour, radii``,
    which the backward reads, with the :class:`Splats` struct over them (``opacity`` set per render), and the
    binning's temporaries ``rect, touched, depth, ellipse, offsets``. ``BYTES_PER_GAUSSIAN`` (192) bytes a Gaussian:
    96 kept for the backward (``conic, centre`` of the early reject among them), 96 of temporaries."""

    sizes_kept = 1  # a ScratchPool keeps spares of the latest n only (the count changes for good under densification)

    def __init__(self, n: int, device):
        def empty(dtype):
            return wp.empty(n, dtype=dtype, device=device)

        self.mu_v, self.P, self.o_g, self.colour = empty(wp.vec3), empty(wp.mat33), empty(wp.vec3), empty(wp.vec3)
        self.conic, self.centre = empty(wp.vec3), empty(wp.vec2)
        self.rect, self.touched, self.radii = empty(wp.vec4i), empty(wp.int32), empty(wp.int32)
        self.depth = empty(float)
        self.ellipse = empty_tile_ellipses(n, device)
        self.offsets = empty(wp.int32)
        self.splats = make_struct(Splats, P=self.P, o_g=self.o_g, colour=self.colour, mu_v=self.mu_v, radius=self.radii,
                                  conic=self.conic, centre=self.centre)

    def arrays(self) -> list:
        """The arrays that own memory (for :meth:`ScratchPool.nbytes`)."""
        return [self.mu_v, self.P, self.o_g, self.colour, self.conic, self.centre, self.rect, self.touched, self.radii,
                self.depth, self.ellipse.exact, self.ellipse.conic, self.ellipse.centre, self.offsets]  # fmt: skip

    def forget(self) -> None:
        """Drop the reference to a render's opacities: a spare holds only its own arrays."""
        self.splats.opacity = None


class PixelScratch:
    """The per-pixel and per-tile arrays one render works in: the :class:`PixelAux` struct ``aux`` over five
    ``[num_pixels]`` arrays (0 where only :func:`prepare_view` runs) and the tile ranges ``range_start, range_end``
    (``[num_tiles]`` int32, zeroed before each use) with the :class:`TileLists` struct over them (``values`` set per
    render); ``aux`` and ``lists`` are read by the backward. 20 bytes a pixel and 8 a tile."""

    sizes_kept = 4  # a ScratchPool keeps spares of the 4 latest image sizes (views of a few sizes come back)

    def __init__(self, num_pixels: int, num_tiles: int, device):
        def empty(dtype, size):
            return wp.empty(size, dtype=dtype, device=device)

        self.range_start, self.range_end = empty(wp.int32, num_tiles), empty(wp.int32, num_tiles)
        self.lists = make_struct(TileLists, range_start=self.range_start, range_end=self.range_end)
        self.aux = make_struct(PixelAux, final_T=empty(float, num_pixels), last_end=empty(wp.int32, num_pixels),
                               median_pos=empty(wp.int32, num_pixels), weight_sum=empty(float, num_pixels),
                               dist_sum=empty(float, num_pixels))  # fmt: skip

    def arrays(self) -> list:
        """The arrays that own memory (for :meth:`ScratchPool.nbytes`)."""
        aux = self.aux
        return [self.range_start, self.range_end, aux.final_T, aux.last_end, aux.median_pos, aux.weight_sum,
                aux.dist_sum]  # fmt: skip

    def forget(self) -> None:
        """Drop the reference to a render's tile lists: a spare holds only its own arrays."""
        self.lists.values = None


class GradScratch:
    """The backward's temporaries for ``n`` Gaussians: the per-Gaussian gradient rows ``packed [n, GRAD_WIDTH]``
    (16-byte aligned; zeroed before each use) with their column views ``g_P, g_o_g, g_colour`` and the
    :class:`SplatGrads` struct over them (``grad2d_abs`` set per backward), and ``zero_mu_v [n]``, the zero gradient
    of the camera-space means fed to the adjoint of ``project_frames`` (zeroed before each use). 76 bytes a
    Gaussian."""

    sizes_kept = 1

    def __init__(self, n: int, device):
        self.packed = wp.empty((n, GRAD_WIDTH), dtype=float, device=device)
        if n and self.packed.ptr % 16:
            raise RuntimeError("render_backward: the packed gradient rows must be 16-byte aligned")
        self.g_P, self.g_o_g, self.g_colour = (_column_view(self.packed, col, dtype) for col, dtype in
                                               ((GRAD_P, wp.mat33), (GRAD_O_G, wp.vec3), (GRAD_COLOUR, wp.vec3)))
        self.grads = make_struct(SplatGrads, packed=self.packed)
        self.zero_mu_v = wp.empty(n, dtype=wp.vec3, device=device)

    def arrays(self) -> list:
        """The arrays that own memory (for :meth:`ScratchPool.nbytes`)."""
        return [self.packed, self.zero_mu_v]

    def forget(self) -> None:
        """Drop the reference to a backward's statistics array."""
        self.grads.grad2d_abs = None


class ScratchPool:
    """Spare scratch arrays of finished renders (:class:`SplatScratch`, :class:`PixelScratch`, :class:`GradScratch`),
    handed to later renders of the same sizes on the same device and stream (``render_forward(..., pool=)``,
    ``render_backward(..., pool=)``): a render's host time is mostly Python, a new Warp array costs ~30 Python calls,
    an allocation and a free, a struct field ~10 more, and a forward + backward makes ~20 of them.

    Rules (each makes reuse unable to change a result):

    - A scratch is only handed out by :meth:`take` and only comes back by :meth:`give`, once the host is done with it:
      a forward's ``state.scratch`` after that state's :func:`render_backward` (or at once when no backward will come),
      a backward's at its end. A scratch given twice, or to another pool, is refused.
    - Spares are filed per kind, device and stream (the device's current stream at :meth:`take`, the one the render
      launches on): kernels queued on that stream may still read a spare, and a render that takes it queues its own
      behind them. One given back on another stream than it was taken on is dropped, not kept.
    - Only exact sizes are handed out (``n`` for the per-Gaussian kinds, ``(num_pixels, num_tiles)`` for
      :class:`PixelScratch`); every array a render reads is written or zeroed by that render first.

    Memory, bounded whatever the sizes: per kind, device and stream, spares of the ``kind.sizes_kept`` sizes most
    recently taken or given (1 for the per-Gaussian kinds, 4 for :class:`PixelScratch`), at most ``max_spares`` of
    each size; spares of an older size are freed when a new size is taken or given. :meth:`nbytes` counts the spares,
    :meth:`clear` frees them. A training loop with one render in flight holds one spare of each kind between renders:
    ``248·N + 20·pixels + 8·tiles`` bytes that per-render arrays would have freed.
    """

    def __init__(self, max_spares: int = 2):
        if int(max_spares) < 0:
            raise ValueError(f"ScratchPool: max_spares must be >= 0, got {max_spares}")
        self.max_spares = int(max_spares)
        # (kind, device alias, stream handle) -> {sizes: [spare, ...]}, the least recently used sizes first
        self._slots: dict[tuple, OrderedDict] = {}
        self._lock = threading.Lock()  # torch runs a CUDA backward on a thread of its own

    @staticmethod
    def _where(kind, device) -> tuple:
        return kind, device.alias, device.stream.cuda_stream if device.is_cuda else 0

    def take(self, kind, device, *sizes):
        """A ``kind(*sizes, device)``: a spare of exactly these sizes filed under ``device``'s current stream, else a
        new one."""
        where = self._where(kind, device)
        scratch = None
        with self._lock:
            by_size = self._slots.get(where)
            if by_size is not None:
                spares = self._file(by_size, sizes, kind.sizes_kept)
                scratch = spares.pop() if spares else None
        if scratch is None:
            scratch = kind(*sizes, device)
        scratch.pool_slot = (self, where, sizes, device)
        return scratch

    def give(self, *scratches) -> None:
        """Keep each of ``scratches`` (from :meth:`take`; the host no longer uses it) for a later :meth:`take`."""
        for scratch in scratches:
            pool, where, sizes, device = getattr(scratch, "pool_slot", None) or (None,) * 4
            if pool is not self:
                raise ValueError("ScratchPool.give: not a scratch taken from this pool, or given back already")
            scratch.pool_slot = None
            if where != self._where(where[0], device):
                continue  # given back on another stream: dropped
            scratch.forget()
            with self._lock:
                spares = self._file(self._slots.setdefault(where, OrderedDict()), sizes, where[0].sizes_kept)
                if len(spares) < self.max_spares:
                    spares.append(scratch)

    @staticmethod
    def _file(by_size: OrderedDict, sizes: tuple, sizes_kept: int) -> list:
        """The spares of ``sizes`` in ``by_size``, made the most recently used; the least recently used sizes beyond
        ``sizes_kept`` are dropped."""
        spares = by_size.pop(sizes, None)
        by_size[sizes] = spares = [] if spares is None else spares
        while len(by_size) > sizes_kept:
            by_size.popitem(last=False)
        return spares

    def spares(self) -> list:
        """Every spare held now."""
        with self._lock:
            return [s for by_size in self._slots.values() for spares in by_size.values() for s in spares]

    def nbytes(self) -> int:
        """Bytes of the arrays the spares hold."""
        return sum(a.capacity for s in self.spares() for a in s.arrays())

    def clear(self) -> None:
        """Free every spare."""
        with self._lock:
            self._slots = {}


def _take(pool: ScratchPool | None, kind, device, *sizes):
    """``pool.take(kind, device, *sizes)``, or a new ``kind(*sizes, device)`` without a pool."""
    return kind(*sizes, device) if pool is None else pool.take(kind, device, *sizes)


def _mark(profile, name: str, device) -> None:
    """Record a timing event named ``name`` (end of that stage) when profiling on CUDA."""
    if profile is not None and device.is_cuda:
        event = wp.Event(device, enable_timing=True)
        wp.record_event(event)
        profile.append((name, event))


def _launch_raster(plain_kernel, tiled_kernel, tiled: bool, settings: RasterSettings, inputs: list, outputs: list, device):
    """Launch the per-pixel kernel: one block per tile in shared-memory mode, else one thread per pixel."""
    num_tiles = settings.tiles_x * settings.tiles_y
    if tiled:
        wp.launch_tiled(tiled_kernel, dim=[num_tiles], inputs=inputs, outputs=outputs, block_dim=int(TILE_PIXELS),
                        device=device, record_tape=False)  # fmt: skip
    else:
        wp.launch(plain_kernel, dim=num_tiles * settings.tile_size**2, inputs=inputs, outputs=outputs, device=device, record_tape=False)


def use_tiled_kernels(device, settings: RasterSettings, tiled: bool | None = None) -> bool:
    """Shared-memory kernels: by default on CUDA with 16×16 tiles. ``tiled=True`` forces them (on the CPU
    only with ``wp.config.enable_cpu_blocks``, which emulates the blocks: for testing)."""
    if tiled is None:
        return bool(device.is_cuda and settings.tile_size == TILE_SIZE)
    if tiled and (settings.tile_size != TILE_SIZE or not (device.is_cuda or wp.config.enable_cpu_blocks)):
        raise ValueError(f"the shared-memory kernels need tile_size {TILE_SIZE} and CUDA (or wp.config.enable_cpu_blocks)")
    return bool(tiled)


def _view(base: wp.array, offset: int, dtype, shape: tuple, strides: tuple) -> wp.array:
    """View of ``base``'s memory as ``dtype`` from byte ``offset`` with ``shape``/``strides`` in bytes (no copy; the
    view keeps ``base`` alive, since a pointer view does not own its memory)."""
    if base.size == 0 or 0 in shape:
        return wp.empty(shape, dtype=dtype, device=base.device)
    view = wp.array(ptr=base.ptr + offset, dtype=dtype, shape=shape, strides=strides,
                    capacity=base.capacity - offset, device=base.device)
    view._base = base
    return view


def sh_parts(sh) -> tuple[wp.array, wp.array]:
    """The SH coefficients as the kernels read them: ``(sh_dc [N] vec3, sh_rest [N, K−1] vec3)``.

    ``sh`` is either that pair (a model's two parameters, returned as given after a shape check; a pair of array
    descriptors, ``wp.from_torch(..., return_ctype=True)``, is returned unchecked: they are only launched) or one
    ``[N, K] vec3`` array, returned as two strided views of it (no copy; gradients written through the views land
    in the array's own ``grad``-shaped layout).
    """
    if isinstance(sh, (tuple, list)):
        if len(sh) != 2:
            raise ValueError(f"sh: expected (sh_dc, sh_rest), got {len(sh)} arrays")
        dc, rest = sh
        if not isinstance(dc, wp.array) and not isinstance(rest, wp.array):
            return dc, rest  # array descriptors (wp.from_torch(..., return_ctype=True)): only launched, not checked
        if dc.ndim != 1 or rest.ndim != 2 or rest.shape[0] != dc.shape[0] or dc.dtype != wp.vec3 or rest.dtype != wp.vec3:
            raise ValueError(f"sh: expected sh_dc [N] vec3 and sh_rest [N, K-1] vec3, got {dc.shape} {dc.dtype.__name__} and "
                             f"{rest.shape} {rest.dtype.__name__}")
        return dc, rest
    if sh.ndim != 2 or sh.dtype != wp.vec3 or sh.shape[1] < 1:
        raise ValueError(f"sh: expected an [N, K] vec3 array (K >= 1) or (sh_dc, sh_rest), got {sh.shape} {sh.dtype.__name__}")
    n, k = sh.shape
    return (_view(sh, 0, wp.vec3, (n,), (sh.strides[0],)),
            _view(sh, sh.strides[1], wp.vec3, (n, k - 1), sh.strides))


def prepare_view(means, quats, scales, opacities, sh, sh_degree: int, cam: CameraParams, settings: RasterSettings,
                 profile: list | None = None, sizer: TileListSizer | None = None,
                 scratch: tuple | None = None) -> tuple[Splats, TileLists, int]:  # fmt: skip
    """Per-view preprocessing and tile binning, shared by rendering and the opacity field.

    Returns ``(splats, lists, count)``: camera-space per-Gaussian data (``[N]`` each), the depth-sorted
    Gaussian indices of every tile, and the number of (Gaussian, tile) entries (allocated ones with a ``sizer``:
    see :func:`~.binning.bin_gaussians`). Memory: ``BYTES_PER_GAUSSIAN · N + BYTES_PER_TILE_ENTRY · count``.
    The arguments as in :func:`render_forward`; ``scratch``: the ``(SplatScratch, PixelScratch)`` to work in
    (``splats`` and ``lists`` are their structs; new arrays when ``None``).
    """
    device = opacities.device
    n = opacities.shape[0]
    num_tiles = settings.tiles_x * settings.tiles_y
    s, px = (SplatScratch(n, device), PixelScratch(0, num_tiles, device)) if scratch is None else scratch
    sh_dc, sh_rest = sh_parts(sh)
    wp.launch(preprocess_gaussians, dim=n, inputs=[means, quats, scales, sh_dc, sh_rest, int(sh_degree), cam.R, cam.t, cam.centre],
              outputs=[s.mu_v, s.P, s.o_g, s.colour], device=device, record_tape=False)  # fmt: skip
    wp.launch(screen_bounds, dim=n, inputs=[s.mu_v, quats, scales, opacities, cam, settings],
              outputs=[s.rect, s.touched, s.radii, s.depth, s.ellipse], device=device, record_tape=False)  # fmt: skip
    wp.launch(ray_conics, dim=n, inputs=[s.mu_v, quats, scales, opacities, s.radii, cam, settings],
              outputs=[s.conic, s.centre], device=device, record_tape=False)  # fmt: skip
    _mark(profile, "preprocess", device)
    px.range_start.zero_()
    px.range_end.zero_()
    values, _, _, count = bin_gaussians(s.rect, s.touched, s.depth, settings.tiles_x, num_tiles, s.ellipse, cam,
                                        settings, sizer, offsets=s.offsets, ranges=(px.range_start, px.range_end))
    _mark(profile, "binning", device)
    px.lists.values = values
    s.splats.opacity = opacities
    return s.splats, px.lists, count


def render_forward(means, quats, scales, opacities, sh, sh_degree: int, cam: CameraParams, settings: RasterSettings,
                   out: RenderOutputs | None = None, profile: list | None = None, tiled: bool | None = None,
                   sizer: TileListSizer | None = None,
                   pool: ScratchPool | None = None) -> tuple[RenderOutputs, RenderState]:  # fmt: skip
    """Render ``N`` Gaussians (activated parameters) into ``out`` (allocated when ``None``).

    Args:
        means ``[N] vec3`` world; quats ``[N] vec4`` unit wxyz; scales ``[N] vec3`` > 0; opacities ``[N]``;
        sh ``[N, K] vec3`` with ``K ≥ (sh_degree+1)²``, or the pair ``(sh_dc [N] vec3, sh_rest [N, K−1] vec3)``
        (:func:`sh_parts`); cam, settings: see ``render_types``. All but ``opacities`` are only passed to launches, so
        they may also be array descriptors (``wp.from_torch(..., return_ctype=True)``, lighter to make and to launch
        with; ``sh`` then as a pair); the device and ``N`` are read from ``opacities``.
        profile: optional list; on CUDA, ``(stage name, wp.Event)`` pairs marking the end of each stage
            are appended (timings for benchmarks).
        tiled: force the shared-memory (True) or plain (False) per-pixel kernels; default: see
            :func:`use_tiled_kernels`.
        sizer: a :class:`~.binning.TileListSizer` kept across renders: no host–device synchronisation to size
            the tile lists (``None``: exact sizing, one synchronisation).
        pool: a :class:`ScratchPool` to take the render's scratch arrays from (new ones when ``None``); the caller
            gives ``state.scratch`` back to it once done with the state (``pool.give(*state.scratch)`` after
            :func:`render_backward`, or at once when no backward will come). Same results either way.
    """
    device = opacities.device
    n = opacities.shape[0]
    num_pixels = cam.width * cam.height
    _mark(profile, "start", device)
    if out is None:
        out = RenderOutputs.allocate(num_pixels, device)
    scratch = (_take(pool, SplatScratch, device, n),
               _take(pool, PixelScratch, device, num_pixels, settings.tiles_x * settings.tiles_y))
    sh = sh_parts(sh)
    splats, lists, count = prepare_view(means, quats, scales, opacities, sh, sh_degree, cam, settings, profile, sizer,
                                        scratch)
    aux = scratch[1].aux
    tiled = use_tiled_kernels(device, settings, tiled)
    _launch_raster(rasterize_forward, rasterize_forward_tiled, tiled, settings, [lists, splats, cam, settings], [out.as_struct(), aux], device)
    _mark(profile, "raster_forward", device)
    # without a pool the state keeps only what the backward reads: the binning's temporaries are freed here
    state = RenderState((means, quats, scales, opacities, sh), int(sh_degree), cam, settings, splats.mu_v, splats.P,
                        splats.o_g, splats.colour, splats.radius, lists, splats, aux, count, tiled,
                        scratch if pool is not None else ())  # fmt: skip
    return out, state


def _column_view(packed: wp.array, column: int, dtype) -> wp.array:
    """``[N]`` view of ``dtype`` starting at ``column`` of every row of the ``[N, W]`` float array ``packed`` (no copy)."""
    return _view(packed, column * 4, dtype, (packed.shape[0],), (packed.strides[0],))


def render_backward(state: RenderState, grad_out: RenderOutputs, grad_in: tuple, grad2d=None, grad2d_abs=None, profile=None,
                    zeroed: bool = False, pool: ScratchPool | None = None):
    """Accumulate the input gradients for the output gradients ``grad_out``.

    Args:
        grad_out: per-pixel output gradients (same layout as :class:`RenderOutputs`).
        grad_in: ``(means, quats, scales, opacities, sh)`` gradient arrays, added into; ``sh``'s as in
            :func:`render_forward` (one ``[N, K]`` array or the ``(sh_dc, sh_rest)`` pair). They are only passed to
            launches and may be array descriptors (see :func:`render_forward`).
        grad2d ``[N] vec2``, grad2d_abs ``[N]``: densification statistics, added into (optional, together);
            ``grad2d`` may be an array descriptor.
        profile: as in :func:`render_forward`.
        zeroed: the SH gradient arrays of ``grad_in`` hold zeros (fresh buffers): their rows are written instead of
            added into, which spares a load per coefficient (same result).
        pool: a :class:`ScratchPool` to take the backward's :class:`GradScratch` from (given back at the end; new
            arrays when ``None``). ``state.scratch`` is the caller's to give back.
    """
    device = state.device
    _mark(profile, "start", device)
    n = state.mu_v.shape[0]
    cam, settings = state.cam, state.settings
    scratch = _take(pool, GradScratch, device, n)
    packed = scratch.packed
    packed.zero_()
    with_stats = grad2d is not None  # without: the kernels never touch grad2d / grad2d_abs, passed as null arrays
    grads = scratch.grads
    grads.grad2d_abs = grad2d_abs if with_stats else None
    _launch_raster(rasterize_backward, rasterize_backward_tiled, state.tiled, settings,
                   [state.lists, state.splats, cam, settings, state.aux, grad_out.as_struct(), int(with_stats)], [grads], device)  # fmt: skip
    _mark(profile, "raster_backward", device)
    zero_mu_v, gP, g_og, g_col = scratch.zero_mu_v, scratch.g_P, scratch.g_o_g, scratch.g_colour
    zero_mu_v.zero_()
    wp.launch(finish_splat_grads, dim=n, inputs=[packed, state.P, state.mu_v, cam, int(with_stats)],
              outputs=[grad_in[3], grad2d if with_stats else None], device=device,
              record_tape=False)  # fmt: skip
    means, quats, scales, _, (sh_dc, sh_rest) = state.inputs
    grad_dc, grad_rest = sh_parts(grad_in[4])
    # the gradient of preprocess_gaussians: its camera-space part by Warp's adjoint, the colour's written out
    wp.launch(project_frames, dim=n, inputs=[means, quats, scales, cam.R, cam.t],
              outputs=[state.mu_v, state.P, state.o_g],
              adj_inputs=[grad_in[0], grad_in[1], grad_in[2], wp.mat33(), wp.vec3()],
              adj_outputs=[zero_mu_v, gP, g_og],
              adjoint=True, device=device, record_tape=False)  # fmt: skip
    wp.launch(sh_colour_backward, dim=n * SH_LANES,
              inputs=[means, sh_rest, state.sh_degree, cam.centre, state.colour, g_col],
              outputs=[grad_in[0], grad_dc, grad_rest, int(not zeroed)], device=device, record_tape=False)  # fmt: skip
    _mark(profile, "preprocess_backward", device)
    if pool is not None:
        pool.give(scratch)


def render_gaussians(means, quats, scales, opacities, sh, sh_degree: int, cam: CameraParams, settings: RasterSettings,
                     tape: wp.Tape | None = None, grad2d=None, grad2d_abs=None) -> RenderOutputs:  # fmt: skip
    """Forward render; with ``tape``, records the hand-written backward on it (``tape.record_func``).

    ``sh``: one ``[N, K] vec3`` array or the pair ``(sh_dc, sh_rest)`` (:func:`sh_parts`). The outputs then carry
    gradient buffers; ``tape.backward`` adds into ``means.grad, quats.grad, scales.grad, opacities.grad`` and the SH
    arrays' ``grad`` (each must exist: create the inputs with ``requires_grad=True``) and, when given, into the
    densification statistics ``grad2d [N] vec2`` / ``grad2d_abs [N]``.
    Returns the outputs; the forward state is kept by the tape's closure.
    """
    out = RenderOutputs.allocate(cam.width * cam.height, means.device, requires_grad=tape is not None)
    out, state = render_forward(means, quats, scales, opacities, sh, sh_degree, cam, settings, out=out)
    if tape is not None:
        sh_arrays = tuple(sh) if isinstance(sh, (tuple, list)) else (sh,)
        inputs = (means, quats, scales, opacities, *sh_arrays)
        missing = [i for i, a in enumerate(inputs) if a.grad is None]
        if missing:
            raise ValueError(f"render_gaussians: inputs {missing} (means, quats, scales, opacities, sh) need requires_grad=True to record on a tape")

        def backward():
            grad_out = RenderOutputs(*[a.grad for a in out.arrays()])
            grad_sh = tuple(a.grad for a in sh_arrays) if len(sh_arrays) == 2 else sh_arrays[0].grad
            render_backward(state, grad_out, tuple(a.grad for a in inputs[:4]) + (grad_sh,), grad2d, grad2d_abs)

        tape.record_func(backward=backward, arrays=out.arrays() + list(inputs))
    return out
