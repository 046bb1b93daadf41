"""The GOF opacity field baked into a sparse Warp volume (NanoVDB), for queries from inside any Warp kernel.

:func:`bake_opacity_volume` evaluates the exact field (:func:`gof_warp.rendering.opacity_field.opacity_field`) on a
lattice of voxel size ``h`` and stores it in a float ``wp.Volume`` — only where it matters:

1. **Bounds**: the 3σ boxes of the opaque Gaussians (opacity ≥ ``opacity_min``), the outer
   ``bounds_percentile`` % per side dropped (far stragglers), padded by the band.
2. **Coarse pass**: the field at every ``coarse_step``-th voxel corner of the bounds (points no camera sees,
   :func:`gof_warp.mesh.tetra.frustum_mask`, are not evaluated). A brick (NanoVDB leaf, 8³ voxels) is kept when
   some camera sees it and its coarse samples straddle ``level`` or come within ``margin`` of it.
3. **Band**: kept bricks are dilated by ``ceil((band + 1) / 8)`` bricks, so every point within ``band``
   voxels of a detected crossing has its whole trilinear stencil stored.
4. **Fine pass**: the exact field at every voxel of the kept bricks (float32), batch by batch.

Everything else reads the background value 0 ("empty"). Voxels that no camera sees store ``unseen_value``
(default 0, empty, unlike GOF's meshing convention of 1: a volume is queried anywhere, and an unseen
"solid" would be a wall at the edge of the frusta).

Voxel index ``(i, j, k)`` sits at world ``origin + h · (i, j, k)`` (voxel centres at integer index
coordinates); in a kernel ``wp.volume_sample_f(vol, wp.volume_world_to_index(vol, x), wp.Volume.LINEAR)``
returns the trilinear interpolation of the stored values. Error and memory: ``docs/warp_volume.md``.

Memory bound: the coarse lattice holds at most ``max_coarse_samples`` values on the host, the volume at most
``max_voxels`` voxels (4 B each plus ~1/8 of that in tree nodes and a fixed ~0.3 MB); the fine pass evaluates
``batch_bricks × 512`` points at a time.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import struct
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
import warp as wp

from ..core.camera import Camera
from ..core.devices import warp_device
from ..core.errors import GofError
from ..core.io_utils import atomic_path, write_bytes_atomic
from ..kernels import volume as vk
from ..rendering.opacity_field import OpacityFieldConfig, opacity_field
from ..rendering.render import RenderConfig
from .tetra import frustum_mask

log = logging.getLogger(__name__)

BRICK = 8  # NanoVDB leaf edge in voxels: the unit of allocation
SIGMA_EXTENT = 3.0  # a Gaussian's extent is SIGMA_EXTENT × its largest standard deviation


@dataclass
class VolumeConfig:
    """Settings of :func:`bake_opacity_volume` (the voxel size and the band are its keyword arguments).

    Attributes:
        level: the surface level of the opacity field (GOF: 0.5).
        margin: a brick is kept when its coarse samples come within ``margin`` of ``level`` (or straddle it).
        coarse_step: voxels between coarse samples; divides 8.
        opacity_min: Gaussians at least this opaque set the bounds and the voxel size.
        extent_percentile: the derived voxel size is this percentile of the opaque Gaussians' 3σ extents ...
        voxels_per_extent: ... divided by this.
        bounds_percentile: per axis, this percentage of the opaque Gaussians on each side is left outside.
        max_voxels: budget of stored voxels; a derived voxel size grows until it fits, a given one raises.
        max_coarse_samples: budget of the coarse lattice (same rule).
        unseen_value: value stored at voxels no camera sees.
        batch_bricks: bricks evaluated per call of the field in the fine pass.
    """

    level: float = 0.5
    margin: float = 0.2
    coarse_step: int = 4
    opacity_min: float = 0.5
    extent_percentile: float = 50.0
    voxels_per_extent: float = 4.0
    bounds_percentile: float = 0.5
    max_voxels: int = 1 << 25
    max_coarse_samples: int = 1 << 24
    unseen_value: float = 0.0
    batch_bricks: int = 4096

    def validate(self) -> "VolumeConfig":
        if not 0.0 < self.level < 1.0:
            raise GofError(f"volume level must be in (0, 1), got {self.level}")
        if not 0.0 <= self.margin < 1.0:
            raise GofError(f"volume margin must be in [0, 1), got {self.margin}")
        if self.coarse_step not in (1, 2, 4, 8):
            raise GofError(f"volume coarse_step must be 1, 2, 4 or 8 voxels, got {self.coarse_step}")
        if not 0.0 < self.extent_percentile <= 100.0 or not 0.0 <= self.bounds_percentile < 50.0:
            raise GofError("volume extent_percentile must be in (0, 100] and bounds_percentile in [0, 50)")
        if self.voxels_per_extent <= 0 or self.max_voxels < BRICK ** 3 or self.max_coarse_samples < 8:
            raise GofError("volume voxels_per_extent must be > 0, max_voxels >= 512, max_coarse_samples >= 8")
        if self.batch_bricks < 1:
            raise GofError(f"volume batch_bricks must be >= 1, got {self.batch_bricks}")
        return self


def derive_voxel_size(gaussians, config: VolumeConfig | None = None) -> float:
    """The voxel size rule: ``percentile(3 · max σ, extent_percentile) / voxels_per_extent`` over the opaque
    Gaussians (all Gaussians when none is opaque), in world units. The budgets may enlarge it later."""
    config = (config or VolumeConfig()).validate()
    if len(gaussians) == 0:
        raise GofError("cannot bake an opacity volume of a model with no Gaussians")
    ext, _, _ = _opaque_extents(gaussians, config)
    h = float(np.percentile(ext, config.extent_percentile)) / config.voxels_per_extent
    if not (math.isfinite(h) and h > 0):
        raise GofError(f"the Gaussians give no usable voxel size ({h}); pass voxel_size")
    return h


def _opaque_extents(gaussians, config):
    """``(3σ extents [K], means [K, 3])`` of the opaque Gaussians (float64 numpy) and how many are opaque."""
    s = gaussians.scales.detach().double().cpu().numpy()
    m = gaussians.means.detach().double().cpu().numpy()
    o = gaussians.opacities.detach().double().cpu().numpy().reshape(-1)
    keep = o >= config.opacity_min
    n_opaque = int(keep.sum())
    if n_opaque == 0:
        keep = np.ones_like(keep)
    return SIGMA_EXTENT * s[keep].max(axis=1), m[keep], n_opaque


def _bounds(gaussians, config):
    """World box ``(lo [3], hi [3])`` of the opaque Gaussians' 3σ boxes, outer percentiles dropped."""
    ext, m, _ = _opaque_extents(gaussians, config)
    lo_pts, hi_pts = m - ext[:, None], m + ext[:, None]
    p = config.bounds_percentile
    lo = np.percentile(lo_pts, p, axis=0) if p > 0 else lo_pts.min(axis=0)
    hi = np.percentile(hi_pts, 100.0 - p, axis=0) if p > 0 else hi_pts.max(axis=0)
    return lo, hi


