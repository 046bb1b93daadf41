"""The GOF optimisation loop (paper Sec. 3.3 and implementation details) as a small class.

:class:`Trainer` wires the stage objects together — renderer, losses, densification policy, optimizer,
3D filter, decoupled appearance — and owns checkpoints and the run folder. It holds no policy of its
own: each decision lives in its stage module (``losses``, ``densify``, ``optim``, ``filter3d``).

Run folder layout::

    RUN/config.yaml          resolved configuration (plain data)
    RUN/cameras.json         train/test cameras (world-to-camera, intrinsics)
    RUN/checkpoints/         ckpt_<it>.pt, written atomically, resumable bit-for-bit on CPU
    RUN/point_cloud.ply      final Gaussians (3DGS layout, with GOF's filter_3D column)
    RUN/metrics.json         time, speed, memory, Gaussian count over training, test PSNR/SSIM, snapshots
    RUN/snapshots/iter_<k>/  point_cloud.ply + snapshot.json at each of ``snapshot_iterations``

Snapshots are how 3DGS and GOF report shorter training lengths (e.g. "7k" and "30k"): the model of one
long run saved at iteration ``k``, with the training time up to ``k``, its Gaussian count and its test
PSNR/SSIM. Writing a snapshot (and evaluating it) is not counted as training time and does not change the
run: the parameters at the end are the same bit for bit on CPU.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from .appearance import AppearanceModel
from .checkpoint import (CheckpointError, CheckpointWriter, list_checkpoints, load_newest, numpy_rng_state,
                         plain_rng_state)
from ..core.config import ConfigError, dump_yaml, from_dict, to_dict
from ..data import DataConfig
from .densify import DensifyConfig, Densifier
from .distributed import Ranks
from ..core.devices import MemoryPhases, cudnn_benchmark, peak_memory
from ..core.errors import GofError
from .filter3d import update_filter_3d
from .hidden import hidden_gaussians
from ..data.init_points import initial_point_cloud
from .interrupts import TrainingInterrupted, deferred_interrupt  # noqa: F401 - TrainingInterrupted public here
from ..core.io_utils import ensure_writable_dir, write_json_atomic, write_text_atomic
from ..kernels.binning import TileListSizer
from .loss_monitor import LossSpikeMonitor
from .losses import LossConfig, TrainingLoss
from ..eval.image_metrics import image_metrics, psnr
from ..core.model import Activation, Gaussians
from .multiview import MultiViewTerm
from .near_camera import (in_front_of_cameras, near_camera_bounds, near_camera_census, near_ray_census,
                          stack_cameras, views_seeing)
from .optim import LeanAdam, OptimConfig, make_optimizer, update_learning_rate
from ..rendering.render import DensifyStats, RenderConfig, RenderScratch, render, scene_near, scene_size
from ..core.scene import Scene
from .settings import EXPERIMENTAL_TARGETS, ExperimentalConfig, PerformanceConfig, upgrade_keys
from .step_scalars import IterationScalars, PendingScalars

log = logging.getLogger(__name__)

SCALARS_FLUSH_EVERY = 50  # iterations between reads of the loss terms (a host-device synchronisation)
# names the step's parts in a torch.profiler trace; ~6 µs a stage otherwise (measured on the 2-core box: ~50 µs a step)
_stage = torch.profiler.record_function


class TrainingError(GofError):
    """Training cannot go on (e.g. the loss became NaN); the last good checkpoint is kept."""


INIT_MODES = ("auto", "sfm", "random")


@dataclass
class ModelConfig:
    """Initialisation of the Gaussians (3DGS/GOF: SfM points, else random points in a box).

    ``init``: ``"sfm"`` — the scene's own sparse points (COLMAP ``points3D``, a ``points3d.ply``) or, when it
    has none, points triangulated from the known poses (:mod:`gof_warp.data.sfm`, cached beside the scene);
    ``"random"`` — ``random_init_points`` uniform in ``init_box`` (3DGS's Blender init); ``"auto"`` — as
    ``"sfm"``, but an error naming the fixes when triangulation fails or finds fewer than 100 points (never a
    silent random start: pass ``"random"`` to ask for one).
    ``background_points``: extra points on a sphere around the scene (:func:`background_points`), where the
    cameras look past every initial point — the far background SfM rarely reaches; 0 = none.
    ``surface_points_iter``: in a run that starts from random points, the iteration at which points on the surfaces
    the training views' renders agree on (:func:`gof_warp.training.surface_points.surface_points`) stand in for the
    missing SfM points: from then on they bound each camera as SfM points would (``render.near_from_points``,
    ``densify.near_camera_fraction``), so Gaussians cannot settle right in front of a camera. 0 = never (those two
    stay off without points); runs from measured points ignore it.
    ``random_min_views``: in a run that starts from random points, the points are drawn only where at least this
    many training cameras see them (in their image, in front), and at every densification and late prune the
    Gaussians whose centres fewer training cameras see (beyond their near plane) are removed: the space right in
    front of a camera that no other view constrains, where a random start leaves floaters over held-out views
    (SfM or triangulated points are seen by two views or more by construction). 0 = off; runs from measured points
    ignore it.
    ``random_far_fraction``: in a random start, this fraction of the ``random_init_points`` lies beyond ``init_box``, in
    random directions at distances log-uniform from the box's half-diagonal to 20 × the farthest camera's distance
    (:func:`gof_warp.data.init_points.initial_point_cloud`): a capture with a background (a ground, walls, a far
    horizon) starts with points there, as SfM's would, instead of painting it on Gaussians near the cameras. 0 (3DGS's
    box start) for objects on a plain background.
    """

    sh_degree: int = 3  # spherical-harmonics degree of the colours (0: view-independent)
    init: str = "auto"  # "auto" | "sfm" | "random": where the initial points come from (class docstring)
    init_opacity: float = 0.1  # opacity of every initial Gaussian
    random_init_points: int = 100_000  # used when the scene has no initial points (3DGS Blender: 100k)
    init_box: tuple[float, ...] | None = None  # (xmin, ymin, zmin, xmax, ymax, zmax); None = from cameras
    background_points: int = field(default=0, metadata={"set_by": "experimental.background_points"})
    use_filter_3d: bool = True  # Mip-Splatting 3D smoothing filter, as GOF
    surface_points_iter: int = 0  # random start: iteration whose rendered surfaces stand in for SfM points (0: never)
    random_min_views: int = 2  # random start: points and Gaussians only where this many training cameras see them
    random_far_fraction: float = 0.0  # random start: this fraction of the points beyond init_box, out to the far background

    def __post_init__(self):
        if self.init not in INIT_MODES:
            raise ConfigError(f"model.init must be one of {INIT_MODES}, got {self.init!r}")
        if isinstance(self.surface_points_iter, bool) or not isinstance(self.surface_points_iter, int) \
                or self.surface_points_iter < 0:
            raise ConfigError(f"model.surface_points_iter must be an integer >= 0, got {self.surface_points_iter!r}")
        if isinstance(self.random_min_views, bool) or not isinstance(self.random_min_views, int) \
                or self.random_min_views < 0:
            raise ConfigError(f"model.random_min_views must be an integer >= 0, got {self.random_min_views!r}")
        if isinstance(self.random_far_fraction, bool) or not isinstance(self.random_far_fraction, (int, float)) \
                or not 0.0 <= self.random_far_fraction < 1.0:
            raise ConfigError(f"model.random_far_fraction must be in [0, 1), got {self.random_far_fraction!r}")
        if self.background_points < 0 or self.random_init_points < 1:
            raise ConfigError("model.background_points must be >= 0 and model.random_init_points >= 1")


@dataclass
class TrainConfig:
    """Everything a training run needs; presets in ``configs/*.yaml`` are this, serialised.

    The stage sections (``data``, ``model``, ``render``, ``loss``, ``optim``, ``densify``) hold the settings a
    preset or a user adjusts; ``experimental`` holds alternatives no preset turns on, ``performance`` overrides of
    speed decisions (:mod:`gof_warp.training.settings`). Both are copied into the stage configs on construction.
    Keys of older configs are moved with a warning (:func:`gof_warp.training.settings.upgrade_keys`).
    """

    iterations: int = 30_000  # training iterations (steps)
    # seeds everything random in the run: view order, initial points, random backgrounds, densification's samples
    seed: int = 0
    appearance: bool = False  # decoupled appearance (GOF: on for DTU and Tanks and Temples)
    checkpoint_every: int = 5000  # iterations between checkpoints; 0 = none
    checkpoint_keep: int = 2  # newest checkpoints kept in RUN/checkpoints
    log_every: int = 100  # iterations between log lines
    snapshot_iterations: list[int] = field(default_factory=list)  # save the model at these iterations (module doc)
    views_per_step: int = 0  # views averaged in one step; 0: one per process (gof_warp.training.distributed)
    # render each training view on a random background colour (3DGS's --random_background) instead of the scene's,
    # so that a partly transparent surface cannot imitate the fixed background. Alpha-composited targets (Blender
    # cut-outs) are composited again on the same colour; opaque images stay as they are. Default false
    random_background: bool = False
    data: DataConfig = field(default_factory=DataConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    performance: PerformanceConfig = field(default_factory=PerformanceConfig)
    experimental: ExperimentalConfig = field(default_factory=ExperimentalConfig)

    upgrade_keys = staticmethod(upgrade_keys)

    def __post_init__(self):
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, int) or self.iterations < 1:
            raise ConfigError(f"iterations must be an integer >= 1, got {self.iterations!r}")
        snaps = list(self.snapshot_iterations)
        valid = all(isinstance(k, int) and not isinstance(k, bool) and 0 < k < self.iterations for k in snaps)
        if not valid or snaps != sorted(set(snaps)):
            raise ConfigError(f"snapshot_iterations must be increasing, unique iterations in [1, iterations - 1] "
                              f"(iterations = {self.iterations}), got {snaps}")
        for key in ("views_per_step", "checkpoint_every", "checkpoint_keep", "log_every"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ConfigError(f"{key} must be an integer >= 0, got {v!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"seed must be an integer >= 0, got {self.seed!r}")
        # the sections' copies (fields marked set_by): one place for each setting
        copies: dict[str, dict] = {}
        for key, (section, name) in EXPERIMENTAL_TARGETS.items():
            copies.setdefault(section, {})[name] = getattr(self.experimental, key)
        copies.setdefault("optim", {}).update(self.performance.optim_fields())
        copies.setdefault("densify", {})["seed"] = self.seed
        for section, values in copies.items():
            current = getattr(self, section)
            if any(getattr(current, k) != v or getattr(current, k) is not v for k, v in values.items()):
                setattr(self, section, dataclasses.replace(current, **values))


def initial_gaussians(scene: Scene, cfg: ModelConfig, seed: int, device) -> tuple[Gaussians, dict, np.ndarray | None]:
    """The first Gaussians (:func:`gof_warp.data.init_points.initial_point_cloud` decides where), what was used, and the
    scene's or triangulated points among them (``[P, 3]``; None for a random start)."""
    points, colours, info = initial_point_cloud(scene, cfg.init, random_points=cfg.random_init_points,
                                                init_box=cfg.init_box, background=cfg.background_points, seed=seed,
                                                min_views=cfg.random_min_views if cfg.init == "random" else 0,
                                                far_fraction=cfg.random_far_fraction)
    log.info("initial points: %d from %s%s", info["points"], info["source"],
             f" + {info['background_points']} background" if info.get("background_points") else "")
    measured = None if info["source"] == "random" else points[:info["points"]]
    return Gaussians.from_points(points, colours, sh_degree=cfg.sh_degree, init_opacity=cfg.init_opacity,
                                 device=device), info, measured


def scene_fingerprint(scene: Scene) -> dict:
    """What identifies the scene a run is trained on: its format, its numbers of train and test views, and a
    SHA-256 over the format, the views' names and every camera's parameters (intrinsics, pose, image size;
    rounded to 9 significant digits). A checkpoint records it; :meth:`Trainer.resume` compares it."""
    def cams(views):
        out = []
        for v in views:
            d = v.camera.to_dict()
            d.pop("near", None)  # the trainer may set near planes itself (render.near_from_points)
            out.append({k: (np.round(np.asarray(x, dtype=np.float64), 9).tolist() if k in ("R", "t") else
                            float(f"{x:.9g}") if isinstance(x, float) else x) for k, x in d.items()}
                       | {"view": v.name})
        return sorted(out, key=lambda c: (str(c["view"]), str(c["name"])))

    body = json.dumps({"format": scene.format, "train": cams(scene.train), "test": cams(scene.test)}, sort_keys=True)
    return {"format": scene.format, "train_views": len(scene.train), "test_views": len(scene.test),
            "sha256": hashlib.sha256(body.encode()).hexdigest()}


#: the keys of a checkpoint that :meth:`Trainer.load_state_dict` reads (others are optional)
CHECKPOINT_KEYS = ("iteration", "elapsed", "config", "params", "max_sh_degree", "active_sh_degree", "filter_3d",
                   "optimizer", "densifier", "appearance", "appearance_optimizer", "view_rng", "view_stack",
                   "torch_rng", "cuda_rng", "history")


def _scene_near_plane(config: TrainConfig, scene: Scene) -> TrainConfig:
    """``config`` with ``render.near`` fitted to the scene (:func:`~gof_warp.rendering.render.scene_near`): the
    default 0.2 is scaled down for a scene smaller than 1 unit; a larger explicit value is warned about. The run's
    config.yaml records the value used, so extraction and resuming use the same plane."""
    size = scene_size(scene.extent, scene.train_cameras, scene.points)
    near, warning = scene_near(config.render.near, size)
    if warning:
        log.warning("warning: %s", warning)
    if near == config.render.near:
        return config
    log.info("render.near %g for this scene of size %.3g (0.2 is larger than the scene; set render.near to choose)",
             near, size)
    return dataclasses.replace(config, render=dataclasses.replace(config.render, near=near))


def _image_tensor(image: np.ndarray, device) -> torch.Tensor:
    return torch.from_numpy(image).to(device=device, dtype=torch.float32) / 255.0



#: ``performance.compile_loss="auto"`` compiles only runs at least this long (iterations): compiling costs ~15 s on a
#: fresh machine and saves ~1–2.5 ms per DTU iteration on a GPU, so shorter runs would spend more on compiling than
#: they save (benchmarks/RESULTS.md).
AUTO_COMPILE_MIN_ITERATIONS = 10_000


def compile_mode(config: TrainConfig) -> str:
    """``config.performance.compile_loss`` with ``"auto"`` resolved for the run's length: ``"off"`` below
    :data:`AUTO_COMPILE_MIN_ITERATIONS` iterations (``TrainingLoss`` itself keeps ``"auto"`` eager off CUDA)."""
    mode = config.performance.compile_loss
    if mode == "auto" and config.iterations < AUTO_COMPILE_MIN_ITERATIONS:
        return "off"
    return mode


class Trainer:
    """One training run on one scene, writing into ``out_dir``.

    Args:
        scene: the loaded :class:`~gof_warp.core.scene.Scene`.
        config: the resolved :class:`TrainConfig`.
        out_dir: the run folder (created; must be writable).
        device: torch device string.
    """

    def __init__(self, scene: Scene, config: TrainConfig, out_dir, device: str, scene_path=None,
                 ranks: Ranks | None = None):
        config = _scene_near_plane(config, scene)
        self.scene, self.config, self.device = scene, config, torch.device(device)
        self.ranks = Ranks.single() if ranks is None else ranks
        self.views_per_step = config.views_per_step or self.ranks.world
        if self.views_per_step % self.ranks.world:
            raise GofError(f"views_per_step = {self.views_per_step} does not divide among {self.ranks.world} processes")
        self.scene_path = None if scene_path is None else str(Path(scene_path).resolve())
        self.scene_fingerprint = scene_fingerprint(scene)
        self.out_dir = ensure_writable_dir(out_dir)
        self.render_config = dataclasses.replace(config.render, background=tuple(float(c) for c in scene.background))
        self.render_config.validate()
        self.cameras = scene.train_cameras
        self.images = [_image_tensor(v.image, self.device) for v in scene.train]
        # per view, 1 − alpha [H, W, 1] of images composited from alpha (random_background recomposites them)
        self._transparency = [None] * len(scene.train)
        if config.random_background and scene.format == "blender":
            self._transparency = [None if v.mask is None or int(v.mask.min()) == 255 else
                                  1.0 - _image_tensor(v.mask[..., None], self.device) for v in scene.train]
        self.iteration = 0
        self.elapsed = 0.0
        self.history: list[dict] = []
        self.snapshots: list[dict] = []  # one record per snapshot written (see write_snapshot)
        self._checkpoints = CheckpointWriter()  # writes in a background thread
        self.warmup_s: float | None = None  # the last _warm_up's time (not training time)
        self.resumed_from: Path | None = None  # the checkpoint resume() loaded
        self.spikes = LossSpikeMonitor()
        self._spikes_read: list[dict] = []  # the listed spikes the last _drain read back (for run's on_spike)
        # tile lists sized without waiting for the GPU each iteration (on the CPU there is nothing to overlap)
        self.tile_lists = (TileListSizer(config.performance.tile_list_margin)
                           if self.device.type == "cuda" and config.performance.tile_list_margin else None)
        # the training renders' scratch arrays, structs and stream wrappers, reused from one render to the next (less
        # host time per render, same results; 268 B a Gaussian held between renders, see RenderScratch). None: made
        # anew per render
        self.render_scratch: RenderScratch | None = RenderScratch()
        self._rng = np.random.default_rng(config.seed)
        self._stack: list[int] = []
        self._pending = PendingScalars()  # iterations whose loss terms are still on the device
        torch.manual_seed(config.seed)
        self.gaussians, self.init_info, init_points = initial_gaussians(scene, config.model, config.seed, self.device)
        # a random start: surface points from the renders at model.surface_points_iter stand in for SfM points
        self._surface_points: np.ndarray | None = None
        self._surface_points_at = (config.model.surface_points_iter
                                   if init_points is None and config.model.surface_points_iter
                                   and (config.render.near_from_points > 0 or config.densify.near_camera_fraction > 0)
                                   else 0)
        self._camera_near_planes(init_points)
        self._in_front = self._near_camera_rule(init_points)
        self._unseen = self._unseen_rule(init_points)
        if config.model.use_filter_3d:
            update_filter_3d(self.gaussians, self.cameras, near=self.render_config.near)
        self.optimizer = make_optimizer(self.gaussians, config.optim, scene.extent)
        self.densifier = Densifier(config.densify)
        hid = config.densify
        self._hidden = (lambda: hidden_gaussians(self.gaussians, self.cameras, margin=hid.hidden_margin,
                                                 max_visible=hid.hidden_max_visible, min_tail=hid.hidden_min_tail,
                                                 config=self.render_config)) if hid.hidden_prune_iters else None
        late = sorted(i for i in hid.hidden_prune_iters if i > config.iterations)
        if late:  # e.g. the unbounded preset's 15k-29k prunes in a shorter run: said, not silently skipped
            log.info("densify.hidden_prune_iters %s lie beyond this run's %d iterations: %s", late, config.iterations,
                     "no hidden prune in it" if len(late) == len(hid.hidden_prune_iters) else "those prunes do not run")
        self.appearance = None
        self.appearance_optimizer = None
        if config.appearance:
            self.appearance = AppearanceModel(len(scene.all_views)).to(self.device)
            self.appearance_optimizer = LeanAdam([
                {"params": self.appearance.embedding.parameters(), "lr": config.optim.appearance_embedding_lr},
                {"params": [p for n, p in self.appearance.named_parameters() if not n.startswith("embedding")],
                 "lr": config.optim.appearance_network_lr},
            ], **config.optim.adam_kwargs(self.device))
        # the loss with the appearance's L1 pair (camera i's embedding is row i), compiled as one graph where asked
        self.loss = TrainingLoss(config.loss, self.cameras, self.device, compile_mode(config),
                                 cuda_graphs=config.performance.loss_cuda_graphs, appearance=self.appearance)
        # the multi-view photometric term (experimental.multiview, off by default), beside the loss and compiled where it is
        self.multiview = (MultiViewTerm(config.loss.multiview, self.cameras, self.images, config.seed,
                                        compile_backend="inductor" if self.loss.compiled is not None else None,
                                        views_per_step=self.views_per_step)
                          if config.loss.multiview.on else None)
        # the Gaussians' activations (normalised quaternions, filtered scales and opacities: ~40 elementwise kernels
        # over N forward and backward, eager) as one compiled kernel each way wherever the loss is compiled (CUDA)
        self.activation = Activation(self.loss.compiled is not None and self.device.type == "cuda",
                                     strict=self.loss.mode != "auto")
        if self.multiview is not None and self.ranks.active:
            log.warning("experimental.multiview with %d processes: each tests occlusion against the depths of the views it "
                        "rendered, so the run is not the one-process run's up to summation order", self.ranks.world)

    # ------------------------------------------------------------------ one iteration
    def _next_view(self) -> int:
        """GOF's sampling: pop a random view from a stack that is refilled when empty."""
        if not self._stack:
            self._stack = self._rng.permutation(len(self.cameras)).tolist()
        return self._stack.pop()

    def step(self) -> dict:
        """Run iteration ``self.iteration + 1``; returns its loss terms, PSNR and Gaussian count (floats)."""
        self._pending.add(*self._step())
        return self._drain()

    def _step(self) -> tuple[IterationScalars, dict[str, torch.Tensor]]:
        """One iteration without reading anything back from the device: its record and its terms as 0-d
        tensors (``l1 … total``, ``psnr``), for :class:`~gof_warp.training.step_scalars.PendingScalars`."""
        cfg = self.config
        it = self.iteration + 1
        if it == self._surface_points_at:
            self._bound_cameras_by_surfaces()
        g = self.gaussians
        update_learning_rate(self.optimizer, it, cfg.optim, self.scene.extent)
        self.densifier.update_sh_degree(it, g)
        mine = self.ranks.my_views([self._next_view() for _ in range(self.views_per_step)])
        terms: dict[str, torch.Tensor] = {}
        for idx in mine:
            for k, v in self._render_view(it, idx).items():  # this rank's mean over its views
                terms[k] = v if k not in terms else terms[k] + v
        terms = terms if len(mine) == 1 else {k: v / len(mine) for k, v in terms.items()}
        if self.ranks.active:  # one process: nothing to sum (and no parameter list to build)
            with _stage("train.all_reduce"):
                self.ranks.sum_gradients(self._trained_params())
        cam = self.cameras[mine[0]]  # the view the spike monitor files the loss under
        if self.render_scratch is not None and self.densifier.count_may_change(it, hidden=self._hidden is not None):
            self.render_scratch.clear()  # its spares are for this count: freed before the densifier allocates
        with torch.no_grad(), _stage("train.densify"):
            if self.densifier.densify_due(it):
                self.ranks.reduce_densify_stats(self.densifier.stats)
            report = self.densifier.step(it, g, self.optimizer, self.scene.extent, near_camera=self._in_front,
                                         hidden=self._hidden, unseen=self._unseen)
            if report.num_hidden:
                log.info("iteration %d: removed %d Gaussians hidden behind the rendered surface", it, report.num_hidden)
            if len(g) == 0:
                raise TrainingError(f"every Gaussian was pruned at iteration {it}: check the scene's near plane "
                                    "(render.near), background colour and densify.min_opacity")
            if cfg.model.use_filter_3d and report.filter_3d_due:
                update_filter_3d(g, self.cameras, near=self.render_config.near)
        with _stage("train.optimizer"):
            self.optimizer.step()
            self.optimizer.zero_grad(set_to_none=True)
            if self.appearance_optimizer is not None:
                self.appearance_optimizer.step()
                self.appearance_optimizer.zero_grad(set_to_none=True)
        self.iteration = it
        # the opacity reset makes every Gaussian transparent, and the regularisers change what the loss
        # measures: a new baseline for the spike monitor, not a spike
        restart = (report.opacity_reset or it == cfg.loss.regularization_from_iter
                   or (self.multiview is not None and it == cfg.loss.multiview.from_iter))
        return IterationScalars(it, cam.name, len(g), restart, self.elapsed, {}), terms

    def _render_view(self, it: int, idx: int) -> dict[str, torch.Tensor]:
        """Render view ``idx``, back-propagate its loss (÷ ``views_per_step``) and gather its densification
        statistics; its detached terms."""
        stats = self._new_stats(it)
        loss, terms = self._view_loss(idx, it, stats)
        with _stage("train.backward"):
            (loss if self.views_per_step == 1 else loss / self.views_per_step).backward()
            if self.views_per_step > 1 and self.loss.cuda_graphs and self.appearance is not None:
                # the appearance's gradients are the graph's outputs, which the next view's replay overwrites
                for p in self.appearance.parameters():
                    p.grad = None if p.grad is None else p.grad.clone()
        if stats is not None:  # per-view gradients, whatever the number of views in the step
            with torch.no_grad():
                self.densifier.after_backward(stats, it, scale=float(self.views_per_step))
        return terms

    def _clear_gradients(self) -> None:
        self.optimizer.zero_grad(set_to_none=True)
        if self.appearance_optimizer is not None:
            self.appearance_optimizer.zero_grad(set_to_none=True)

    def _new_stats(self, it: int) -> DensifyStats | None:
        """Densification statistics for one view of iteration ``it`` (None once they are no longer gathered)."""
        if it >= self.config.densify.stop_iter:
            return None
        return DensifyStats(len(self.gaussians), device=self.device)

    def _view_loss(self, idx: int, loss_it: int, stats: DensifyStats | None):
        """Render view ``idx`` (filling ``stats``) and its loss as at iteration ``loss_it`` (appearance-corrected
        L1 when the model has one): ``(loss, terms)``, the terms detached, with the render's PSNR."""
        cam, gt = self.cameras[idx], self.images[idx]
        render_config = self.render_config
        if self.config.random_background:
            render_config, gt = self._random_background(idx, loss_it, gt)
        with _stage("train.render"):
            out = render(self.gaussians.activated(self.activation), cam, config=render_config, stats=stats,
                         tile_lists=self.tile_lists, scratch=self.render_scratch)
        with _stage("train.loss"):
            loss, terms = self.loss(out, gt, cam, idx, loss_it)
            if self.multiview is not None:
                loss = self._add_multiview(out, idx, loss_it, loss, terms)
            terms["psnr"] = psnr(out["rgb"].detach(), gt)
        return loss, terms

    def _add_multiview(self, out: dict, idx: int, it: int, loss: torch.Tensor, terms: dict) -> torch.Tensor:
        """``loss`` plus the weighted multi-view term of view ``idx`` once it is active (its value into ``terms``
        as ``multiview``); the view's median depth is kept for its neighbours' occlusion tests either way."""
        mv = self.multiview(out, idx, it) if self.multiview.active(it) else None
        self.multiview.remember(idx, out["median_depth"], it)
        if mv is None:
            return loss
        weighted = self.config.loss.multiview.weight * mv[0]
        terms["multiview"] = mv[0].detach()
        terms["total"] = terms["total"] + weighted.detach()
        return loss + weighted

    def _random_background(self, idx: int, it: int, gt: torch.Tensor) -> tuple[RenderConfig, torch.Tensor]:
        """``(render config, target)`` of view ``idx`` at iteration ``it`` on a random background colour, drawn from
        ``(seed, it, idx)`` alone, so a resumed run draws the same colours; an alpha image's target is composited
        again on it (``gt + (1 − α)(bg − scene background)``)."""
        bg = np.random.default_rng([self.config.seed, it, idx]).random(3)
        config = dataclasses.replace(self.render_config, background=tuple(float(c) for c in bg))
        clear = self._transparency[idx]
        if clear is not None:
            shift = torch.tensor(bg - np.asarray(self.render_config.background), dtype=gt.dtype).to(gt.device,
                                                                                                   non_blocking=True)
            gt = gt + clear * shift
        return config, gt

    def _camera_near_planes(self, points: np.ndarray | None) -> None:
        """``render.near_from_points``: give every train and test camera its own near plane (:attr:`Camera.near`),
        that fraction of the depth of the nearest initial point in its image. The trainer's scene and ``cameras``
        are replaced by copies holding them (the caller's scene is left as it was); ``cameras.json`` records
        them, so extraction and pictures clip as training did."""
        fraction = self.render_config.near_from_points
        if fraction <= 0:
            return
        if points is None or len(points) == 0:
            if self._surface_points_at:
                log.info("render.near_from_points: off until iteration %d, then from the rendered surfaces "
                         "(model.surface_points_iter)", self._surface_points_at)
            else:
                log.warning("render.near_from_points is off for this run: it needs SfM or triangulated points, and "
                            "this run starts from random points (model.surface_points_iter takes them from the "
                            "renders)")
            self.init_info["camera_near"] = "off: no initial points"
            return
        views = self.scene.all_views
        bounds = near_camera_bounds(torch.tensor(points, dtype=torch.float64), [v.camera for v in views], fraction)
        placed = [dataclasses.replace(v, camera=dataclasses.replace(v.camera, near=float(b)))
                  for v, b in zip(views, bounds.tolist())]
        n = len(self.scene.train)
        self.scene = dataclasses.replace(self.scene, train=placed[:n], test=placed[n:])
        self.cameras = self.scene.train_cameras
        clip = [self.render_config.clip_near(v.camera) for v in placed]
        log.info("per-camera near planes %.3g–%.3g (fraction %g of the nearest initial point; render.near %g)",
                 min(clip), max(clip), fraction, self.render_config.near)
        self.init_info["camera_near"] = {"fraction": fraction, "min": round(min(clip), 4), "max": round(max(clip), 4)}

    def _bound_cameras_by_surfaces(self, points: np.ndarray | None = None) -> None:
        """``model.surface_points_iter``: the points on the surfaces the training views agree on now (or ``points``,
        from a checkpoint) bound the cameras as SfM points would (near planes, near-camera prune); ``cameras.json``
        is rewritten with the new near planes."""
        from .surface_points import surface_points

        if points is None:
            points = surface_points(self.gaussians, self.cameras, self.render_config)
            log.info("iteration %d: %d points on the surfaces the training views agree on bound the cameras",
                     self.iteration + 1, len(points))
        self._surface_points = np.asarray(points, np.float64)
        self.init_info["surface_points"] = {"iteration": self._surface_points_at, "points": int(len(points))}
        if len(points) == 0:
            log.warning("model.surface_points_iter: the renders agree on no surface; the cameras stay unbounded")
            return
        self._camera_near_planes(self._surface_points)
        self._in_front = self._near_camera_rule(self._surface_points)
        if self.ranks.is_main:
            self._write_static_files()

    def _near_camera_rule(self, points: np.ndarray | None) -> Callable[[], torch.Tensor] | None:
        """``densify.near_camera_fraction``'s test as a callable for the densifier (None when off): the Gaussians
        that a training camera's rays meet nearer than that fraction of its nearest initial point."""
        fraction = self.config.densify.near_camera_fraction
        if fraction <= 0:
            return None
        if points is None or len(points) == 0:  # a random start
            if not self._surface_points_at:
                log.warning("densify.near_camera_fraction is off for this run: it bounds each camera by its nearest "
                            "SfM or triangulated point, and this run starts from random points "
                            "(model.surface_points_iter takes them from the renders)")
            self.init_info["near_camera_prune"] = "off: no initial points"
            return None
        stack = stack_cameras(self.cameras, self.device)
        bounds = near_camera_bounds(torch.tensor(points, dtype=torch.float64), self.cameras, fraction).to(self.device)
        log.info("near-camera prune: %d cameras, bounds %.3g–%.3g (fraction %g of the nearest initial point)",
                 len(self.cameras), float(bounds.min()), float(bounds.max()), fraction)
        self.init_info["near_camera_prune"] = {"fraction": fraction, "bound_min": round(float(bounds.min()), 4),
                                               "bound_max": round(float(bounds.max()), 4)}
        rc = self.render_config

        def in_front() -> torch.Tensor:
            g = self.gaussians
            return in_front_of_cameras(g.means, g.quats, g.scales, g.opacities, stack, bounds, near=rc.near,
                                       alpha_min=rc.alpha_min, alpha_max=rc.alpha_max)
        return in_front

    def _unseen_rule(self, points: np.ndarray | None) -> Callable[[], torch.Tensor] | None:
        """``model.random_min_views``' test for a random start (None for a run from points, or when 0): the
        Gaussians whose centres fewer than that many training cameras hold in their image beyond their near plane."""
        k = self.config.model.random_min_views
        if points is not None or k <= 0:
            return None
        self.init_info["unseen_prune"] = {"min_views": k}

        def unseen() -> torch.Tensor:  # the cameras are read at each call: surface_points_iter may set near planes
            stack = stack_cameras(self.cameras, self.device)
            near = torch.tensor([self.render_config.clip_near(c) for c in self.cameras], dtype=torch.float64)
            means = self.gaussians.means
            # a non-finite centre is left to the loss's NaN check, which names the iteration it came from
            return (views_seeing(means, stack, near) < k) & torch.isfinite(means).all(dim=1)
        return unseen

    def view_index(self, name: str) -> int | None:
        """Index in ``cameras``/``images`` of the training view called ``name`` (None: no such view)."""
        return next((i for i, c in enumerate(self.cameras) if c.name == name), None)

    def _near_census(self, view: str, spike_iteration: int) -> dict | None:
        """:func:`near_camera_census` (centres) and :func:`near_ray_census` (``"rays"``: what its rays meet) of the
        camera named ``view`` within a quarter of the scene extent, taken when the spike is read back
        (``iteration``: up to ``SCALARS_FLUSH_EVERY`` iterations after the spike)."""
        idx = self.view_index(view)
        if idx is None:
            return None
        g, rc, within = self.gaussians, self.render_config, 0.25 * self.scene.extent
        census = near_camera_census(g.means, g.opacities, g.scales, self.cameras[idx], within=within,
                                    min_opacity=rc.alpha_min)
        rays = near_ray_census(g.means, g.quats, g.scales, g.opacities, self.cameras[idx], within=within,
                               near=rc.near, alpha_min=rc.alpha_min, alpha_max=rc.alpha_max)
        return {**census, "rays": rays, "iteration": self.iteration, "spike_iteration": spike_iteration}

    def _trained_params(self) -> list[torch.Tensor]:
        params = list(self.gaussians.params.values())
        return params if self.appearance is None else params + list(self.appearance.parameters())

    def _drain(self) -> dict:
        """Read the queued iterations' terms back (one copy), stop on a non-finite loss, feed the spike monitor
        and the history; returns the newest iteration's values (empty when nothing was queued)."""
        last = {}
        self._spikes_read = []
        for rec in self._pending.flush():
            total = rec.values["total"]
            if not math.isfinite(total):
                raise TrainingError(
                    f"the loss became {total} at iteration {rec.iteration} (view {rec.view!r}); training stopped. "
                    f"The last good checkpoint in {self.out_dir / 'checkpoints'} is kept: lower the learning rates "
                    "or check the input images, then resume with --resume")
            if rec.restart_monitor:
                self.spikes.restart()
            terms = {k: v for k, v in rec.values.items() if k != "psnr"}
            self.spikes.update(rec.iteration, total, rec.view, terms)
            if self.spikes.last_view_spike is not None:  # what sits right in front of that camera now
                self.spikes.last_view_spike["near_camera"] = self._near_census(rec.view, rec.iteration)
                self._spikes_read.append(self.spikes.last_view_spike)
            last = {**rec.values, "num_gaussians": rec.num_gaussians}
            if rec.iteration % self.config.log_every == 0 or rec.iteration == self.config.iterations:
                self.history.append({"iteration": rec.iteration, "elapsed_s": round(rec.elapsed_s, 3),
                                     **{k: round(v, 6) for k, v in last.items()}})
        return last

    # ------------------------------------------------------------------ the run
    def run(self, progress: Callable[[int, dict], None] | None = None,
            on_snapshot: Callable[["Trainer", dict], None] | None = None,
            on_spike: Callable[["Trainer", dict], None] | None = None) -> dict:
        """Train to ``config.iterations``, checkpointing; then evaluate and write the outputs.

        ``on_snapshot(trainer, record)`` is called after each snapshot is written (:meth:`write_snapshot`), e.g.
        to draw its picture; its time is not counted as training time, and it must not change the model.
        ``on_spike(trainer, event)`` likewise for each per-view loss spike the monitor lists (``event``: its entry of
        ``loss_spikes.view_spikes``, which the callback may annotate), when the spike is read back (rank 0 only).

        Ctrl-C during training stops at the end of the current iteration: a checkpoint of that iteration is
        written (atomically, like every checkpoint) and :class:`TrainingInterrupted` is raised; the final
        outputs (``point_cloud.ply``, ``metrics.json``) are not written. :meth:`resume` continues bit-for-bit (with
        ``experimental.multiview`` on, not quite: see :class:`~gof_warp.training.multiview.MultiViewTerm`).
        """
        cfg = self.config
        if self.ranks.is_main:
            self._write_static_files()
        self.memory = MemoryPhases(self.device)
        with cudnn_benchmark(True):  # the warm-up records the loss graphs: it chooses the algorithms
            if self.iteration < cfg.iterations:
                self._warm_up()
            self.memory.end_phase("warm_up")
            with deferred_interrupt() as interrupted:
                last = self._train_loop(progress, interrupted, on_snapshot, on_spike)
        train_time = self.elapsed
        if not self.ranks.is_main:  # rank 0 writes the run folder
            return {"iterations": cfg.iterations, "train_time_s": round(train_time, 3), "rank": self.ranks.rank}
        self.save_checkpoint(wait=True)
        self.gaussians.save_ply(self.out_dir / "point_cloud.ply")
        metrics = {
            "iterations": cfg.iterations,
            "train_time_s": round(train_time, 3),
            "its_per_s": round(cfg.iterations / train_time, 3) if train_time > 0 else None,
            "warmup_s": None if self.warmup_s is None else round(self.warmup_s, 3),
            "num_gaussians": len(self.gaussians),
            "device": str(self.device),
            "processes": self.ranks.world,
            "views_per_step": self.views_per_step,
            **{k: round(v, 1) for k, v in peak_memory(self.device).items()},
            **self.memory.overall(),  # the peaks over all phases (torch's counters restart at each phase)
            # per phase: warm_up (compiling, graph capture), densify (to densify.stop_iter), after (to the end)
            "memory_phases": self.memory.phases or None,
            "final_train_psnr": round(last.get("psnr", float("nan")), 3) if last else None,
            "test": self.evaluate(),
            "loss_spikes": self.spikes.report(),
            # Gaussians removed after densification (densify.late_prune_interval; None: off, GOF's schedule)
            "late_pruned": dict(self.densifier.late_pruned) if cfg.densify.late_prune_interval else None,
            # Gaussians removed as hidden behind the rendered surface (densify.hidden_prune_iters; None: off)
            "hidden_pruned": self.densifier.hidden_pruned if cfg.densify.hidden_prune_iters else None,
            # Gaussians too few training cameras saw (a random start's model.random_min_views; None: off)
            "unseen_pruned": self.densifier.unseen_pruned if self._unseen is not None else None,
            # calls, exact measurements, overflows (renders that dropped entries: see kernels.binning.TileListSizer)
            "tile_lists": None if self.tile_lists is None else self.tile_lists.stats(),
            "loss_compiled": self.loss.compiled is not None, "loss_compile_fallback": self.loss.fallback_reason,
            "activations_compiled": self.activation.compiled,
            "activations_compile_fallback": self.activation.fallback_reason,
            "init": self.init_info,
            "snapshots": self.snapshots,
            "history": self.history,
        }
        write_json_atomic(self.out_dir / "metrics.json", metrics)
        self._warn_about_overflows()
        return metrics

    def _warn_about_overflows(self) -> None:
        """Say so when renders dropped tile-list entries (their images, and those steps, were missing Gaussians)."""
        s = self.tile_lists
        if s is not None and s.overflows:
            log.warning("%d of %d training renders overflowed their tile lists and dropped some Gaussians' entries "
                        "(metrics.json -> tile_lists); a larger performance.tile_list_margin (now %g) or 0 (exact sizing, one "
                        "synchronisation per render) avoids it", s.overflows, s.calls, s.margin)

    def _warm_up(self, started: float | None = None) -> None:
        """A throw-away forward and backward pass of one training view before the clock starts: it loads the
        renderer's Warp modules and lets torch set up its libraries (first-call costs of ~6 s on a GPU that
        would otherwise land in the first iterations' time; reported apart as ``warmup_s``), and compiles both
        graphs of a compiled loss (``compile_loss``; a failure there makes ``"auto"`` fall back to the eager
        loss, and the pass is repeated). It changes nothing that training reads: no optimiser step, no
        densification statistics kept, no random numbers drawn, and the gradients it leaves are cleared, so a run with it is bitwise the run without it.
        With several ranks it ends at a barrier, so that every rank's clock starts when all are ready."""
        t = time.perf_counter() if started is None else started
        it = self.iteration + 1
        regularised = max(it, self.config.loss.regularization_from_iter)  # the regularisers' kernels too
        if self.multiview is not None:  # and the multi-view term's, once it acts
            regularised = max(regularised, self.config.loss.multiview.from_iter)
        schedule = [regularised] + ([it] if self.loss.compiled is not None and it < regularised else [])
        if self.multiview is not None:  # the multi-view term's graphs too (compiled along with the loss)
            self.multiview.prime()
        for loss_it in schedule:  # a compiled loss: both of its graphs (with and without the regularisers)
            loss, _ = self._view_loss(0, loss_it, self._new_stats(it))
            try:
                loss.backward()  # the compiled loss's backward graph is built here
            except Exception as e:  # noqa: BLE001 - "auto" falls back to the eager loss; anything else is raised
                if self.loss.compiled is None or self.loss.mode != "auto":
                    raise
                self.loss.give_up(e)
                self.activation.give_up(e)  # compiled with the loss: its backward, built here too, may be what failed
                if self.multiview is not None:  # its backward, compiled at the same call, may be what failed
                    self.multiview.give_up(e)
                self._clear_gradients()
                return self._warm_up(t)
            self._clear_gradients()  # each pass on its own (CUDA-graph gradients last until the next replay)
        if self.multiview is not None:  # the throw-away render's depth is not one training made
            self.multiview.forget()
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        # the ranks start the clock together: the first collective also sets up NCCL's communicators, which in the
        # first step would count that and the ranks' different start-up times as training time
        self.ranks.barrier()
        self.warmup_s = time.perf_counter() - t

    def _train_loop(self, progress, interrupted: Callable[[], bool], on_snapshot=None, on_spike=None) -> dict:
        """Iterate to ``config.iterations`` (history, progress, snapshots, checkpoints); the last step's terms."""
        cfg = self.config
        t0 = time.perf_counter() - self.elapsed
        last = {}
        snapshot_at = set(cfg.snapshot_iterations)
        while self.iteration < cfg.iterations:
            record, terms = self._step()
            it = self.iteration
            self.elapsed = record.elapsed_s = time.perf_counter() - t0
            self._pending.add(record, terms)
            checkpoint_due = cfg.checkpoint_every > 0 and it % cfg.checkpoint_every == 0 and it < cfg.iterations
            if (len(self._pending) >= SCALARS_FLUSH_EVERY or it % cfg.log_every == 0 or it == cfg.iterations
                    or it in snapshot_at or checkpoint_due):
                last = self._drain()  # waits for the GPU: the time now includes the queued work
                self.elapsed = time.perf_counter() - t0
                self.memory.sample()
                if self._spikes_read and on_spike is not None and self.ranks.is_main:
                    t_spike = time.perf_counter()
                    for event in self._spikes_read:
                        on_spike(self, event)
                    t0 += time.perf_counter() - t_spike  # not training time
            if progress is not None:
                progress(it, {**last, "num_gaussians": len(self.gaussians),
                              "its_per_s": it / self.elapsed if self.elapsed > 0 else math.nan})
            if self.ranks.active and cfg.performance.checksum_every and it % cfg.performance.checksum_every == 0:
                self.ranks.check_identical(self.gaussians.params, it)
            if it in snapshot_at and self.ranks.is_main:  # before the checkpoint of the same iteration, which records it
                t_snap = time.perf_counter()
                record = self.write_snapshot()
                if on_snapshot is not None:
                    on_snapshot(self, record)
                t0 += time.perf_counter() - t_snap  # not training time
            if it == cfg.densify.stop_iter or it == cfg.iterations:
                self.memory.end_phase("densify" if it == cfg.densify.stop_iter else "after")
            if checkpoint_due:
                self.save_checkpoint()
            if interrupted():
                self._drain()
                raise self._interrupted(getattr(interrupted, "signum", None))
        return last

    def _interrupted(self, signum: int | None = None) -> TrainingInterrupted:
        """Checkpoint the current iteration (unless just done) for an interrupt (``signum``: the signal, SIGINT
        when None); the exception to raise."""
        self._checkpoints.wait()
        found = list_checkpoints(self.out_dir)
        path = found[-1][1] if found else None
        if not found or found[-1][0] != self.iteration:
            try:
                path = self.save_checkpoint(wait=True)
            except TrainingError as e:  # NaN parameters: keep the previous checkpoint, say why
                log.warning("%s", e)
        return TrainingInterrupted(self.iteration, self.config.iterations, path,
                                   signal.SIGINT if signum is None else signum)

    @torch.no_grad()
    def evaluate(self, views=None) -> dict:
        """PSNR/SSIM (LPIPS when its weights are present locally) on the test views (train if none)."""
        views = list(self.scene.test if views is None else views)
        split = "test"
        if not views:
            views, split = list(self.scene.train), "train (no test views)"
        preds, gts, masks = [], [], None
        for v in views:
            out = render(self.gaussians, v.camera, config=self.render_config)
            preds.append(out["rgb"].clamp(0, 1).permute(2, 0, 1))
            gts.append(_image_tensor(v.image, self.device).permute(2, 0, 1))
        result = image_metrics(preds, gts, masks)
        return {"split": split, "views": len(views), **result}

    def write_snapshot(self) -> dict:
        """Save the model as it is now into ``RUN/snapshots/iter_<k>/`` (``point_cloud.ply``, the final PLY's
        writer, and ``snapshot.json``: ``iteration``, ``train_time_s`` up to now, ``num_gaussians``, ``test``
        PSNR/SSIM, ``path`` of the PLY relative to the run folder), atomically; returns that record, which
        is also kept in :attr:`snapshots` (a snapshot of the same iteration, from a resumed run, is replaced)."""
        folder = Path("snapshots") / f"iter_{self.iteration}"
        self.gaussians.save_ply(self.out_dir / folder / "point_cloud.ply")
        record = {"iteration": self.iteration, "train_time_s": round(self.elapsed, 3),
                  "num_gaussians": len(self.gaussians), "test": self.evaluate(),
                  "path": (folder / "point_cloud.ply").as_posix()}
        write_json_atomic(self.out_dir / folder / "snapshot.json", record)
        self.snapshots = sorted([s for s in self.snapshots if s["iteration"] != self.iteration] + [record],
                                key=lambda s: s["iteration"])
        log.info("snapshot at iteration %d: %d Gaussians, %.1f s of training", self.iteration, len(self.gaussians),
                 self.elapsed)
        return record

    # ------------------------------------------------------------------ files and checkpoints
    def _write_static_files(self):
        write_text_atomic(self.out_dir / "config.yaml", dump_yaml(self.config))
        cams = {split: [v.camera.to_dict() for v in views]
                for split, views in (("train", self.scene.train), ("test", self.scene.test))}
        write_json_atomic(self.out_dir / "cameras.json", {"convention": "world-to-camera, OpenCV axes", **cams,
                                                          "extent": self.scene.extent, "scene": self.scene_path})

    def state_dict(self) -> dict:
        """Everything :meth:`load_state_dict` needs to continue bit-for-bit, as plain data (tensors, numbers,
        strings, None, lists/tuples/dicts: what ``torch.load(weights_only=True)`` reads back; see
        :mod:`gof_warp.training.checkpoint`)."""
        g = self.gaussians
        return {
            "iteration": self.iteration,
            "elapsed": self.elapsed,
            "config": to_dict(self.config),
            "params": {k: v.detach().clone() for k, v in g.params.items()},
            "max_sh_degree": g.max_sh_degree,
            "active_sh_degree": g.active_sh_degree,
            "filter_3d": None if g.filter_3d is None else g.filter_3d.clone(),
            "optimizer": self.optimizer.state_dict(),
            "densifier": self.densifier.state_dict(),
            "appearance": None if self.appearance is None else self.appearance.state_dict(),
            "appearance_optimizer": None if self.appearance_optimizer is None else self.appearance_optimizer.state_dict(),
            "view_rng": plain_rng_state(self._rng.bit_generator.state),
            "view_stack": list(self._stack),
            "torch_rng": torch.get_rng_state(),
            "cuda_rng": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else None,
            "history": list(self.history),
            "snapshots": list(self.snapshots),
            "loss_spikes": self.spikes.state_dict(),
            "tile_lists": None if self.tile_lists is None else self.tile_lists.state_dict(),
            "scene_fingerprint": dict(self.scene_fingerprint),
            "surface_points": None if self._surface_points is None else torch.from_numpy(self._surface_points.copy()),
        }

    def load_state_dict(self, state: dict) -> None:
        p = state["params"]
        self.gaussians = Gaussians(**{k: v.to(self.device) for k, v in p.items()}, max_sh_degree=state["max_sh_degree"],
                                   active_sh_degree=state["active_sh_degree"],
                                   filter_3d=None if state["filter_3d"] is None else state["filter_3d"].to(self.device))
        self.optimizer = make_optimizer(self.gaussians, self.config.optim, self.scene.extent)
        self.optimizer.load_state_dict(state["optimizer"])
        self.densifier.load_state_dict(state["densifier"])
        if self.appearance is not None and state["appearance"] is not None:
            self.appearance.load_state_dict(state["appearance"])
            self.appearance_optimizer.load_state_dict(state["appearance_optimizer"])
        self._rng.bit_generator.state = numpy_rng_state(state["view_rng"])
        self._stack = list(state["view_stack"])
        torch.set_rng_state(state["torch_rng"].cpu())  # RNG states are CPU byte tensors, whatever map_location did
        if state["cuda_rng"] is not None and torch.cuda.is_available():
            torch.cuda.set_rng_state_all([s.cpu() for s in state["cuda_rng"]])
        self.history = list(state["history"])
        self.snapshots = list(state.get("snapshots", []))  # checkpoints written before snapshots existed have none
        if state.get("loss_spikes") is not None:
            self.spikes.load_state_dict(state["loss_spikes"])
        if self.tile_lists is not None and state.get("tile_lists") is not None:  # counters over the whole run
            self.tile_lists.load_state_dict(state["tile_lists"])
        self.iteration = int(state["iteration"])
        self.elapsed = float(state["elapsed"])
        if state.get("surface_points") is not None:  # the cameras were bounded by the renders' surfaces
            self._bound_cameras_by_surfaces(state["surface_points"].cpu().double().numpy())

    def save_checkpoint(self, wait: bool = False) -> Path | None:
        """Write ``RUN/checkpoints/ckpt_<it>.pt`` (rank 0 only: other ranks return None) in the background
        (:class:`~gof_warp.training.checkpoint.CheckpointWriter`: the state is copied to host memory first, so training
        may go on); ``wait=True`` returns once the file is in place."""
        if not self.ranks.is_main:
            return None
        for name, t in self.gaussians.params.items():
            if not torch.isfinite(t).all():
                raise TrainingError(f"parameter {name} has NaN/inf at iteration {self.iteration}; checkpoint not written "
                                    "(the previous one is kept)")
        path = self._checkpoints.submit(self.out_dir, self.iteration, self.state_dict(), keep=self.config.checkpoint_keep)
        if wait:
            self._checkpoints.wait()
        return path

    def resume(self) -> int:
        """Load the newest usable checkpoint of ``out_dir``; returns its iteration.

        A newer checkpoint that cannot be read (truncated, corrupt, refused as unsafe) is renamed to
        ``<name>.corrupt`` and named in a warning with the one used instead
        (:func:`gof_warp.training.checkpoint.load_newest`); :attr:`resumed_from` is the file loaded. :class:`GofError`
        when the checkpoint lacks an entry, lies beyond ``config.iterations``, was written with another config,
        or on another scene (:func:`scene_fingerprint`; checkpoints without one are not compared).
        """
        state, self.resumed_from = load_newest(self.out_dir, map_location=self.device, set_aside=self.ranks.is_main)
        self._check_checkpoint(state, self.resumed_from)
        saved = to_dict(from_dict(TrainConfig, state["config"], "checkpoint config"))
        now = to_dict(self.config)
        for key in ("iterations", "snapshot_iterations"):  # training may be extended on resume, and snapshots
            saved.pop(key, None)  # do not change the training
            now.pop(key)
        if saved != now:
            diff = sorted(k for k in now if now[k] != saved.get(k))
            raise GofError(f"the checkpoint in {self.out_dir} was written with a different config (sections {diff}); "
                           "resume with the same config (RUN/config.yaml) or start a new run")
        self.load_state_dict(state)
        return self.iteration

    def _check_checkpoint(self, state: dict, path: Path) -> None:
        """:class:`GofError` when the checkpoint ``state`` (read from ``path``) cannot continue this run."""
        missing = [k for k in CHECKPOINT_KEYS if k not in state]
        if missing:
            raise CheckpointError(f"checkpoint {path} lacks the entr{'y' if len(missing) == 1 else 'ies'} "
                                  f"{', '.join(repr(k) for k in missing)}: it is not a complete gof_warp checkpoint")
        it = state["iteration"]
        if isinstance(it, bool) or not isinstance(it, int) or it < 0:
            raise CheckpointError(f"checkpoint {path} holds the iteration {it!r}, not a count of iterations")
        if it > self.config.iterations:
            raise GofError(f"checkpoint {path} is at iteration {it}, beyond this run's {self.config.iterations} "
                           f"iterations: pass --iterations {it} or more to continue it")
        saved = state.get("scene_fingerprint")
        if isinstance(saved, dict) and saved.get("sha256") != self.scene_fingerprint["sha256"]:
            now = self.scene_fingerprint
            raise GofError(f"the checkpoint {path} was trained on another scene ({saved.get('format')!r}, "
                           f"{saved.get('train_views')} train / {saved.get('test_views')} test views) than this one "
                           f"({now['format']!r}, {now['train_views']} train / {now['test_views']} test views, other "
                           "cameras or view names): resume with the scene the run was trained on, or start a new run")


def has_checkpoints(run_dir) -> bool:
    return bool(list_checkpoints(run_dir))
