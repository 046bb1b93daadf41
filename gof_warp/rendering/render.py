"""Differentiable ray–Gaussian rendering for torch (GOF Sec. 3.1–3.3): :func:`render`, :func:`rasterize`.

The math, conventions and kernel structure are in ``docs/rendering.md``; the kernels in
:mod:`gof_warp.kernels.renderer`. This module validates the torch inputs, wraps the Warp forward and the
hand-written Warp backward in a ``torch.autograd.Function`` (launched on torch's current CUDA stream) and
returns the per-pixel maps as ``[H, W, ...]`` tensors.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import torch
import warp as wp

from ..core.camera import Camera
from ..core.config import ConfigError
from ..core.devices import StreamWrappers
from ..kernels.render_types import camera_params_from, make_camera_params, make_raster_settings
from ..kernels.binning import TileListSizer
from ..kernels.renderer import RenderOutputs, ScratchPool, render_backward, render_forward


_PARAM_NAMES = ("means", "quats", "scales", "opacities", "sh_dc", "sh_rest")
_PARAM_TYPES = (wp.vec3, wp.vec4, wp.vec3, None, wp.vec3, wp.vec3)
#: which parameters the renderer's host functions only pass to launches, so that they can go as Warp's light array
#: descriptors (``_wp(launch_only=True)``): all but the opacities, which are also a struct field. Every input
#: gradient is only launched.
_LAUNCH_ONLY = (True, True, True, False, True, True)
_MODEL_ATTRS = ("means", "rotations", "scales", "opacities", "active_sh_degree")  # what render() reads of a model
_MISSING = object()


DEFAULT_NEAR = 0.2  # GOF's near plane, for scenes of a few units
# Left at DEFAULT_NEAR, the near plane is at most this fraction of the scene's size (scene_near): scenes of size
# >= 1 keep 0.2 exactly, a scene of size 1e-6 gets 2e-7 instead of a plane far beyond everything it holds.
NEAR_SCENE_FRACTION = 0.2


def scene_size(extent: float, cameras=None, points=None) -> float:
    """A scene's size for :func:`scene_near`: its camera extent (3DGS's ``cameras_extent``), or when initial
    points are given and larger, the median distance from the cameras' mean centre to them (forward-facing
    captures: cameras close together looking at things far away)."""
    size = float(extent)
    if cameras and points is not None and len(points):
        centre = np.mean([c.center for c in cameras], axis=0)
        size = max(size, float(np.median(np.linalg.norm(np.asarray(points, np.float64) - centre, axis=1))))
    return size


def scene_near(near: float, size: float) -> tuple[float, str | None]:
    """``(near plane to use, a warning or None)`` for ``render.near = near`` in a scene of ``size``.

    ``near == DEFAULT_NEAR`` (the setting left alone): ``min(0.2, NEAR_SCENE_FRACTION × size)``, so normal scenes
    keep 0.2. Another value is the user's: kept, with a warning when it is larger than the scene."""
    if not (size > 0 and math.isfinite(size)):
        return near, None
    if near == DEFAULT_NEAR:
        return min(near, NEAR_SCENE_FRACTION * size), None
    if near > size:
        return near, (f"render.near = {near:g} is larger than the scene (size {size:.3g}): Gaussians nearer than "
                      f"that to a camera are not drawn, which may be most of the scene")
    return near, None