def _window_reduce(a: np.ndarray, r: int, nb: tuple, fn) -> np.ndarray:
    """Per brick, ``fn``-reduce the ``(r + 1)³`` coarse samples of its closed cell (separable)."""
    for axis in range(3):
        parts = [np.take(a, np.arange(o, o + r * nb[axis], r), axis=axis) for o in range(r + 1)]
        a = fn.reduce(parts)
    return a


def _dilate(mask: np.ndarray, d: int) -> np.ndarray:
    """Boolean dilation by ``d`` cells along each axis (a cube of side ``2d + 1``)."""
    for axis in range(3):
        out = mask.copy()
        n = mask.shape[axis]
        for s in range(1, d + 1):
            if s >= n:
                break
            lo = [slice(None)] * 3
            hi = [slice(None)] * 3
            lo[axis], hi[axis] = slice(0, n - s), slice(s, n)
            out[tuple(lo)] |= mask[tuple(hi)]
            out[tuple(hi)] |= mask[tuple(lo)]
        mask = out
    return mask


def _field(gaussians, cameras, pts, render_config, config):
    """Exact field at ``pts`` ([M, 3] float32 torch), ``unseen_value`` where no view sees the point."""
    f, seen = opacity_field(gaussians, cameras, pts, render_config=render_config, return_seen=True,
                            config=OpacityFieldConfig(unseen_value=config.unseen_value))
    return torch.where(seen > 0, f, torch.full_like(f, config.unseen_value))


