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

from dataclasses import dataclass, fields

import warp as wp

from .binning import TileListSizer, bin_gaussians
from .project import SH_LANES, preprocess_gaussians, project_frames, screen_bounds, sh_colour_backward
from .rasterize import rasterize_forward
from .rasterize_backward import finish_splat_grads, rasterize_backward
from .rasterize_tiled import TILE_PIXELS, TILE_SIZE, rasterize_backward_tiled, rasterize_forward_tiled
from .render_types import (GRAD_COLOUR, GRAD_O_G, GRAD_P, GRAD_WIDTH, CameraParams, PixelAux, PixelMaps, RasterSettings,
                           SplatGrads, Splats, TileLists, make_struct)
from .tile_overlap import empty_tile_ellipses

#: Bytes of per-Gaussian renderer state (mu_v 12, P 36, o_g 12, colour 12, rect 16, counts/radii/depth/
#: offsets 16, tile-test exact/conic/centre 4 + 48 + 16) and per (Gaussian, tile) entry (int64 key + int32 value, ×2 for the
#: radix sort's scratch).
BYTES_PER_GAUSSIAN = 172
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

    @property
    def device(self):
        return self.mu_v.device


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
                 profile: list | None = None, sizer: TileListSizer | None = None) -> tuple[Splats, TileLists, int]:
    """Per-view preprocessing and tile binning, shared by rendering and the opacity field.

    Returns ``(splats, lists, count)``: camera-space per-Gaussian data (``[N]`` each), the depth-sorted
    Gaussian indices of every tile, and the number of (Gaussian, tile) entries (allocated ones with a ``sizer``:
    see :func:`~.binning.bin_gaussians`). Memory: ``BYTES_PER_GAUSSIAN · N + BYTES_PER_TILE_ENTRY · count``.
    The arguments as in :func:`render_forward`.
    """
    device = opacities.device
    n = opacities.shape[0]

    def empty(dtype):
        return wp.empty(n, dtype=dtype, device=device)

    mu_v, P, o_g, colour = empty(wp.vec3), empty(wp.mat33), empty(wp.vec3), empty(wp.vec3)
    rect, touched, radii, depth = empty(wp.vec4i), empty(wp.int32), empty(wp.int32), empty(float)
    ellipse = empty_tile_ellipses(n, device)
    sh_dc, sh_rest = sh_parts(sh)
    wp.launch(preprocess_gaussians, dim=n, inputs=[means, quats, scales, sh_dc, sh_rest, int(sh_degree), cam.R, cam.t, cam.centre],
              outputs=[mu_v, P, o_g, colour], device=device, record_tape=False)  # fmt: skip
    wp.launch(screen_bounds, dim=n, inputs=[mu_v, quats, scales, opacities, cam, settings],
              outputs=[rect, touched, radii, depth, ellipse], device=device, record_tape=False)  # fmt: skip
    _mark(profile, "preprocess", device)
    num_tiles = settings.tiles_x * settings.tiles_y
    values, range_start, range_end, count = bin_gaussians(rect, touched, depth, settings.tiles_x, num_tiles, ellipse, cam, settings,
                                                          sizer)
    _mark(profile, "binning", device)
    lists = make_struct(TileLists, values=values, range_start=range_start, range_end=range_end)
    splats = make_struct(Splats, P=P, o_g=o_g, colour=colour, opacity=opacities, mu_v=mu_v, radius=radii)
    return splats, lists, count