@dataclass
class RenderConfig:
    """Compositing thresholds (defaults: the official GOF/3DGS rasteriser, ``GOF_REFERENCE.md`` §1–2).

    ``distortion``, ``distortion_linear_from`` and ``tile_cull`` are set in a training config through its
    ``experimental`` section (:mod:`gof_warp.training.settings`); constructing a RenderConfig checks every value
    (:class:`~gof_warp.core.config.ConfigError` naming the key).

    Attributes:
        near: Gaussians with camera z ≤ near are culled and intersections with t* ≤ near skipped
            (GOF hard-codes 0.2; scale-dependent, hence configurable). Left at 0.2, a training run scales it
            down for a scene smaller than 1 unit (:func:`scene_near`: ``0.2 ×`` the scene's size); any other
            value is used as given, with a warning when it is larger than the scene.
        alpha_min: (pixel, Gaussian) pairs with α < alpha_min are skipped (3DGS/GOF: 1/255).
        alpha_max: α = min(alpha_max, opacity · E) (3DGS/GOF: 0.99).
        transmittance_min: compositing stops before a Gaussian that would bring T below it (1e-4).
        k_max: pairs whose ray passes farther than k_max Mahalanobis units from the mean are skipped;
            also caps the binning ellipsoid. Default sqrt(2 ln 255) ≈ 3.33: the extent at which an
            opacity-1 Gaussian falls below 1/255, so it never removes a pair alpha_min keeps.
        tile_size: screen tile edge in pixels (16 as 3DGS).
        background: RGB composited behind the Gaussians (GOF: black, or white with --white_background).
        distortion: ``"gof"`` (default): Σ_{j<i} w_i w_j (m_i − m_j)² on the NDC depth
            m(t) = far (t − near) / ((far − near) t), as the official GOF/2DGS code computes it — the
            form its λ_d (100 / 1000) is calibrated for; ``"paper"``: Σ_ij w_i w_j |t_i − t_j| on raw depth
            (paper Eq. 13), whose gradient is ~10⁴ times larger at scene depths of a few units, so λ_d must
            then be scaled down accordingly. Weights are detached in both (gradient only through t*).
        far: the far plane of m(t) (GOF: 100).
        distortion_linear_from: 0 (GOF): the ``"gof"`` distortion compares m(t) everywhere, so its weight per unit
            of depth falls as ``near / t²`` and layers far behind the objects cost almost nothing. ``L > near``:
            beyond depth ``L`` m(t) is continued by its tangent at ``L``, so far layers are compressed as hard as
            layers at ``L`` (not GOF; measured: see benchmarks/RESULTS.md).
        tile_cull: bin each Gaussian only into the screen tiles its projected ellipse meets (exact,
            conservative; same images and gradients, fewer list entries); False: every tile of its
            bounding rectangle (as 3DGS/GOF), for comparisons.
        near_from_points: ``f > 0``: the trainer gives each camera (train and test) its own near plane, ``f`` × the
            depth of the nearest initial (SfM or triangulated) point in its image (:attr:`Camera.near`; never
            below ``near``), as NeRF's LLFF loader bounds rays by the SfM depths. A Gaussian closer to a camera
            than anything the photos triangulated is then not drawn in that view, so it cannot cover it.
            ``render()`` itself reads only the camera's ``near``. 0 (default, GOF): ``near`` for every camera.
    """

    near: float = DEFAULT_NEAR
    alpha_min: float = 1.0 / 255.0
    alpha_max: float = 0.99
    transmittance_min: float = 1e-4
    k_max: float = math.sqrt(2.0 * math.log(255.0))
    tile_size: int = 16
    background: tuple = (0.0, 0.0, 0.0)
    distortion: str = field(default="gof", metadata={"set_by": "experimental.distortion"})
    far: float = 100.0
    tile_cull: bool = field(default=True, metadata={"set_by": "experimental.tile_cull"})
    distortion_linear_from: float = field(default=0.0, metadata={"set_by": "experimental.distortion_linear_from"})
    near_from_points: float = 0.0

    def clip_near(self, camera: Camera) -> float:
        """The depth the renderer clips ``camera``'s view at: the larger of ``near`` and the camera's own
        (:attr:`Camera.near`; 0 when it has none)."""
        return max(self.near, getattr(camera, "near", 0.0))

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the key (``render.near``) and its allowed range."""
        if not self.near > 0:
            raise ConfigError(f"render.near must be > 0, got {self.near}")
        if not 0 <= self.near_from_points < 1:
            raise ConfigError(f"render.near_from_points must be in [0, 1) (0: off), got {self.near_from_points}")
        if not 0 <= self.alpha_min <= self.alpha_max < 1:
            raise ConfigError(f"render.alpha_min, render.alpha_max: need 0 <= alpha_min <= alpha_max < 1, got "
                              f"{self.alpha_min}, {self.alpha_max}")
        if not 0 <= self.transmittance_min < 1:
            raise ConfigError(f"render.transmittance_min must be in [0, 1), got {self.transmittance_min}")
        if not self.k_max > 0 or not math.isfinite(self.k_max):
            raise ConfigError(f"render.k_max must be finite and > 0, got {self.k_max}")
        if int(self.tile_size) != self.tile_size or not 1 <= self.tile_size <= 32:
            raise ConfigError(f"render.tile_size must be an integer in [1, 32], got {self.tile_size}")
        if self.distortion not in ("gof", "paper"):
            raise ConfigError(f"experimental.distortion must be 'gof' or 'paper', got {self.distortion!r}")
        if not self.far > self.near:
            raise ConfigError(f"render.far must be > near, got {self.far}")
        if not (self.distortion_linear_from == 0 or self.distortion_linear_from > self.near):
            raise ConfigError("experimental.distortion_linear_from must be 0 (off) or a depth beyond near "
                             f"({self.near}), got {self.distortion_linear_from}")
        if self.distortion_linear_from and self.distortion != "gof":
            raise ConfigError("experimental.distortion_linear_from applies to the 'gof' distortion only, "
                             f"got distortion={self.distortion!r}")
        if len(self.background) != 3:
            raise ConfigError(f"render.background must have 3 entries, got {self.background}")


def raster_settings_for(camera: Camera, config: RenderConfig, pixel_pad: float = 0.0):
    """The kernels' ``RasterSettings`` for ``camera``'s image under ``config`` (``pixel_pad``: see
    ``gof_warp.kernels.render_types``; 0 for rendering pixel centres). The clipping depth is the larger of
    ``config.near`` and the camera's own ``near`` (:attr:`Camera.near`); the distortion's NDC depth keeps
    ``config.near`` as its near plane, so a camera's clip does not change what the distortion weighs."""
    return _make_raster_settings(*_raster_settings_args(camera, config, pixel_pad))


