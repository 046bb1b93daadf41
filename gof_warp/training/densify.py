"""Adaptive density control of GOF: a policy object with explicit state.

Per training iteration the trainer calls, in this order (GOF ``train.py``)::

    densifier.update_sh_degree(it, gaussians)          # before rendering: SH degree +1 every 1000 it
    ... render, loss.backward() ...
    densifier.after_backward(stats, it)                # accumulate screen-space gradient statistics
    report = densifier.step(it, gaussians, optimizer, extent)   # clone/split/prune, opacity reset
    if report.filter_3d_due: update_filter_3d(gaussians, train_cameras)
    optimizer.step(); optimizer.zero_grad()

Rules (GOF_REFERENCE §4; defaults in :class:`DensifyConfig`):

* Statistics while ``it < 15 000`` for visible Gaussians (radius > 0): ``ḡ = mean over views of
  ‖Σ_pixels ∂L/∂μ2D‖`` (NDC units, 3DGS) and ``M̄ = mean over views of Σ_pixels ‖∂L/∂μ2D‖`` (the
  paper's improved metric, Eq. 15), plus the largest screen radius.
* Every 100 iterations for ``500 < it < 15 000``: candidates, then each candidate is **cloned** when
  its largest (unfiltered) scale is ≤ 0.01·E, else **split**. Clone: a child sampled from the parent's
  Gaussian, ``μ' = μ + R(q)(s ⊙ ε)``, ``ε ~ N(0, I)``, other raw parameters copied, parent kept
  (paper appendix; GOF ``densify_and_clone``). Split: two children sampled the same way with scales
  ``s/1.6``, parent removed. Children's statistics start at zero.
* Prune (same step, parents and children): opacity ``σ(o) < 0.05`` (unfiltered); when
  ``it > 3000`` also largest scale ``> 0.1·E`` and, only with ``prune_screen_size=True``, screen radius
  ``> 20 px``. In GOF/3DGS's code the screen test is dead (``densification_postfix`` zeroes the radii
  before the prune), and so it is off by default here: on a real capture with a floor (colmap_can,
  720×1280, H200) the live test pruned every near-camera floor Gaussian at the first size prune (60k → 20k
  Gaussians at iteration 3,100, train PSNR 32 → 24 dB, a hole-riddled floor) — the "missing ground" of
  ground-and-objects scenes. ``prune_screen_size=True`` gives the papers' described behaviour.
  Children have radius 0 (never seen) until the next step.
* Opacity reset every 3000 iterations while ``it < 15 000``: filtered opacity ``← min(o_f, 0.01)``,
  the parameter's Adam moments zeroed (GOF ``reset_opacity``).
* After densification GOF never prunes again, so Gaussians the loss drives transparent after ``stop_iter`` stay,
  and so does a floater in front of a camera. Optional (off by default, GOF's schedule):
  ``late_prune_interval > 0`` keeps densification's prune (transparent, or larger than ``max_world_scale·E``)
  going every that many iterations until ``filter_3d_until_iter``; ``near_camera_fraction = f > 0`` makes each
  such prune also remove the Gaussians that a training camera's rays meet nearer than ``f`` × the depth of the
  nearest initial (SfM) point that camera sees (``gof_warp.training.near_camera``): nothing the photos triangulated lies
  that close. Measured on colmap_can: every per-view loss spike after 15k was such a Gaussian (opaque, 0.2–0.6
  in front of the camera, its centre often beside the image) or one that had grown past ``0.1·E`` (scale 4).
* A run from random points (``ModelConfig.random_min_views``): after each densification and late prune, the
  Gaussians whose centres fewer than that many training cameras see are removed (the trainer's ``unseen`` test,
  :func:`gof_warp.training.near_camera.views_seeing`): densification grows from SfM points, which two views or more
  saw, but random points also fill the space right in front of a camera, which no other view constrains.
* Optional budget ``max_gaussians``: growth stops at the budget; when there are more candidates than
  room, the highest-scoring ones (score = metric / its threshold) are kept. The budget is checked
  against the count *before* this step's prune; room freed by the prune is used at the next step.

Candidate metrics (``DensifyConfig.metric``):

* ``"gof"`` (default): ``ḡ ≥ τ`` OR ``M̄ ≥ Q``, where ``Q`` is the ``(1 − r)``-quantile of ``M̄``
  over all Gaussians and ``r`` the fraction with ``ḡ ≥ τ`` — so ``M̄`` selects as many Gaussians as
  ``ḡ`` does (GOF ``densify_and_prune``; not in the paper, which gives no calibrated threshold for
  ``M̄`` as far as we could find). Deviation: with ``r = 0`` GOF's quantile is ``max M̄`` and one
  Gaussian is still selected; we select none. Our quantile is exact at any N (``torch.quantile``
  fails above 2²⁴ elements).
* ``"paper"``: ``ḡ ≥ τ`` OR ``M̄ ≥ abs_grad_threshold`` (a fixed threshold you choose; with
  ``τ_M = τ`` it reduces to ``M̄ ≥ τ``, since ``M̄ ≥ ḡ`` always, and densifies far more).
* ``"standard"``: 3DGS's ``ḡ ≥ τ`` only (ablation).

Whether ``M̄`` sums per-pixel L2 norms (paper) or L1 norms (GOF's CUDA) is the renderer's choice.
All parameter/optimizer changes go through :func:`gof_warp.training.optim.replace_params`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import torch

from ..core.devices import StreamWrappers, warp_device
from ..core.config import ConfigError
from ..core.errors import GofError
from ..core.model import Gaussians, quat_to_rotmat
from .optim import replace_params

METRICS = ("gof", "paper", "standard")


@dataclass
class DensifyConfig:
    """Densification schedule and thresholds (defaults: GOF ``arguments/__init__.py``, ``train.py``)."""

    start_iter: int = 500  # densify when it > start_iter ...
    stop_iter: int = 15_000  # ... and it < stop_iter (statistics are gathered while it < stop_iter)
    interval: int = 100  # densify every this many iterations
    metric: str = field(default="gof", metadata={"set_by": "experimental.densify_metric"})  # "gof" | "paper" | "standard"
    grad_threshold: float = 2e-4  # τ on ḡ, NDC units
    abs_grad_threshold: float = field(default=2e-4, metadata={"set_by": "experimental.abs_grad_threshold"})  # τ_M
    percent_dense: float = 0.01  # clone if max scale <= percent_dense·E, else split
    split_children: int = 2  # Gaussians a split makes of one
    split_scale_divisor: float = 1.6  # GOF: 0.8 · split_children
    min_opacity: float = 0.05  # prune Gaussians less opaque than this
    prune_big_after: int = 3000  # size prunes when it > prune_big_after (GOF: opacity_reset_interval)
    max_world_scale: float = 0.1  # × extent
    # GOF's code: the 3DGS test is dead (module docstring)
    prune_screen_size: bool = field(default=False, metadata={"set_by": "experimental.prune_screen_size"})
    max_screen_radius: float = field(default=20.0, metadata={"set_by": "experimental.max_screen_radius"})  # pixels
    opacity_reset_interval: int = 3000  # reset every opacity every this many iterations (while densifying)
    opacity_reset_value: float = 0.01  # the opacity a reset sets
    reset_opacity_at_start: bool = False  # GOF does it at it == start_iter with a white background
    sh_degree_interval: int = 1000  # raise the active SH degree by one every this many iterations
    max_gaussians: int | None = None  # budget; None = unbounded
    filter_3d_interval: int = 100  # recompute φ every this many it for stop_iter < it < filter_3d_until_iter
    filter_3d_until_iter: int = 29_900  # GOF: iterations − 100
    seed: int = field(default=0, metadata={"set_by": "seed"})  # clone/split sampling; TrainConfig.seed
    # after densification (it >= stop_iter) GOF never prunes again; > 0: every this many iterations (while
    # it < filter_3d_until_iter) prune as densification does, σ(o) < min_opacity or max scale > max_world_scale·E
    late_prune_interval: int = 0
    # > 0 (needs initial points and late_prune_interval): each late prune also removes the Gaussians that a training
    # camera's rays meet nearer than this fraction of the nearest initial point it sees
    near_camera_fraction: float = 0.0
    # not GOF (off by default): at these iterations remove the Gaussians behind the rendered surface in every training
    # view (gof_warp.training.hidden.behind_surface, by more than hidden_margin × its depth), whose tails the opacity field
    # counts in front of that surface; of those, only the ones the photos show less than hidden_max_visible of in
    # their best view (gof_warp.training.hidden.visible_fraction: ~0 behind an opaque surface; None: the depth test alone)
    hidden_prune_iters: list[int] = field(default_factory=list)
    hidden_margin: float = 0.01  # hidden prune: behind the surface by more than this fraction of its depth
    hidden_max_visible: float | None = 0.2  # hidden prune: only those seen less than this in their best view
    # and, unless None, only the ones whose opacity at the rendered surface (gof_warp.training.hidden.surface_measures' tail:
    # o·exp(-½(Δ/σ_t)²) along the ray, the largest over the views) is above this: what raises GOF's field in front of
    # a surface, not a thin layer under it
    hidden_min_tail: float | None = None

    def __post_init__(self):
        if self.metric not in METRICS:
            raise ConfigError(f"experimental.densify_metric must be one of {METRICS}, got {self.metric!r}")
        if self.max_gaussians is not None and self.max_gaussians < 1:
            raise ConfigError(f"densify.max_gaussians must be positive or None, got {self.max_gaussians}")
        if self.interval < 1 or self.opacity_reset_interval < 1 or self.sh_degree_interval < 1:
            raise ConfigError(f"densify.interval, densify.opacity_reset_interval and densify.sh_degree_interval must be >= 1, got "
                              f"{self.interval}, {self.opacity_reset_interval}, {self.sh_degree_interval}")
        if self.split_children < 1 or self.split_scale_divisor <= 0:
            raise ConfigError("densify.split_children must be >= 1 and densify.split_scale_divisor > 0")
        if self.late_prune_interval < 0:
            raise ConfigError(f"densify.late_prune_interval must be >= 0 (0: off), got {self.late_prune_interval}")
        if not 0.0 <= self.near_camera_fraction < 1.0:
            raise ConfigError("densify.near_camera_fraction must be in [0, 1) (0: off), got "
                           f"{self.near_camera_fraction}")
        if self.near_camera_fraction > 0 and self.late_prune_interval == 0:
            raise ConfigError("densify.near_camera_fraction acts at the late prunes: set late_prune_interval > 0")
        if any(int(i) != i or i < 1 for i in self.hidden_prune_iters):
            raise ConfigError(f"densify.hidden_prune_iters must be iterations >= 1, got {self.hidden_prune_iters}")
        if not self.hidden_margin > 0:
            raise ConfigError(f"densify.hidden_margin must be > 0, got {self.hidden_margin}")
        if self.hidden_max_visible is not None and not 0.0 < self.hidden_max_visible <= 1.0:
            raise ConfigError(f"densify.hidden_max_visible must be in (0, 1] or None, got {self.hidden_max_visible}")
        if self.hidden_min_tail is not None and not 0.0 <= self.hidden_min_tail < 1.0:
            raise ConfigError(f"densify.hidden_min_tail must be in [0, 1) or None, got {self.hidden_min_tail}")


@dataclass
class DensifyReport:
    """What one :meth:`Densifier.step` did."""

    iteration: int
    num_before: int
    num_after: int
    densified: bool = False
    num_candidates: int = 0
    num_over_budget: int = 0  # candidates dropped because of max_gaussians
    num_cloned: int = 0  # parents cloned (= clone children)
    num_split: int = 0  # parents split (removed; split_children children each)
    num_added: int = 0  # children that survived the prune
    num_pruned: int = 0  # Gaussians removed by the prune (split parents not counted)
    abs_threshold: float | None = None  # threshold applied to M̄ (Q for metric="gof")
    opacity_reset: bool = False
    late_pruned: bool = False  # a prune after densification ran (late_prune_interval)
    num_near_camera: int = 0  # of num_pruned: Gaussians in front of a camera (near_camera_fraction)
    num_hidden: int = 0  # Gaussians removed as hidden behind the rendered surface (hidden_prune_iters)
    num_unseen: int = 0  # Gaussians removed because too few training cameras see them (the trainer's unseen test)
    filter_3d_due: bool = False  # the trainer should recompute the 3D filter now (GOF schedule)


def quantile(values: torch.Tensor, q: float) -> torch.Tensor:
    """``torch.quantile(values, q)`` (linear interpolation) for any length, via ``kthvalue``."""
    n = values.numel()
    pos = q * (n - 1)
    lo, hi = math.floor(pos), math.ceil(pos)
    v_lo = values.kthvalue(lo + 1).values
    v_hi = values.kthvalue(hi + 1).values if hi != lo else v_lo
    return v_lo + (v_hi - v_lo) * (pos - lo)


def densify_candidates(grad: torch.Tensor, grad_abs: torch.Tensor, config: DensifyConfig):
    """Candidates from the mean statistics ``ḡ`` and ``M̄`` (both ``[N]``).

    Returns ``(mask [N] bool, score [N], abs_threshold or None)``; ``score ≥ 1`` exactly for
    candidates (metric over its threshold, the larger of the two) and ranks them for the budget.
    """
    tau = config.grad_threshold
    score = grad / tau
    if config.metric == "standard":
        return score >= 1.0, score, None
    if config.metric == "paper":
        tau_m = config.abs_grad_threshold
    else:
        ratio = (grad >= tau).float().mean().item() if grad.numel() else 0.0
        tau_m = quantile(grad_abs, 1.0 - ratio).item() if ratio > 0 else math.inf
    if not (tau_m > 0 and math.isfinite(tau_m)):  # no M̄ candidates (nothing selected, or all-zero M̄)
        return score >= 1.0, score, tau_m
    score = torch.maximum(score, grad_abs / tau_m)
    return score >= 1.0, score, tau_m


def sample_children(gaussians: Gaussians, index: torch.Tensor, n_children: int, generator: torch.Generator,
                    scale_divisor: float = 1.0) -> dict[str, torch.Tensor]:
    """Raw parameters of ``n_children`` children per parent ``index`` (order: all parents once, then again).

    Child means are drawn from the parent's Gaussian, ``μ + R(q)(s ⊙ ε)``, ``ε ~ N(0, I)`` with the
    parent's unfiltered scales ``s``; log-scales become ``log(s / scale_divisor)``; everything else
    (and ``filter_3d`` when set) is copied.
    """
    with torch.no_grad():
        idx = index.repeat(n_children)
        p = {k: v.detach()[idx] for k, v in gaussians.params.items()}
        s = torch.exp(p["log_scales"])
        eps = torch.randn(s.shape, generator=generator, device=s.device, dtype=s.dtype)
        p["means"] = p["means"] + (quat_to_rotmat(p["quats"]) @ (s * eps)[..., None])[..., 0]
        p["log_scales"] = p["log_scales"] - math.log(scale_divisor)
        if gaussians.filter_3d is not None:
            p["filter_3d"] = gaussians.filter_3d[idx]
    return p


def prune_mask(opacity: torch.Tensor, scales: torch.Tensor, max_radii: torch.Tensor, extent: float,
               iteration: int, config: DensifyConfig) -> torch.Tensor:
    """``[N]`` bool: unfiltered opacity ``< min_opacity``; after ``prune_big_after`` also largest
    unfiltered scale ``> max_world_scale·extent`` and (if enabled) screen radius ``> max_screen_radius``."""
    mask = opacity < config.min_opacity
    if iteration > config.prune_big_after:
        mask |= scales.max(dim=1).values > config.max_world_scale * extent
        if config.prune_screen_size:
            mask |= max_radii > config.max_screen_radius
    return mask


def reset_opacity(gaussians: Gaussians, optimizer, value: float = 0.01) -> None:
    """Filtered opacity ``o_f ← min(o_f, value)`` (GOF ``reset_opacity``), Adam moments of the opacity zeroed."""
    with torch.no_grad():
        coef = torch.ones(len(gaussians), device=gaussians.device)  # the 3D filter's energy factor
        if gaussians.filter_3d is not None:
            s2 = gaussians.raw_scales ** 2
            coef = torch.sqrt(s2.prod(dim=1) / (s2 + gaussians.filter_3d[:, None] ** 2).prod(dim=1))
        o_f = gaussians.raw_opacities * coef
        new = torch.where(o_f > value, torch.logit(value / coef, eps=1e-6), gaussians.opacity_logits.detach())
    rows = torch.ones(len(gaussians), dtype=torch.bool, device=gaussians.device)
    replace_params(gaussians, optimizer, reset={"opacity_logits": (rows, new)})


def sh_degree_at(iteration: int, interval: int, max_degree: int) -> int:
    """Active SH degree at ``iteration``: one more every ``interval`` iterations (GOF: at it = 1000, 2000, 3000)."""
    return min(max_degree, max(0, iteration) // interval)


@dataclass
class _Stats:
    grad: torch.Tensor  # [N] Σ over views of ‖Σ_pixels ∂L/∂μ2D‖
    grad_abs: torch.Tensor  # [N] Σ over views of M
    count: torch.Tensor  # [N] views in which the Gaussian was visible
    max_radii: torch.Tensor  # [N] largest screen radius (px)

    @classmethod
    def zeros(cls, n: int, device) -> "_Stats":
        z = lambda dtype: torch.zeros(n, dtype=dtype, device=device)  # noqa: E731
        return cls(z(torch.float32), z(torch.float32), z(torch.int32), z(torch.int32))


class ViewStatsKernel:
    """Adds one view's statistics into the running sums in place, for the Gaussians it saw (``radii > 0``): the norms
    of their view-space gradients ``grad`` ``[N]`` and ``grad_abs`` ``[N]`` into the sums, one more view counted, the
    largest radius kept. One Warp kernel (:func:`gof_warp.kernels.densify_stats.accumulate_view_stats`) on torch's
    current stream instead of ten elementwise operators, with the same bits (it only adds and takes a maximum). The
    launch is recorded once per set of running sums (they change only when the Gaussians do) and replayed with each
    view's arrays, so a view costs the host three array descriptors and one replay."""

    def __init__(self):
        self._streams = StreamWrappers()
        self._key: tuple | None = None
        self._cmd = None

    def __call__(self, stats: _Stats, grad: torch.Tensor, grad_abs: torch.Tensor, radii: torch.Tensor) -> None:
        import warp as wp

        from ..kernels.densify_stats import accumulate_view_stats

        # the view's terms as float32 / int32 and contiguous (themselves when they are: the renderer's are), kept
        # alive here while the launch reads them through descriptors that hold only their addresses
        view = [t.to(dtype).contiguous() for t, dtype in ((grad, torch.float32), (grad_abs, torch.float32),
                                                            (radii, torch.int32))]
        arrays = [wp.from_torch(t, requires_grad=False, return_ctype=True) for t in view]
        sums = (stats.grad, stats.grad_abs, stats.count, stats.max_radii)
        device = radii.device
        key = (device, radii.shape[0], *(t.data_ptr() for t in sums))
        if key != self._key:
            wp.init()  # idempotent
            self._cmd = wp.launch(accumulate_view_stats, dim=radii.shape[0], device=warp_device(device),
                                  inputs=[*arrays, *(wp.from_torch(t, requires_grad=False) for t in sums)],
                                  record_cmd=True)
            self._key = key
        else:
            for i, a in enumerate(arrays):
                self._cmd.set_param_at_index(i, a)
        self._cmd.launch(self._streams.launch_stream(device))