def _coarse_pass(gaussians, cameras, h, origin, nb, render_config, config):
    """``(keep [nb], seen [nb], samples)``: bricks near the level, bricks some camera sees, samples taken."""
    r = BRICK // config.coarse_step
    ns = tuple(n * r + 1 for n in nb)
    dev = gaussians.device
    axes = [torch.arange(n, dtype=torch.float64, device=dev) * (config.coarse_step * h) + float(origin[i])
            for i, n in enumerate(ns)]
    grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    inside = frustum_mask(grid, cameras, render_config.near, 1e30)
    values = torch.full((grid.shape[0],), config.unseen_value, dtype=torch.float32, device=dev)
    if bool(inside.any()):
        values[inside] = _field(gaussians, cameras, grid[inside].float(), render_config, config)
    vals = values.cpu().numpy().reshape(ns)
    seen = _window_reduce(inside.cpu().numpy().reshape(ns), r, nb, np.logical_or)
    lo = _window_reduce(vals, r, nb, np.minimum)
    hi = _window_reduce(vals, r, nb, np.maximum)
    near_level = (lo <= config.level + config.margin) & (hi >= config.level - config.margin)
    return near_level & seen, seen, int(inside.sum())


def _torch_ordered(device: torch.device):
    """On CUDA, launch Warp kernels on torch's current stream (torch fields and stores stay ordered)."""
    if device.type != "cuda":
        return contextlib.nullcontext()
    return wp.ScopedStream(wp.stream_from_torch(device))


def _fine_pass(gaussians, cameras, h, origin, bricks, wdev, render_config, config) -> wp.Volume:
    """Allocate the kept bricks ``[B, 3]`` (brick coordinates) and fill every voxel with the exact field."""
    volume = wp.Volume.allocate_by_tiles(wp.array(bricks * BRICK, dtype=wp.vec3i, device=wdev), voxel_size=h,
                                         bg_value=0.0, translation=tuple(float(v) for v in origin), device=wdev)
    local = np.stack(np.meshgrid(*[np.arange(BRICK, dtype=np.int32)] * 3, indexing="ij"), -1).reshape(-1, 3)
    origin_t = torch.as_tensor(origin, dtype=torch.float64, device=gaussians.device)
    for start in range(0, len(bricks), config.batch_bricks):
        ijk = (bricks[start:start + config.batch_bricks, None, :] * BRICK + local[None]).reshape(-1, 3)
        ijk_t = torch.as_tensor(ijk, device=gaussians.device).contiguous()
        pts = (origin_t + h * ijk_t.double()).float()
        vals = _field(gaussians, cameras, pts, render_config, config).contiguous()
        wp.launch(vk.store_voxels, dim=len(ijk), device=wdev,
                  inputs=[volume.id, wp.from_torch(ijk_t, dtype=wp.vec3i), wp.from_torch(vals)])
    wp.synchronize_device(wdev)
    return volume