def _raster_settings_args(camera: Camera, config: RenderConfig, pixel_pad: float) -> tuple:
    """The arguments of :func:`_make_raster_settings` for ``camera`` under ``config``: every value the settings are
    made of, hashable (the key of :class:`RenderScratch`'s shared settings)."""
    return (camera.width, camera.height, config.clip_near(camera), config.alpha_min, config.alpha_max,
            config.transmittance_min, config.k_max, tuple(float(b) for b in config.background), config.tile_size,
            pixel_pad, config.distortion, config.far, config.tile_cull, config.distortion_linear_from,
            config.near)  # fmt: skip


def _make_raster_settings(width, height, near, alpha_min, alpha_max, transmittance_min, k_max, background, tile_size,
                          pixel_pad, distortion, far, tile_cull, distortion_linear_from, ndc_near):  # fmt: skip
    return make_raster_settings(width, height, near, alpha_min, alpha_max, transmittance_min, k_max, background,
                                tile_size, pixel_pad=pixel_pad, distortion=distortion, far=far, tile_cull=tile_cull,
                                distortion_linear_from=distortion_linear_from, ndc_near=ndc_near)  # fmt: skip


def _camera_params_from_bytes(R: bytes, t: bytes, fx, fy, cx, cy, width, height):
    """``camera_params_from`` for a camera whose float64 ``R [3, 3]`` and ``t [3]`` are given as bytes."""
    return make_camera_params(np.frombuffer(R).reshape(3, 3), np.frombuffer(t), fx, fy, cx, cy, width, height)