class Densifier:
    """GOF's densification policy (see the module docstring). State: statistics, sampler, history.

    Attributes:
        config: the :class:`DensifyConfig`.
        history: ``[(iteration, count)]`` after each densification (the Gaussian count over training).
    """

    def __init__(self, config: DensifyConfig | None = None):
        self.config = config or DensifyConfig()
        self.stats: _Stats | None = None
        self.generator: torch.Generator | None = None
        self.history: list[tuple[int, int]] = []
        # Gaussians the late prunes removed, by reason (each counted once, in this order)
        self.late_pruned = {"transparent": 0, "too_large": 0, "near_camera": 0}
        self.hidden_pruned = 0  # Gaussians the hidden prunes removed
        self.unseen_pruned = 0  # Gaussians removed because too few training cameras see them
        self._view_stats = ViewStatsKernel()  # adds each view's statistics into self.stats

    # ------------------------------------------------------------------ hooks
    def update_sh_degree(self, iteration: int, gaussians: Gaussians) -> int:
        """Set ``gaussians.active_sh_degree`` for ``iteration`` (call before rendering); returns it."""
        gaussians.active_sh_degree = sh_degree_at(iteration, self.config.sh_degree_interval, gaussians.max_sh_degree)
        return gaussians.active_sh_degree

    @torch.no_grad()
    def after_backward(self, stats, iteration: int, scale: float = 1.0) -> None:
        """Accumulate the renderer's ``DensifyStats`` (``grad2d [N, 2]``, ``grad2d_abs [N]``,
        ``radii [N]``) of one view; a no-op from ``stop_iter`` on. Visible = radius > 0. ``scale`` multiplies
        the gradient terms: a view whose loss entered the step divided by k gives its own gradients back
        with ``scale = k``, so the thresholds mean the same whatever the number of views per step."""
        if iteration >= self.config.stop_iter:
            return
        radii = stats.radii
        n = radii.shape[0]
        if stats.grad2d.shape != (n, 2) or stats.grad2d_abs.shape != (n,):
            raise GofError(f"after_backward: stats shapes grad2d {list(stats.grad2d.shape)}, grad2d_abs "
                           f"{list(stats.grad2d_abs.shape)}, radii {list(radii.shape)} disagree")
        if self.stats is None:
            self.stats = _Stats.zeros(n, radii.device)
        elif self.stats.count.shape[0] != n:
            raise GofError(f"after_backward: {n} Gaussians but statistics for {self.stats.count.shape[0]}; "
                           "the model changed outside Densifier.step (call reset_stats)")
        grad, grad_abs = stats.grad2d.norm(dim=-1), stats.grad2d_abs
        if scale != 1.0:
            grad, grad_abs = grad * scale, grad_abs * scale
        self._view_stats(self.stats, grad, grad_abs, radii)

    def densify_due(self, iteration: int) -> bool:
        """Whether :meth:`step` densifies and prunes at ``iteration`` (it reads the statistics then)."""
        cfg = self.config
        return cfg.start_iter < iteration < cfg.stop_iter and iteration % cfg.interval == 0

    def reset_stats(self, n: int | None = None, device=None) -> None:
        """Forget the statistics (sized lazily at the next :meth:`after_backward` when ``n`` is None)."""
        self.stats = None if n is None else _Stats.zeros(n, device)

    def late_prune_due(self, iteration: int) -> bool:
        """Whether :meth:`step` prunes at ``iteration`` after densification (``late_prune_interval``)."""
        cfg = self.config
        return (cfg.late_prune_interval > 0 and cfg.stop_iter <= iteration < cfg.filter_3d_until_iter
                and iteration % cfg.late_prune_interval == 0)

    def hidden_prune_due(self, iteration: int) -> bool:
        """Whether :meth:`step` prunes the hidden Gaussians at ``iteration`` (when it is given a ``hidden`` test)."""
        return iteration in self.config.hidden_prune_iters

    def count_may_change(self, iteration: int, hidden: bool) -> bool:
        """Whether :meth:`step` may add or remove Gaussians at ``iteration`` (``hidden``: it is given a hidden test)."""
        return (self.densify_due(iteration) or self.late_prune_due(iteration)
                or (hidden and self.hidden_prune_due(iteration)))

    def step(self, iteration: int, gaussians: Gaussians, optimizer, extent: float,
             near_camera: Callable[[], torch.Tensor] | None = None,
             hidden: Callable[[], torch.Tensor] | None = None,
             unseen: Callable[[], torch.Tensor] | None = None) -> DensifyReport:
        """Densify/prune and reset opacities when the schedule says so (call after backward, before
        ``optimizer.step()``). Replaced parameters have no ``.grad``, so Adam skips them this
        iteration, as in GOF. ``near_camera()`` (``[N]`` bool, called only at a late prune): the Gaussians in
        front of a camera (``near_camera_fraction``). ``hidden()`` (``[N]`` bool, called at ``hidden_prune_iters``,
        after any other change this step): the Gaussians behind the rendered surface. ``unseen()`` (``[N]`` bool,
        called after each densification and late prune): the Gaussians too few training cameras see."""
        cfg = self.config
        n0 = len(gaussians)
        report = DensifyReport(iteration=iteration, num_before=n0, num_after=n0)
        if iteration < cfg.stop_iter:
            if self.densify_due(iteration):
                self._densify_and_prune(iteration, gaussians, optimizer, extent, report)
                self.history.append((iteration, len(gaussians)))
            at_start = cfg.reset_opacity_at_start and iteration == cfg.start_iter
            if iteration % cfg.opacity_reset_interval == 0 or at_start:
                reset_opacity(gaussians, optimizer, cfg.opacity_reset_value)
                report.opacity_reset = True
        elif self.late_prune_due(iteration):
            self._late_prune(iteration, gaussians, optimizer, extent, near_camera, report)
        if unseen is not None and (report.densified or report.late_pruned):
            report.num_unseen = self._mask_prune(iteration, gaussians, optimizer, unseen, "unseen")
            self.unseen_pruned += report.num_unseen
            if report.num_unseen and report.densified:  # as densification leaves them: zero, one row a Gaussian
                self.stats = _Stats.zeros(len(gaussians), gaussians.means.device)
        if hidden is not None and self.hidden_prune_due(iteration):
            self._hidden_prune(iteration, gaussians, optimizer, hidden, report)
        report.filter_3d_due = report.densified or (
            iteration % cfg.filter_3d_interval == 0 and cfg.stop_iter < iteration < cfg.filter_3d_until_iter)
        report.num_after = len(gaussians)
        return report

    def _late_prune(self, iteration: int, gaussians, optimizer, extent: float, near_camera, report: DensifyReport) -> None:
        cfg = self.config
        with torch.no_grad():
            transparent = gaussians.raw_opacities < cfg.min_opacity
            too_large = gaussians.raw_scales.max(dim=1).values > cfg.max_world_scale * extent
            mask = transparent | too_large
            if near_camera is not None:
                near = near_camera()
                report.num_near_camera = int((near & ~mask).sum())
                mask |= near
            report.num_pruned = int(mask.sum())
            n_transparent = int(transparent.sum())
        if report.num_pruned and report.num_pruned == len(gaussians):
            raise GofError(f"the late prune at iteration {iteration} would remove all {len(gaussians)} Gaussians "
                           f"({n_transparent} with opacity below densify.min_opacity = {cfg.min_opacity}, "
                           f"{report.num_near_camera} in front of a camera): check the scene's near plane, "
                           "densify.min_opacity and densify.near_camera_fraction")
        report.late_pruned = True
        self.late_pruned["transparent"] += n_transparent
        self.late_pruned["too_large"] += report.num_pruned - report.num_near_camera - n_transparent
        self.late_pruned["near_camera"] += report.num_near_camera
        if report.num_pruned:
            replace_params(gaussians, optimizer, keep=~mask)
            self.stats = None

    def _hidden_prune(self, iteration: int, gaussians, optimizer, hidden, report: DensifyReport) -> None:
        report.num_hidden = self._mask_prune(iteration, gaussians, optimizer, hidden, "hidden")
        self.hidden_pruned += report.num_hidden

    def _mask_prune(self, iteration: int, gaussians, optimizer, test: Callable[[], torch.Tensor], what: str) -> int:
        """Remove the Gaussians ``test()`` (``[N]`` bool) marks; how many. Removing every one is an error."""
        mask = test()
        if mask.shape != (len(gaussians),):
            raise GofError(f"{what} prune at iteration {iteration}: a mask of shape {list(mask.shape)} for "
                           f"{len(gaussians)} Gaussians")
        n = int(mask.sum())
        if n == len(gaussians):
            raise GofError(f"the {what} prune at iteration {iteration} would remove all {len(gaussians)} Gaussians")
        if n:
            replace_params(gaussians, optimizer, keep=~mask)
            self.stats = None
        return n

    # ------------------------------------------------------------------ the densification step
    def _densify_and_prune(self, iteration, gaussians, optimizer, extent, report: DensifyReport) -> None:
        cfg = self.config
        n = len(gaussians)
        device = gaussians.device
        s = self.stats if self.stats is not None and self.stats.count.shape[0] == n else _Stats.zeros(n, device)
        denom = s.count.clamp_min(1).float()
        cand, score, report.abs_threshold = densify_candidates(s.grad / denom, s.grad_abs / denom, cfg)
        report.num_candidates = int(cand.sum())
        if cfg.max_gaussians is not None:
            room = max(0, cfg.max_gaussians - n)
            if report.num_candidates > room:
                order = torch.argsort(torch.where(cand, score, torch.full_like(score, -math.inf)), descending=True)
                cand = torch.zeros_like(cand)
                cand[order[:room]] = True
                report.num_over_budget = report.num_candidates - room
        with torch.no_grad():
            scales = gaussians.raw_scales
            small = scales.max(dim=1).values <= cfg.percent_dense * extent
            clone_idx = torch.nonzero(cand & small).flatten()
            split_idx = torch.nonzero(cand & ~small).flatten()
            gen = self._generator(device)
            clones = sample_children(gaussians, clone_idx, 1, gen)
            splits = sample_children(gaussians, split_idx, cfg.split_children, gen, cfg.split_scale_divisor)
            children = {k: torch.cat([clones[k], splits[k]]) for k in clones}
            parent_prune = prune_mask(gaussians.raw_opacities, scales, s.max_radii, extent, iteration, cfg)
            child_prune = prune_mask(torch.sigmoid(children["opacity_logits"]), torch.exp(children["log_scales"]),
                                     torch.zeros_like(children["opacity_logits"]), extent, iteration, cfg)
            keep = ~parent_prune
            keep[split_idx] = False
            report.num_pruned = int(parent_prune.sum()) + int(child_prune.sum()) - int(parent_prune[split_idx].sum())
            children = {k: v[~child_prune] for k, v in children.items()}
        replace_params(gaussians, optimizer, keep=keep, append=children)
        report.densified = True
        report.num_cloned, report.num_split = clone_idx.numel(), split_idx.numel()
        report.num_added = children["means"].shape[0]
        self.stats = _Stats.zeros(len(gaussians), device)

    def _generator(self, device) -> torch.Generator:
        device = torch.device(device)
        if self.generator is None or self.generator.device.type != device.type:
            self.generator = torch.Generator(device=device)
            self.generator.manual_seed(self.config.seed)
        return self.generator

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict:
        """Statistics, sampler state and history (for checkpoints)."""
        gen = None if self.generator is None else (str(self.generator.device), self.generator.get_state())
        return {"config": asdict(self.config), "history": list(self.history),
                "stats": None if self.stats is None else asdict(self.stats), "generator": gen,
                "late_pruned": dict(self.late_pruned), "hidden_pruned": self.hidden_pruned,
                "unseen_pruned": self.unseen_pruned}

    def load_state_dict(self, state: dict) -> None:
        self.history = [tuple(h) for h in state["history"]]
        self.stats = None if state["stats"] is None else _Stats(**state["stats"])
        self.late_pruned = dict(state.get("late_pruned", self.late_pruned))  # older checkpoints: none
        self.hidden_pruned = int(state.get("hidden_pruned", 0))
        self.unseen_pruned = int(state.get("unseen_pruned", 0))
        if state["generator"] is not None:
            device, gstate = state["generator"]
            self.generator = torch.Generator(device=device)
            self.generator.set_state(gstate.cpu())  # a CPU byte tensor even for a CUDA generator