def bake_opacity_volume(gaussians, cameras: Sequence[Camera], *, voxel_size: float | None = None, band: int = 4,
                        render_config: RenderConfig | None = None, config: VolumeConfig | None = None):
    """Bake the GOF opacity field into a sparse float ``wp.Volume`` on the Gaussians' device.

    Args:
        gaussians: :class:`~gof_warp.core.model.Gaussians` (activated values; the 3D filter applies).
        cameras: the views the field is a minimum over (normally the training cameras).
        voxel_size: voxel edge in world units; ``None``: :func:`derive_voxel_size`, enlarged to fit the budgets.
        band: voxels on each side of a detected level crossing whose trilinear samples are exact-stencil.
        render_config: near plane and compositing thresholds of the field (as rendering).
        config: :class:`VolumeConfig`.

    Returns:
        ``(volume, info)``: the ``wp.Volume`` (float32, background 0) and a JSON-ready dict: ``voxel_size``,
        ``origin`` (world position of voxel (0, 0, 0)), ``active_voxels``, ``bricks``, ``bytes`` (NanoVDB
        buffer), ``bounds_min``/``bounds_max`` (world box of the stored voxels), ``coarse_samples``,
        ``fine_samples``, ``dense_voxels`` (the scene box's lattice), per-stage ``time_s`` and the settings used.

    Raises:
        GofError: no Gaussians or cameras, a bad size or band, or a given voxel size over the voxel budget.
    """
    t0 = time.perf_counter()
    config = (config or VolumeConfig()).validate()
    render_config = render_config or RenderConfig()
    render_config.validate()
    if not cameras:
        raise GofError("baking an opacity volume needs at least one camera")
    if len(gaussians) == 0:
        raise GofError("cannot bake an opacity volume of a model with no Gaussians")
    if not isinstance(band, (int, np.integer)) or band < 0:
        raise GofError(f"band must be a non-negative number of voxels, got {band!r}")
    given = voxel_size is not None
    if given:
        h = float(voxel_size)
        if not (math.isfinite(h) and h > 0):
            raise GofError(f"voxel_size must be a positive finite length, got {voxel_size!r}")
    else:
        h = derive_voxel_size(gaussians, config)
    h_rule = h
    lo, hi = _bounds(gaussians, config)
    dilate = math.ceil((band + 1) / BRICK)
    for _attempt in range(8):
        pad = (dilate * BRICK + config.coarse_step) * h
        origin = lo - pad
        nb = tuple(int(max(1, math.ceil(e))) for e in (hi + pad - origin) / (BRICK * h))
        n_coarse = math.prod(n * (BRICK // config.coarse_step) + 1 for n in nb)
        if n_coarse > config.max_coarse_samples:
            if given:
                raise GofError(f"voxel_size {h:g} needs {n_coarse:,} coarse samples over the scene box "
                               f"(budget {config.max_coarse_samples:,}): choose a larger voxel size")
            h *= 1.05 * (n_coarse / config.max_coarse_samples) ** (1 / 3)
            continue
        t_c = time.perf_counter()
        with _torch_ordered(gaussians.device):
            near, seen, coarse_evaluated = _coarse_pass(gaussians, cameras, h, origin, nb, render_config, config)
        t_coarse = time.perf_counter() - t_c
        keep = _dilate(near, dilate) & seen
        n_vox = int(keep.sum()) * BRICK ** 3
        if n_vox <= config.max_voxels:
            break
        if given:
            raise GofError(f"voxel_size {h:g} needs {n_vox:,} voxels (budget {config.max_voxels:,}): choose a "
                           "larger voxel size or raise max_voxels")
        h *= 1.05 * math.sqrt(n_vox / config.max_voxels)  # the band is a surface: count ∝ h⁻²
    else:
        raise GofError("could not fit the opacity volume into its budgets; pass a larger voxel_size")
    bricks = np.argwhere(keep).astype(np.int32)
    if len(bricks) == 0:
        raise GofError("the opacity field crosses its level nowhere that a camera sees: nothing to bake")
    wdev = warp_device(gaussians.device)
    t_f = time.perf_counter()
    with _torch_ordered(gaussians.device):
        volume = _fine_pass(gaussians, cameras, h, origin, bricks, wdev, render_config, config)
    t_fine = time.perf_counter() - t_f
    lo_idx, hi_idx = bricks.min(axis=0) * BRICK, (bricks.max(axis=0) + 1) * BRICK - 1
    info = {
        "voxel_size": h, "voxel_size_rule": h_rule, "voxel_size_given": given, "origin": origin.tolist(),
        "active_voxels": int(volume.get_voxel_count()), "bricks": len(bricks), "bytes": int(volume.array().shape[0]),
        "bounds_min": (origin + h * lo_idx).tolist(), "bounds_max": (origin + h * hi_idx).tolist(),
        "coarse_samples": n_coarse, "coarse_evaluated": coarse_evaluated, "fine_samples": len(bricks) * BRICK ** 3,
        "dense_voxels": math.prod(nb) * BRICK ** 3,
        "band": int(band), "background": 0.0, "n_gaussians": len(gaussians), "n_cameras": len(cameras),
        "time_s": {"coarse": t_coarse, "fine": t_fine, "total": time.perf_counter() - t0},
        "config": asdict(config),
    }
    log.info("opacity volume: h=%.4g, %d bricks, %d voxels, %.1f MB, %.1f s", h, len(bricks),
             info["active_voxels"], info["bytes"] / 1e6, info["time_s"]["total"])
    return volume, info


def sample_volume(volume: wp.Volume, points) -> np.ndarray:
    """``[M]`` float32: trilinear samples of a float volume at world ``points`` (``[M, 3]``, numpy)."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float32))
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise GofError(f"points must be [M, 3], got {list(pts.shape)}")
    out = wp.zeros(len(pts), dtype=wp.float32, device=volume.device)
    if len(pts):
        wp.launch(vk.sample_volume_world, dim=len(pts), device=volume.device,
                  inputs=[volume.id, wp.array(pts, dtype=wp.vec3, device=volume.device)], outputs=[out])
    return out.numpy()


def save_volume(volume_or_grid, path) -> Path:
    """Write a ``wp.Volume`` (or the bytes / ``wp.array`` of a NanoVDB grid) as ``.nvdb``, atomically.

    The file is loadable with ``wp.Volume.load_from_nvdb(open(path, "rb"))`` (uncompressed codec)."""
    path = Path(path)
    volume = volume_or_grid
    if isinstance(volume_or_grid, (bytes, bytearray, memoryview, np.ndarray)):
        data = np.frombuffer(bytes(volume_or_grid), dtype=np.uint8)
        volume = wp.Volume(wp.array(data, dtype=wp.uint8, device="cpu"))
    elif isinstance(volume_or_grid, wp.array):
        volume = wp.Volume(volume_or_grid)
    if not isinstance(volume, wp.Volume):
        raise GofError(f"save_volume needs a wp.Volume or NanoVDB grid bytes, got {type(volume_or_grid).__name__}")
    with atomic_path(path) as tmp:
        volume.save_to_nvdb(str(tmp))
    return path


def load_volume(path, device=None) -> wp.Volume:
    """A ``wp.Volume`` from an ``.nvdb`` file, with a clear error for a missing or foreign file."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            return wp.Volume.load_from_nvdb(f, device=device)
    except OSError as e:
        raise GofError(f"cannot read {path}: {e.strerror or e}") from None
    except (RuntimeError, ValueError, IndexError, struct.error) as e:  # bad magic, short file, bad tree
        raise GofError(f"{path} is not a NanoVDB volume: {e}") from None


def bake_run(run_dir_or_ply, scene: str | None = None, out_path=None, voxel_size: float | None = None,
             band: int = 4, device: str | None = None, config: VolumeConfig | None = None) -> dict:
    """Bake a run's opacity field and write ``.nvdb`` plus its info JSON beside it; return the info.

    Args:
        run_dir_or_ply: a run folder (``point_cloud.ply``, ``cameras.json``, ``config.yaml``) or a Gaussian PLY.
        scene: the scene folder the PLY was trained on (cameras), as ``extract --scene``.
        out_path: the ``.nvdb`` to write; default ``RUN/opacity_volume.nvdb`` (or ``PLY`` with suffix ``.nvdb``).
        voxel_size, band, config: see :func:`bake_opacity_volume`.
        device: torch device name (``None``/``"auto"``: the devices rule of :mod:`gof_warp.core.devices`).
    """
    from ..core.devices import resolve_device
    from ..training.run_folder import load_run

    run = Path(run_dir_or_ply)
    gaussians, cameras, _views, render_config = load_run(run, scene, resolve_device(device))
    volume, info = bake_opacity_volume(gaussians, cameras, voxel_size=voxel_size, band=band,
                                       render_config=render_config, config=config)
    if out_path is None:
        out_path = run / "opacity_volume.nvdb" if run.is_dir() else run.with_suffix(".nvdb")
    out_path = save_volume(volume, out_path)
    info["nvdb"] = str(out_path)
    info["file_bytes"] = out_path.stat().st_size
    write_bytes_atomic(out_path.with_suffix(".json"), (json.dumps(info, indent=2) + "\n").encode())
    return info