class DensifyStats:
    """Per-Gaussian densification statistics filled by the renderer (GOF Sec. 3.3, 3DGS Sec. 5.2).

    Pass one to :func:`render`/:func:`rasterize` (``stats=``); it must be sized for the same ``N`` and
    live on the same device. The forward writes ``radii`` (this render) and raises ``max_radii`` and
    ``visible_count``; the backward **adds** into the gradient sums, so one object accumulates over
    the views of a densification interval. With ``g_p = (∂L_p/∂u, ∂L_p/∂v)·(W/2, H/2)`` the gradient of
    pixel p's outputs w.r.t. the projected mean at fixed depth (NDC units, through the ray–Gaussian
    geometry; the SH view-direction dependence is not included, as in 3DGS):

    Attributes:
        grad2d: ``[N, 2]`` float32, Σ_p g_p (its norm is 3DGS's view-space gradient).
        grad2d_abs: ``[N]`` float32, Σ_p ‖g_p‖₂ (the paper's per-pixel-norm metric).
        radii: ``[N]`` int32 screen radius (pixels) of the latest render; 0 = not visible.
        max_radii: ``[N]`` int32 max of ``radii`` over the renders.
        visible_count: ``[N]`` int32 number of renders in which the Gaussian was visible.
    """

    def __init__(self, num_gaussians: int, device="cpu"):
        n = int(num_gaussians)
        self.grad2d = torch.zeros(n, 2, dtype=torch.float32, device=device)
        self.grad2d_abs = torch.zeros(n, dtype=torch.float32, device=device)
        self.radii = torch.zeros(n, dtype=torch.int32, device=device)
        self.max_radii = torch.zeros(n, dtype=torch.int32, device=device)
        self.visible_count = torch.zeros(n, dtype=torch.int32, device=device)

    def __len__(self) -> int:
        return self.radii.shape[0]

    def reset(self) -> None:
        for t in (self.grad2d, self.grad2d_abs, self.radii, self.max_radii, self.visible_count):
            t.zero_()

    def _record_radii(self, radii: torch.Tensor) -> None:
        self.radii.copy_(radii)
        torch.maximum(self.max_radii, radii, out=self.max_radii)
        self.visible_count += (radii > 0).to(torch.int32)


class RenderScratch:
    """What a caller that renders over and over (a training loop) keeps between its renders to spend less host time
    on each: pass one to :func:`render` / :func:`rasterize` (``scratch=``), as a :class:`TileListSizer`. Outputs and
    gradients are the same as without it, bit for bit; the renders without one are untouched.

    It holds:

    - ``pool``, a :class:`~gof_warp.kernels.renderer.ScratchPool`: the scratch arrays of finished renders (the
      per-Gaussian ``SplatScratch`` and ``GradScratch``, the per-pixel ``PixelScratch``, and the Warp structs over
      them), handed to the next render of exactly the same sizes. A forward's arrays come back after its backward (at
      once when no backward will come: under ``torch.no_grad()`` or when no input requires a gradient), so a render
      whose backward is pending never shares arrays with another render.
    - the camera and settings structs of the latest ``max_views`` distinct views and settings, keyed by every value
      they are made of (the camera's pose and intrinsics; the config's values and the camera's near plane), so a
      struct handed out is the one a new render would build; the renders of a view share it (no render changes one).
    - Warp's wrapper of each torch CUDA stream rendered on (by device and stream handle), made once instead of per
      forward and per backward; every render launches on torch's current stream, as without it.

    Memory, for ``N`` Gaussians and images of ``P`` pixels in ``T`` tiles: with one render in flight at a time (the
    trainer) the spares held between renders are ``268·N + 20·P + 8·T`` bytes (a forward's 192 B a Gaussian and a
    backward's 76, which per-render arrays would have freed), plus ``20·P + 8·T`` for each of up to 3 more image sizes
    rendered last; at most ``max_spares`` times that with renders overlapping. That is the most it adds to the memory
    in use at any moment (between renders; during one, 192 B a Gaussian at most): ~225 MB at 800k Gaussians on
    800×600 images. Spares of an older ``N`` are freed when a new one is taken, and :meth:`clear` frees them all (the
    trainer does before a step that densifies or prunes). On the host, the struct caches hold ~3.5 MB when full
    (1024 views and 1024 settings); one stream wrapper per torch stream rendered on (torch's streams are a fixed pool).

    Threads and streams: one object may serve renders on several threads (torch runs a CUDA backward on a thread of
    its own) and streams: the pool and the wrapper cache are guarded by locks, and spares are filed per device and
    per stream the render launched on, so a spare goes only to a later render on the same stream, queued behind the
    kernels that used it; one given back on another stream is dropped. Not for renders captured into CUDA graphs,
    and not to be shared between processes.

    Checked on CUDA (one H100): ``tests/rendering/test_render_host_glue.py`` (outputs bit for bit, gradients within the float
    atomics' run-to-run spread, spares on two streams). A scratch saves ~1.3 ms of host time a forward + backward
    at 800k Gaussians on 800×600 (GPU time unchanged) and raises Warp's pool peak on DTU scan 24 from ~183 to
    ~245 MB (within the bound above). ``compute-sanitizer --tool memcheck`` over those tests and 233 training
    iterations through a count change finds no error. On a non-default torch stream, Warp 1.19 registers a stream
    per wrapper without counting them, so a short-lived wrapper of the same handle made elsewhere (a render without
    a scratch, ``volume.py``, ``marching_inputs.py``) unregisters it under the cached one when it dies, as
    per-render wrappers already do to each other; the trainer renders on torch's default stream (handle 0), which
    Warp never registers.
    """

    def __init__(self, max_spares: int = 2, max_views: int = 1024):
        self.pool = ScratchPool(max_spares)
        self.max_views = int(max_views)
        self._camera_params = functools.lru_cache(maxsize=self.max_views)(_camera_params_from_bytes)
        self._raster_settings = functools.lru_cache(maxsize=self.max_views)(_make_raster_settings)
        self._streams = StreamWrappers()

    def view_structs(self, camera: Camera, config: RenderConfig) -> tuple:
        """``(camera_params_from(camera), raster_settings_for(camera, config))``, shared with the earlier renders of
        the same values (never to be modified)."""
        R, t = (np.ascontiguousarray(x, dtype=np.float64).tobytes() for x in (camera.R, camera.t))
        cam = self._camera_params(R, t, camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height)
        return cam, self._raster_settings(*_raster_settings_args(camera, config, 0.0))

    def stream_scope(self, device: torch.device):
        """A scope that launches on torch's current stream of ``device`` (CUDA) through a cached Warp wrapper."""
        return wp.ScopedStream(self._streams.current(device))

    def nbytes(self) -> int:
        """Bytes of the spare arrays held now."""
        return self.pool.nbytes()

    def clear(self) -> None:
        """Free the spare arrays (the structs and stream wrappers stay: they are small)."""
        self.pool.clear()


