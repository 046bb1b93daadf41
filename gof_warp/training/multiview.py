"""Multi-view photometric consistency: the rendered surface must look the same from a neighbouring photo.

A regulariser used by planar-Gaussian surface methods (PGSR and its successors) and not part of GOF. The colour
loss compares each view's render with its own photo only, so where one or two cameras see a surface the
Gaussians can sit anywhere along their rays that keeps each photo's colours. This term ties the rendered
geometry to a second photo directly:

* At ``P`` random pixels ``p`` of the reference view ``r``, the rendered **median depth** ``D(p)`` and normal
  ``n(p)`` (camera space) define a local plane ``nᵀX = ρ`` with ``ρ = nᵀ D(p) K⁻¹p̃`` (z-depth, pixel centres at
  ``i + ½``).
* A ``s × s`` patch of pixels ``q`` around ``p`` is cast onto that plane, ``X_q = ρ / (nᵀ K⁻¹q̃) · K⁻¹q̃``, and
  projected into a neighbour view ``m``: the plane-induced homography ``H = K_m (R_rel − t_rel nᵀ/ρ) K_r⁻¹``,
  written out as cast-then-project.
* The loss of a patch is ``1 − NCC`` between the reference photo's grey values at ``q`` and the neighbour photo's at
  the projected points (bilinear): 0 when the plane carries the reference patch onto the same texture in the
  neighbour. NCC ignores gain and offset, so exposure changes between photos cost nothing.
* A patch counts only where it is informative and its neighbour sees it: reference alpha above ``alpha_min`` at
  ``p``, every projected point in front of the neighbour and inside its image, a textured reference patch (grey
  standard deviation above ``min_std``), and not occluded in the neighbour — the plane's point farther than
  ``(1 + occlusion_tolerance)`` × the neighbour's own last rendered median depth there is hidden behind
  something else (the depth comes from when that view was last trained on, so no second render is needed).
  The test is one-sided: a surface rendered more than ``occlusion_tolerance`` behind where the neighbour renders it
  looks hidden and gets no pull from this term (only one rendered in front of it, or within the tolerance, does).
* Each step compares a view with ``neighbours_per_step`` of its candidate neighbours (one, as PGSR, by default). A
  patch's loss is the mean over the drawn neighbours it counts for, and the term the mean over the patches that
  count for at least one: a surface near the edge of a capture, which only one or two of the candidates see, is then
  compared whenever one of those is drawn, not only when it is the one.

The gradient reaches ``D(p)`` and ``n(p)`` through the projected coordinates (the neighbour photo's spatial
gradient), and so the Gaussians through the renderer's median-depth and normal outputs.

Neighbours (:func:`neighbour_views`): for each training camera, the ``k`` nearest camera centres among the cameras
whose viewing directions lie within ``max_angle_deg`` of its own.

Shapes: images are channel-last ``[H, W, 3]`` in ``[0, 1]`` (grey ``[H, W]``); depth ``[H, W]``; normals
``[H, W, 3]``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import torch

from ..core.camera import Camera
from ..core.config import ConfigError
from ..core.errors import GofError, error_summary

log = logging.getLogger(__name__)

_SALT = 0x6D76  # keeps the term's draws apart from other per-(seed, iteration, view) draws (random backgrounds)

GREY_WEIGHTS = (0.299, 0.587, 0.114)  # ITU-R BT.601 luma


@dataclass
class MultiViewConfig:
    """Settings of the multi-view photometric term (``experimental.multiview`` in a training config). ``weight`` 0 (default) is off.

    Attributes:
        weight: λ of the term in the loss (PGSR uses 0.15 for its photometric part).
        from_iter: first iteration it acts (PGSR's multi-view terms start at 7,000; GOF's regularisers at 15,000).
        pixels: patch centres sampled per view and step.
        patch: patch side in pixels (odd).
        neighbours: candidate neighbours per view.
        neighbours_per_step: how many of them are drawn per view and step (without replacement; at most
            ``neighbours``). Each patch's loss is the mean ``1 − NCC`` over the drawn neighbours that see it, so a
            surface that only one or two of the candidates see (the edge of a capture) is compared at every step
            where one of those is drawn. 1 (PGSR's choice, the default): one neighbour per step; more cost time a
            step and moved far surfaces (measured: see benchmarks/RESULTS.md).
        max_angle_deg: neighbours' viewing directions within this angle of the reference's.
        alpha_min: reference alpha at the patch centre below which the patch is left out.
        min_std: reference patches whose grey standard deviation is below this are textureless: left out.
        occlusion_tolerance: relative depth margin of the occlusion test.
    """

    weight: float = 0.0
    from_iter: int = 7_000
    pixels: int = 4096
    patch: int = 7
    neighbours: int = 8
    neighbours_per_step: int = 1
    max_angle_deg: float = 45.0
    alpha_min: float = 0.5
    min_std: float = 0.01
    occlusion_tolerance: float = 0.05

    def __post_init__(self):
        if not (self.weight >= 0 and math.isfinite(self.weight)):
            raise ConfigError(f"experimental.multiview.weight must be a finite number >= 0, got {self.weight!r}")
        if int(self.patch) != self.patch or self.patch < 3 or self.patch % 2 == 0:
            raise ConfigError(f"experimental.multiview.patch must be an odd integer >= 3, got {self.patch!r}")
        if self.pixels < 1 or self.neighbours < 1 or self.neighbours_per_step < 1:
            raise ConfigError("experimental.multiview: pixels, neighbours and neighbours_per_step must be >= 1")
        if self.neighbours_per_step > self.neighbours:
            raise ConfigError(f"experimental.multiview.neighbours_per_step ({self.neighbours_per_step}) must be at most "
                           f"neighbours ({self.neighbours})")
        if not 0.0 < self.max_angle_deg <= 180.0:
            raise ConfigError(f"experimental.multiview.max_angle_deg must be in (0, 180], got {self.max_angle_deg!r}")
        if self.min_std < 0 or self.occlusion_tolerance < 0 or not 0.0 <= self.alpha_min < 1.0:
            raise ConfigError("experimental.multiview: min_std and occlusion_tolerance must be >= 0, alpha_min in [0, 1)")

    @property
    def on(self) -> bool:
        return self.weight > 0


def grey(image: torch.Tensor) -> torch.Tensor:
    """``[H, W]`` luma of a channel-last ``[H, W, 3]`` image."""
    if image.ndim != 3 or image.shape[-1] != 3:
        raise GofError(f"grey: expected a channel-last [H, W, 3] image, got {list(image.shape)}")
    w = torch.tensor(GREY_WEIGHTS, dtype=image.dtype, device=image.device)
    return image @ w


def neighbour_views(cameras, k: int, max_angle_deg: float) -> list[list[int]]:
    """For each camera, the indices of up to ``k`` other cameras with the nearest centres among those whose
    viewing direction (the camera's +z axis) lies within ``max_angle_deg`` of its own; ``[]`` for a camera that has
    none. Camera pairs at the same centre (no baseline, no parallax) are never neighbours."""
    if len(cameras) == 0:
        return []
    centres = np.stack([c.center for c in cameras])
    axes = np.stack([np.asarray(c.R, np.float64)[2] for c in cameras])
    dist = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    cos = np.clip(axes @ axes.T, -1.0, 1.0)
    allowed = (cos >= math.cos(math.radians(max_angle_deg))) & (dist > 1e-9 * max(float(dist.max()), 1e-30))
    out = []
    for i in range(len(cameras)):
        cand = np.flatnonzero(allowed[i])
        out.append(cand[np.argsort(dist[i, cand], kind="stable")][:k].tolist())
    return out


def _relative_pose_np(ref: Camera, nbr: Camera) -> np.ndarray:
    """``[R_rel.ravel(), t_rel]`` (12 floats, float64): the pose taking reference camera coordinates to the
    neighbour's, ``R_rel = R_nbr R_refᵀ``, ``t_rel = t_nbr − R_rel t_ref``."""
    r_ref, r_nbr = np.asarray(ref.R, np.float64), np.asarray(nbr.R, np.float64)
    rot = r_nbr @ r_ref.T
    return np.concatenate([rot.reshape(-1), np.asarray(nbr.t, np.float64) - rot @ np.asarray(ref.t, np.float64)])


def _relative_pose(ref: Camera, nbr: Camera, dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
    """``(R_rel [3, 3], t_rel [3])`` of :func:`_relative_pose_np` as tensors."""
    row = torch.tensor(_relative_pose_np(ref, nbr), dtype=dtype, device=device)
    return row[:9].view(3, 3), row[9:]


def patch_offsets(patch: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """``[s·s, 2]`` integer pixel offsets ``(du, dv)`` of an ``s × s`` patch around its centre, row-major."""
    r = patch // 2
    d = torch.arange(-r, r + 1, dtype=dtype, device=device)
    dv, du = torch.meshgrid(d, d, indexing="ij")
    return torch.stack([du.reshape(-1), dv.reshape(-1)], dim=-1)


def sample_centres(height: int, width: int, count: int, patch: int, generator: torch.Generator | None = None,
                   device=None) -> torch.Tensor:
    """``[count, 2]`` integer pixel coordinates ``(u, v)`` drawn uniformly among the pixels whose ``patch × patch``
    neighbourhood lies inside a ``width × height`` image (with replacement), on ``generator``'s device (no copy from
    the host, so no wait for the GPU) or, without one, on ``device``."""
    r = patch // 2
    if width <= 2 * r or height <= 2 * r:
        raise GofError(f"multi-view patches of {patch} px do not fit a {width}x{height} image")
    on = generator.device if generator is not None else device
    u = torch.randint(r, width - r, (count,), generator=generator, device=on)
    v = torch.randint(r, height - r, (count,), generator=generator, device=on)
    return torch.stack([u, v], dim=-1)


def plane_warp(centres: torch.Tensor, depth: torch.Tensor, normal: torch.Tensor, ref: Camera, nbr: Camera,
               patch: int, pose: tuple[torch.Tensor, torch.Tensor] | None = None
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Project the patches around ``centres`` through their local planes into ``nbr``.

    Args:
        centres: ``[P, 2]`` integer pixels ``(u, v)`` of the reference view.
        depth: ``[P]`` z-depths at the centres; normal: ``[P, 3]`` camera-space unit normals there.
        pose: ``(R_rel [3, 3], t_rel [3])`` from the reference's camera coordinates to the neighbour's, on the
            depth's device and dtype (computed from the cameras when None).
    Returns:
        ``(uv, z, ok)``: ``[P, S, 2]`` continuous pixel coordinates in ``nbr`` (pixel ``i`` spans ``[i, i + 1]``),
        ``[P, S]`` depths in ``nbr``, ``[P, S]`` whether the ray meets the plane in front of the reference camera
        and the point lies in front of the neighbour; ``S = patch²``.
    """
    rot, trans = _relative_pose(ref, nbr, depth.dtype, depth.device) if pose is None else pose
    return _warp(centres, depth, normal, ref.pinhole, nbr.pinhole, rot, trans, patch)


def _warp(centres, depth, normal, k_ref, k_nbr, rot, trans, patch: int):
    """:func:`plane_warp` with the intrinsics as ``(fx, fy, cx, cy)``: floats, or a ``[4]`` tensor (no per-camera
    constants for a compiled graph to specialise on) — and the relative pose given."""
    points, ok = _cast(centres, depth, normal, k_ref, patch)
    return _project(points, ok, k_nbr, rot, trans)


def _cast(centres, depth, normal, k_ref, patch: int):
    """The reference half of :func:`_warp`: ``(points [P, S, 3], ok [P, S])``, each patch pixel's ray cast onto its
    patch's plane, in reference camera coordinates, and whether the ray meets the plane in front of the camera."""
    dt, dev = depth.dtype, depth.device
    off = patch_offsets(patch, dt, dev)
    q = centres.to(dt)[:, None, :] + off[None]  # [P, S, 2]
    rays = torch.stack([(q[..., 0] + 0.5 - k_ref[2]) / k_ref[0], (q[..., 1] + 0.5 - k_ref[3]) / k_ref[1],
                        torch.ones_like(q[..., 0])], dim=-1)  # [P, S, 3]
    centre_ray = rays[:, (patch * patch) // 2]  # [P, 3]
    rho = (normal * centre_ray).sum(-1) * depth  # nᵀX0
    denom = (normal[:, None, :] * rays).sum(-1)  # nᵀr_q
    # the plane must face the same way along every ray of the patch, and not be seen edge-on
    ok = (denom * (normal * centre_ray).sum(-1)[:, None] > 0) & (denom.abs() > 1e-4)
    scale = rho[:, None] / torch.where(ok, denom, torch.ones_like(denom))
    ok = ok & (scale > 0)
    return scale[..., None] * rays, ok


def _project(points, ok, k_nbr, rot, trans):
    """The neighbour half of :func:`_warp`: ``(uv [P, S, 2], z [P, S], ok [P, S])`` of reference-camera ``points``
    in the neighbour (``ok`` also requires the point in front of it)."""
    x = points @ rot.T + trans
    z = x[..., 2]
    ok = ok & (z > 1e-6)
    zs = torch.where(ok, z, torch.ones_like(z))
    uv = torch.stack([k_nbr[0] * x[..., 0] / zs + k_nbr[2], k_nbr[1] * x[..., 1] / zs + k_nbr[3]], dim=-1)
    return uv, z, ok


def _bilinear(image: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """``image [H, W]`` at continuous pixel coordinates ``uv [..., 2]`` (pixel ``i`` spans ``[i, i + 1]``), bilinear,
    border-clamped; differentiable in ``uv``."""
    h, w = image.shape
    grid = torch.stack([2.0 * uv[..., 0] / w - 1.0, 2.0 * uv[..., 1] / h - 1.0], dim=-1)
    flat = grid.reshape(1, 1, -1, 2).to(image.dtype)
    out = torch.nn.functional.grid_sample(image[None, None], flat, mode="bilinear", padding_mode="border",
                                          align_corners=False)
    return out.reshape(uv.shape[:-1])


def ncc(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-8) -> torch.Tensor:
    """Normalised cross-correlation of patches ``a, b [P, S]`` along ``S``: ``[P]`` in ``[-1, 1]``."""
    a = a - a.mean(-1, keepdim=True)
    b = b - b.mean(-1, keepdim=True)
    cov = (a * b).mean(-1)
    return cov / torch.sqrt((a * a).mean(-1) * (b * b).mean(-1) + eps)


def multiview_loss(median_depth: torch.Tensor, normal: torch.Tensor, alpha: torch.Tensor, grey_ref: torch.Tensor,
                   grey_nbr: torch.Tensor, ref: Camera, nbr: Camera, centres: torch.Tensor, config: MultiViewConfig,
                   nbr_depth: torch.Tensor | None = None,
                   pose: tuple[torch.Tensor, torch.Tensor] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """The term for one reference view and one neighbour (module docstring).

    Args:
        median_depth: ``[H, W]`` rendered median depth of ``ref`` (differentiable); normal: ``[H, W, 3]`` its
            rendered camera-space normal (``Σ ω_i n_i``, normalised here); alpha: ``[H, W]``.
        grey_ref, grey_nbr: ``[H, W]`` / ``[H', W']`` grey photos of the two views.
        centres: ``[P, 2]`` patch centres from :func:`sample_centres`.
        nbr_depth: ``[H', W']`` the neighbour's last rendered median depth (occlusion test), or None (no test).
        pose: the pair's relative pose as :func:`plane_warp` takes it (None: from the cameras).
    Returns:
        ``(loss, used)``: the mean ``1 − NCC`` over the patches that count (0 with a zero gradient when none
        does), and how many counted (a 0-d tensor).
    """
    rot, trans = _relative_pose(ref, nbr, median_depth.dtype, median_depth.device) if pose is None else pose
    return _loss(median_depth, normal, alpha, grey_ref, [grey_nbr], ref.pinhole, [nbr.pinhole], [rot], [trans],
                 centres, config, [nbr_depth])


def _loss(median_depth, normal, alpha, grey_ref, grey_nbrs, k_ref, k_nbrs, rots, transs, centres,
          config: MultiViewConfig, nbr_depths):
    """The term against one or more neighbours, on plain tensors (intrinsics as in :func:`_warp`): what the trainer
    compiles. ``grey_nbrs``, ``k_nbrs``, ``rots``, ``transs``, ``nbr_depths``: one entry per neighbour (a depth may
    be None: no occlusion test). A patch's loss is the mean ``1 − NCC`` over the neighbours it counts for (the
    module docstring's masks, per neighbour); the term is the mean over the patches that count for at least one,
    and ``used`` their number. With one neighbour this is :func:`multiview_loss`."""
    s = config.patch
    u, v = centres[:, 0], centres[:, 1]
    d = median_depth[v, u]
    n = normal[v, u]
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    points, cast_ok = _cast(centres, d, n, k_ref, s)
    off = patch_offsets(s, torch.long, centres.device)
    ref_patch = grey_ref[v[:, None] + off[None, :, 1], u[:, None] + off[None, :, 0]]  # [P, S]
    informative = (alpha[v, u] > config.alpha_min) & (d > 0) & (ref_patch.std(-1) > config.min_std)
    c = (s * s) // 2
    total = torch.zeros_like(d)
    count = torch.zeros_like(d)
    for grey_nbr, k_nbr, rot, trans, nbr_depth in zip(grey_nbrs, k_nbrs, rots, transs, nbr_depths):
        uv, z, ok = _project(points, cast_ok, k_nbr, rot, trans)
        h, w = grey_nbr.shape
        inside = (uv[..., 0] >= 0.5) & (uv[..., 0] <= w - 0.5) & (uv[..., 1] >= 0.5) & (uv[..., 1] <= h - 0.5)
        keep = (ok & inside).all(-1) & informative
        if nbr_depth is not None:
            seen = _nearest(nbr_depth, uv[:, c].detach())
            keep = keep & (z[:, c].detach() <= seen * (1.0 + config.occlusion_tolerance))
        per_patch = 1.0 - ncc(ref_patch, _bilinear(grey_nbr, uv))
        total = total + torch.where(keep, per_patch, torch.zeros_like(per_patch))
        count = count + keep.to(count.dtype)
    counted = count > 0
    used = counted.sum()
    loss = (total / count.clamp_min(1.0)).sum() / used.clamp_min(1)
    return loss, used


class MultiViewTerm:
    """The term over a fixed list of training views, as the trainer uses it.

    Holds each view's grey photo, its neighbours (:func:`neighbour_views`) and the median depth of its last render
    (the occlusion test). :meth:`__call__` draws its neighbours (``neighbours_per_step``) and the patch centres from
    ``(seed, iteration, view)`` alone, so a resumed run draws the same ones. The kept depths are not checkpointed: a
    resumed run skips the pairs whose neighbour it has not rendered since, so it is not bit for bit the uninterrupted
    run. With several
    processes each keeps the depths of the views it rendered, so the term is not the one-process run's either.

    Args:
        config: :class:`MultiViewConfig`; cameras: the training cameras; images: their ``[H, W, 3]`` photos on the
            training device; seed: the run's seed.
        compile_backend: compile the term with ``torch.compile`` and this backend (the trainer does where it compiles
            its loss: some 70 small operations and as many in the backward become a few fused kernels, which on a
            GPU is the difference between host-bound and not); None: eager. If compiling fails the term warns and
            stays eager.
        views_per_step: views trained per iteration: every view is rendered once an epoch of
            ``⌈views / views_per_step⌉`` iterations (GOF's stack of views), so depths are kept from one epoch before
            the term acts (a depth per view on the device, not needed earlier).
    """

    def __init__(self, config: MultiViewConfig, cameras, images, seed: int, compile_backend: str | None = None,
                 views_per_step: int = 1):
        self.config, self.cameras, self.seed = config, list(cameras), int(seed)
        epoch = -(-len(self.cameras) // max(int(views_per_step), 1))
        self.remember_from = config.from_iter - epoch - 1
        self._core = _loss
        if compile_backend is not None:
            self._core = torch.compile(_loss, dynamic=False, fullgraph=True, backend=compile_backend)
        self.grey = [grey(im) for im in images]
        self.neighbours = neighbour_views(self.cameras, config.neighbours, config.max_angle_deg)
        self.depth: list[torch.Tensor | None] = [None] * len(self.cameras)
        # every (view, neighbour) pose, built on the host and copied to the device once: a copy per pair on first use
        # would make the host wait for the GPU hundreds of times early in training
        pairs = [(i, m) for i, nb in enumerate(self.neighbours) for m in nb]
        self._pose_index = {pair: row for row, pair in enumerate(pairs)}
        flat = [_relative_pose_np(self.cameras[i], self.cameras[m]) for i, m in pairs]
        device = images[0].device if len(images) else None
        self._poses = torch.tensor(np.asarray(flat, np.float32).reshape(-1, 12), device=device)
        self._intr = torch.tensor([c.pinhole for c in self.cameras], dtype=torch.float32, device=device)

    def active(self, iteration: int) -> bool:
        """Whether the term acts at ``iteration`` (on, and from ``from_iter``)."""
        return self.config.on and iteration >= self.config.from_iter

    def remember(self, view: int, median_depth: torch.Tensor, iteration: int | None = None) -> None:
        """Keep view ``view``'s rendered median depth ``[H, W]`` (a detached copy) for later occlusion tests; at an
        ``iteration`` before ``remember_from``, nothing is kept."""
        if iteration is None or iteration >= self.remember_from:
            self.depth[view] = median_depth.detach().clone()

    def forget(self) -> None:
        """Drop every kept depth (a resumed run starts without them: until a view is rendered again, the pairs
        whose neighbour it is are skipped)."""
        self.depth = [None] * len(self.cameras)

    def __call__(self, out: dict, view: int, iteration: int) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(loss, used)`` of view ``view`` at ``iteration`` from the renderer's ``out`` (``median_depth``,
        ``normal``, ``alpha``), against ``neighbours_per_step`` of its neighbours drawn from ``(seed, iteration,
        view)``; None when it has none, or when none of the drawn ones has been rendered yet (no depth for the
        occlusion test; drawn ones without a depth are left out)."""
        choices = self.neighbours[view]
        if not choices:
            return None
        rng = np.random.default_rng([self.seed, iteration, view, _SALT])
        per_step = min(self.config.neighbours_per_step, len(choices))
        if per_step == 1:  # one integer draw, as the term has always drawn it: runs made before reproduce
            drawn = [choices[int(rng.integers(len(choices)))]]
        else:
            drawn = [choices[int(i)] for i in rng.choice(len(choices), size=per_step, replace=False)]
        drawn = [m for m in drawn if self.depth[m] is not None]
        if not drawn:
            return None
        depth = out["median_depth"]
        h, w = depth.shape
        # drawn on the depth's device: a host-side draw copied over would wait for the GPU every step
        gen = torch.Generator(device=depth.device).manual_seed(int(rng.integers(2**62)))
        centres = sample_centres(h, w, self.config.pixels, self.config.patch, gen)
        rows = [self._poses[self._pose_index[(view, m)]].to(depth.dtype) for m in drawn]
        args = (depth, out["normal"], out["alpha"], self.grey[view], [self.grey[m] for m in drawn],
                self._intr[view].to(depth.dtype), [self._intr[m].to(depth.dtype) for m in drawn],
                [r[:9].view(3, 3) for r in rows], [r[9:] for r in rows], centres, self.config,
                [self.depth[m] for m in drawn])
        if self._core is not _loss:
            try:
                return self._core(*args)
            except Exception as e:  # noqa: BLE001 - any compiler failure: the eager term computes the same
                self.give_up(e)
        return _loss(*args)

    def give_up(self, error: Exception) -> None:
        """Compute the term eager from now on (after ``error`` from the compiler), with a warning. The forward's
        failure is caught here; the backward is compiled at the first ``backward()``, so the trainer's warm-up calls
        this when that fails."""
        if self._core is not _loss:
            log.warning("torch.compile of the multi-view term failed (%s); using it eager", error_summary(error, 300))
            self._core = _loss

    def prime(self) -> None:
        """Give every view a depth of zeros (every patch then counts as occluded), so that a throw-away pass builds
        the compiled term's graphs; :meth:`forget` afterwards."""
        self.depth = [torch.zeros(g.shape, dtype=torch.float32, device=g.device) for g in self.grey]


def _nearest(image: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """``image [H, W]`` at the pixel holding each continuous coordinate ``uv [P, 2]`` (clamped to the image)."""
    h, w = image.shape
    i = uv[:, 0].floor().long().clamp(0, w - 1)
    j = uv[:, 1].floor().long().clamp(0, h - 1)
    return image[j, i]


__all__ = ["MultiViewConfig", "MultiViewTerm", "grey", "multiview_loss", "ncc", "neighbour_views", "patch_offsets", "plane_warp",
           "sample_centres"]