def render_forward(means, quats, scales, opacities, sh, sh_degree: int, cam: CameraParams, settings: RasterSettings,
                   out: RenderOutputs | None = None, profile: list | None = None, tiled: bool | None = None,
                   sizer: TileListSizer | None = None) -> tuple[RenderOutputs, RenderState]:  # fmt: skip
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
    """
    device = opacities.device
    n = opacities.shape[0]
    num_pixels = cam.width * cam.height
    _mark(profile, "start", device)
    if out is None:
        out = RenderOutputs.allocate(num_pixels, device)

    def empty(dtype, size=n):
        return wp.empty(size, dtype=dtype, device=device)

    sh = sh_parts(sh)
    splats, lists, count = prepare_view(means, quats, scales, opacities, sh, sh_degree, cam, settings, profile, sizer)
    mu_v, P, o_g, colour, radii = splats.mu_v, splats.P, splats.o_g, splats.colour, splats.radius

    final_T, last_end = empty(float, num_pixels), empty(wp.int32, num_pixels)
    median_pos, weight_sum = empty(wp.int32, num_pixels), empty(float, num_pixels)
    dist_sum = empty(float, num_pixels)
    tiled = use_tiled_kernels(device, settings, tiled)
    aux = make_struct(PixelAux, final_T=final_T, last_end=last_end, median_pos=median_pos, weight_sum=weight_sum,
                      dist_sum=dist_sum)
    _launch_raster(rasterize_forward, rasterize_forward_tiled, tiled, settings, [lists, splats, cam, settings], [out.as_struct(), aux], device)
    _mark(profile, "raster_forward", device)
    state = RenderState((means, quats, scales, opacities, sh), int(sh_degree), cam, settings, mu_v, P, o_g, colour,
                        radii, lists, splats, aux, count, tiled)  # fmt: skip
    return out, state


def _column_view(packed: wp.array, column: int, dtype) -> wp.array:
    """``[N]`` view of ``dtype`` starting at ``column`` of every row of the ``[N, W]`` float array ``packed`` (no copy)."""
    return _view(packed, column * 4, dtype, (packed.shape[0],), (packed.strides[0],))


def render_backward(state: RenderState, grad_out: RenderOutputs, grad_in: tuple, grad2d=None, grad2d_abs=None, profile=None,
                    zeroed: bool = False):
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
    """
    device = state.device
    _mark(profile, "start", device)
    n = state.mu_v.shape[0]
    cam, settings = state.cam, state.settings
    packed = wp.zeros((n, GRAD_WIDTH), dtype=float, device=device)
    if n and packed.ptr % 16:
        raise RuntimeError("render_backward: the packed gradient rows must be 16-byte aligned")
    with_stats = grad2d is not None  # without: the kernels never touch grad2d / grad2d_abs, passed as null arrays
    grads = make_struct(SplatGrads, packed=packed, grad2d_abs=grad2d_abs if with_stats else None)
    _launch_raster(rasterize_backward, rasterize_backward_tiled, state.tiled, settings,
                   [state.lists, state.splats, cam, settings, state.aux, grad_out.as_struct(), int(with_stats)], [grads], device)  # fmt: skip
    _mark(profile, "raster_backward", device)
    gP, g_og, g_col = (_column_view(packed, col, dtype) for col, dtype in ((GRAD_P, wp.mat33), (GRAD_O_G, wp.vec3), (GRAD_COLOUR, wp.vec3)))
    wp.launch(finish_splat_grads, dim=n, inputs=[packed, state.P, state.mu_v, cam, int(with_stats)],
              outputs=[grad_in[3], grad2d if with_stats else None], device=device,
              record_tape=False)  # fmt: skip
    means, quats, scales, _, (sh_dc, sh_rest) = state.inputs
    grad_dc, grad_rest = sh_parts(grad_in[4])
    # the gradient of preprocess_gaussians: its camera-space part by Warp's adjoint, the colour's written out
    wp.launch(project_frames, dim=n, inputs=[means, quats, scales, cam.R, cam.t],
              outputs=[state.mu_v, state.P, state.o_g],
              adj_inputs=[grad_in[0], grad_in[1], grad_in[2], wp.mat33(), wp.vec3()],
              adj_outputs=[wp.zeros(n, dtype=wp.vec3, device=device), gP, g_og],
              adjoint=True, device=device, record_tape=False)  # fmt: skip
    wp.launch(sh_colour_backward, dim=n * SH_LANES,
              inputs=[means, sh_rest, state.sh_degree, cam.centre, state.colour, g_col],
              outputs=[grad_in[0], grad_dc, grad_rest, int(not zeroed)], device=device, record_tape=False)  # fmt: skip
    _mark(profile, "preprocess_backward", device)


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