def _stream_scope(device: torch.device, scratch: RenderScratch | None = None):
    """Launch on torch's current stream on CUDA (through ``scratch``'s wrapper of it when given); a no-op scope on the
    CPU."""
    wp.init()  # stream_from_torch needs Warp's runtime (idempotent)
    if device.type == "cuda":
        if scratch is not None:
            return scratch.stream_scope(device)
        return wp.ScopedStream(wp.stream_from_torch(device))
    return wp.ScopedDevice("cpu")


def _wp(t: torch.Tensor, dtype=None, launch_only: bool = False):
    """``t`` as a Warp array (no copy); ``launch_only``: as the lighter array descriptor that ``wp.launch`` takes, for
    an array that is only passed to kernels (not set in a struct, viewed or asked for its device or shape)."""
    if t.numel() == 0:  # e.g. sh[:, 1:] of a degree-0 model: torch keeps the parent's strides, Warp wants packed ones
        t = torch.empty(t.shape, dtype=t.dtype, device=t.device)
    # requires_grad=False: the kernels get no gradient buffer (the inputs come in requiring grad: no .detach() needed)
    return wp.from_torch(t.contiguous(), dtype=dtype, requires_grad=False, return_ctype=launch_only)


class _RasterizeFunction(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opacities, sh_dc, sh_rest, cam, settings, sh_degree, stats, sizer, scratch,
                differentiable):
        device = means.device
        pool = None if scratch is None else scratch.pool
        H, W = cam.height, cam.width
        f32 = dict(dtype=torch.float32, device=device)
        outs = [torch.empty(H * W, 3, **f32), torch.empty(H * W, **f32), torch.empty(H * W, **f32),
                torch.empty(H * W, **f32), torch.empty(H * W, 3, **f32), torch.empty(H * W, **f32)]  # fmt: skip
        types = (wp.vec3, None, None, None, wp.vec3, None)
        with _stream_scope(device, scratch):
            args = [_wp(x, t, launch_only) for x, t, launch_only in
                    zip((means, quats, scales, opacities, sh_dc, sh_rest), _PARAM_TYPES, _LAUNCH_ONLY)]
            out = RenderOutputs(*[_wp(o, t) for o, t in zip(outs, types)])
            _, state = render_forward(*args[:4], tuple(args[4:]), sh_degree, cam, settings, out=out, sizer=sizer,
                                      pool=pool)  # fmt: skip
            radii = wp.to_torch(state.radii)
            if stats is not None:
                stats._record_radii(radii)
            radii = radii.clone()  # the state's radii may be a spare's, which the next render overwrites
            if pool is not None and not differentiable:  # no backward will come: the arrays can go at once
                pool.give(*state.scratch)
                state = None
        ctx.state, ctx.stats, ctx.types, ctx.device, ctx.scratch = state, stats, types, device, scratch
        ctx.shapes = [x.shape for x in (means, quats, scales, opacities, sh_dc, sh_rest)]
        ctx.mark_non_differentiable(radii)
        ctx.set_materialize_grads(False)  # outputs without a gradient come as None (zeros made below, none for radii)
        return (*[o.view(H, W) if o.dim() == 1 else o.view(H, W, 3) for o in outs], radii)

    @staticmethod
    def backward(ctx, g_rgb, g_alpha, g_accum, g_median, g_normal, g_dist, _g_radii):
        state, stats = ctx.state, ctx.stats
        if state is None:
            raise RuntimeError("gof_warp.rendering.render: backward called twice through the same render (retain_graph is not supported)")
        device = ctx.device
        num_pixels = state.cam.height * state.cam.width
        flat = []
        for g, t in zip((g_rgb, g_alpha, g_accum, g_median, g_normal, g_dist), ctx.types):
            shape = (num_pixels, 3) if t is wp.vec3 else (num_pixels,)
            flat.append(torch.zeros(shape, dtype=torch.float32, device=device) if g is None else g.reshape(shape).float().contiguous())
        grad_in = [torch.zeros(s, dtype=torch.float32, device=device) for s in ctx.shapes]
        pool = None if ctx.scratch is None else ctx.scratch.pool
        with _stream_scope(device, ctx.scratch):
            grad_out = RenderOutputs(*[_wp(g, t) for g, t in zip(flat, ctx.types)])
            wp_in = tuple(_wp(g, t, launch_only=True) for g, t in zip(grad_in, _PARAM_TYPES))
            g2d = g2abs = None
            if stats is not None:
                g2d, g2abs = _wp(stats.grad2d, wp.vec2, launch_only=True), _wp(stats.grad2d_abs)
            render_backward(state, grad_out, (*wp_in[:4], tuple(wp_in[4:])), g2d, g2abs, zeroed=True, pool=pool)
            if pool is not None:  # inside the scope: the pool files them under the stream they were used on
                pool.give(*state.scratch)
        ctx.state = None  # the forward state is not used after this
        return (*grad_in, None, None, None, None, None, None, None)


def _check_params(means, quats, scales, opacities, sh, check_values: bool = True):
    """Shapes, dtypes and devices of the activated parameters (clear ``ValueError``s).

    Returns ``(sh_dc [N, 3], sh_rest [N, K−1, 3])``: ``sh`` as given if it is that pair, else two views of the
    ``[N, K, 3]`` tensor (the autograd graph runs through them)."""
    if isinstance(sh, (tuple, list)):
        if len(sh) != 2:
            raise ValueError(f"rasterize: sh must be an [N, K, 3] tensor or a pair (sh_dc, sh_rest), got {len(sh)} tensors")
        sh_dc, sh_rest = sh
    elif isinstance(sh, torch.Tensor):
        if sh.dim() != 3 or sh.shape[1] < 1:
            raise ValueError(f"rasterize: sh must have shape [N, K, 3], got {list(sh.shape)}")
        sh_dc, sh_rest = sh[:, 0], sh[:, 1:]
    else:
        raise TypeError(f"rasterize: sh must be a torch.Tensor or a pair of them, got {type(sh).__name__}")
    params = dict(zip(_PARAM_NAMES, (means, quats, scales, opacities, sh_dc, sh_rest)))
    for name, x in params.items():
        if not isinstance(x, torch.Tensor):
            raise TypeError(f"rasterize: {name} must be a torch.Tensor, got {type(x).__name__}")
        if x.dtype != torch.float32:
            raise ValueError(f"rasterize: {name} must be float32, got {x.dtype}")
        if x.device != means.device:
            raise ValueError(f"rasterize: {name} is on {x.device} but means is on {means.device}")
    n = means.shape[0] if means.dim() == 2 else -1
    expected = dict(means=(n, 3), quats=(n, 4), scales=(n, 3), opacities=(n,), sh_dc=(n, 3))
    for name, shape in expected.items():
        if tuple(params[name].shape) != shape or n < 0:
            raise ValueError(f"rasterize: {name} must have shape {list(shape)} (N={n}), got {list(params[name].shape)}")
    if sh_rest.dim() != 3 or sh_rest.shape[0] != n or sh_rest.shape[2] != 3 or sh_rest.shape[1] + 1 not in (1, 4, 9, 16):
        raise ValueError(f"rasterize: sh must have shape [N, K, 3] (sh_rest [N, K-1, 3]) with N={n} and K in (1, 4, 9, 16), "
                         f"got sh_rest {list(sh_rest.shape)}")
    if check_values and n > 0 and not bool((scales > 0).all()):  # reads a flag back: a GPU sync
        raise ValueError("rasterize: scales must be positive (activated)")
    return sh_dc, sh_rest


def rasterize(means, quats, scales, opacities, sh, camera: Camera, *, sh_degree=None, config=None, stats=None,
              check_values: bool = True, tile_lists: TileListSizer | None = None,
              scratch: RenderScratch | None = None) -> dict:
    """Render activated Gaussian parameters from ``camera`` (differentiable w.r.t. every tensor).

    Args:
        means: ``[N, 3]`` world-space centres. quats: ``[N, 4]`` unit quaternions, wxyz (used as
            given). scales: ``[N, 3]`` positive. opacities: ``[N]`` in (0, 1). sh: ``[N, K, 3]`` SH
            coefficients, ``K = (D+1)²``, D ≤ 3, or the pair ``(sh_dc [N, 3], sh_rest [N, K−1, 3])`` as a model
            keeps them (no concatenation per render). All float32 on one device (CPU or CUDA).
        camera: :class:`gof_warp.core.camera.Camera`.
        sh_degree: active SH degree (default: the maximum ``sh`` holds).
        config: :class:`RenderConfig` (default thresholds of GOF).
        stats: optional :class:`DensifyStats` filled by this render's forward and backward.
        check_values: check that the scales are positive (one device-to-host read; :func:`render` skips it: a
            model's activated scales are positive by construction).
        tile_lists: a :class:`~gof_warp.kernels.binning.TileListSizer` kept across renders (a training loop's):
            the tile lists are sized from earlier renders' counts instead of reading this one's back, so the host
            need not wait for the GPU. ``None``: exact sizing (one device-to-host read per render).
        scratch: a :class:`RenderScratch` kept across renders (a training loop's): scratch arrays, structs and stream
            wrappers of earlier renders are reused, which spares host time; same results. ``None``: all made anew.

    Returns:
        dict of ``[H, W]``/``[H, W, 3]`` float32 tensors: ``rgb``, ``alpha`` (1 − T), ``depth`` (expected
        depth Σwt*/alpha, 0 where alpha = 0), ``accum_depth`` (Σwt*), ``median_depth``, ``normal``
        (Σw n̂, camera space, not renormalised), ``distortion``; plus ``radii`` ``[N]`` int32 (not
        differentiable).
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"rasterize: camera must be a gof_warp.core.camera.Camera, got {type(camera).__name__}")
    config = RenderConfig() if config is None else config
    if not isinstance(config, RenderConfig):
        raise TypeError(f"rasterize: config must be a RenderConfig, got {type(config).__name__}")
    config.validate()
    sh_dc, sh_rest = _check_params(means, quats, scales, opacities, sh, check_values)
    num_coeffs = sh_rest.shape[1] + 1
    max_degree = int(round(math.sqrt(num_coeffs))) - 1
    sh_degree = max_degree if sh_degree is None else int(sh_degree)
    if not 0 <= sh_degree <= max_degree:
        raise ValueError(f"rasterize: sh_degree {sh_degree} not in [0, {max_degree}] for sh with K={num_coeffs}")
    if stats is not None:
        if not isinstance(stats, DensifyStats):
            raise TypeError(f"rasterize: stats must be a DensifyStats, got {type(stats).__name__}")
        if len(stats) != means.shape[0] or stats.grad2d.device != means.device:
            raise ValueError(f"rasterize: stats holds {len(stats)} Gaussians on {stats.grad2d.device}, need {means.shape[0]} on {means.device}")
    if tile_lists is not None and not isinstance(tile_lists, TileListSizer):
        raise TypeError(f"rasterize: tile_lists must be a TileListSizer, got {type(tile_lists).__name__}")
    differentiable = True
    if scratch is None:
        cam, settings = camera_params_from(camera), raster_settings_for(camera, config)
    elif isinstance(scratch, RenderScratch):
        cam, settings = scratch.view_structs(camera, config)
        # whether autograd will record the render: if not, no backward comes to give its arrays back
        differentiable = torch.is_grad_enabled() and any(
            x.requires_grad for x in (means, quats, scales, opacities, sh_dc, sh_rest))
    else:
        raise TypeError(f"rasterize: scratch must be a RenderScratch, got {type(scratch).__name__}")
    rgb, alpha, accum, median, normal, dist, radii = _RasterizeFunction.apply(
        means, quats, scales, opacities, sh_dc, sh_rest, cam, settings, sh_degree, stats, tile_lists, scratch,
        differentiable)
    seen = alpha > 0
    depth = torch.where(seen, accum / torch.where(seen, alpha, 1.0), 0.0)
    return dict(rgb=rgb, alpha=alpha, depth=depth, accum_depth=accum, median_depth=median, normal=normal, distortion=dist, radii=radii)


def render(gaussians, camera: Camera, *, config=None, stats=None, sh_degree=None, tile_lists=None,
           scratch=None) -> dict:
    """Render a Gaussian model (any object with activated ``means``, ``rotations`` (unit wxyz),
    ``scales``, ``opacities``, ``active_sh_degree`` and either ``sh_dc``/``sh_rest`` or ``sh``, e.g.
    ``gof_warp.core.model.Gaussians``, whose two SH parameters are read as they are, without concatenating them).

    The activations are torch ops on the raw parameters, so gradients reach the raw parameters
    (log-scales, opacity logits, unnormalised quaternions) by torch's chain rule. ``sh_degree``
    overrides ``gaussians.active_sh_degree``; ``tile_lists``, ``scratch``: see :func:`rasterize`. See :func:`rasterize`
    for the outputs.
    """
    # each attribute read once: the activated parameters are computed on every access (torch ops and autograd nodes)
    model = {attr: getattr(gaussians, attr, _MISSING) for attr in _MODEL_ATTRS}
    for attr, value in model.items():
        if value is _MISSING:
            raise TypeError(f"render: gaussians has no attribute {attr!r} (expected a gof_warp.core.model.Gaussians)")
    sh = (getattr(gaussians, "sh_dc", _MISSING), getattr(gaussians, "sh_rest", _MISSING))
    if sh[0] is _MISSING or sh[1] is _MISSING:
        sh = getattr(gaussians, "sh", _MISSING)
        if sh is _MISSING:
            raise TypeError("render: gaussians has neither 'sh_dc'/'sh_rest' nor 'sh' "
                            "(expected a gof_warp.core.model.Gaussians)")
    degree = model["active_sh_degree"] if sh_degree is None else sh_degree
    return rasterize(model["means"], model["rotations"], model["scales"], model["opacities"], sh, camera,
                     sh_degree=degree, config=config, stats=stats, check_values=False, tile_lists=tile_lists,
                     scratch=scratch)  # fmt: skip
