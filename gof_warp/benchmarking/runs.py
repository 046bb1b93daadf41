"""The pieces of a benchmark run, shared by the benchmark suites (:mod:`gof_warp.cli.bench`) and the stability
suite (:mod:`gof_warp.benchmarking.stability`): extraction methods and runs as plain data, GOF's schedule compressed to a run's
length, the run's scene folder and resolved config, and training a run (or reusing its trained model).
Library code: it imports no command-line module.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

from .report import peak_memory, reset_peak_memory
from ..core.errors import GofError

log = logging.getLogger("gof_warp.benchmarking")  # one logger for the harness


@dataclass(frozen=True)
class Method:
    """One extraction configuration; ``name`` is its key in the results table (method ``none``: no mesh)."""

    name: str
    method: str  # tetra | cubes | tsdf | none
    binary_steps: int = 0
    resolution: int | None = None  # grid resolution (cubes, tsdf)

    def mesh_config(self):
        from ..mesh.extraction import MeshConfig

        cfg = MeshConfig(method=self.method, binary_steps=self.binary_steps)
        if self.resolution:
            cfg.cubes_resolution = self.resolution
            cfg.tsdf.resolution = self.resolution
        return cfg


@dataclass(frozen=True)
class Run:
    """One trained model: a synthetic preset at a resolution/view count (or ``real:NAME``), a training config,
    the methods extracted from its last model and, at each of ``snapshots``, from that snapshot;
    ``budget_s`` is the planned cost (training + every extraction and scoring) on the suite's machine.

    ``overrides`` are nested sections of :class:`~gof_warp.training.trainer.TrainConfig` (``{"densify": {...}}``), merged
    into the preset when the run trains; they are checked when the run is defined (:func:`check_overrides`), so
    a typo'd key or a mistyped value is a :class:`~gof_warp.core.config.ConfigError` naming it, not a silent no-op."""

    name: str
    preset: str
    resolution: tuple[int, int]
    views: int | None
    config: str = "quick"  # training preset (configs/NAME.yaml)
    overrides: dict = field(default_factory=dict, hash=False)  # TrainConfig sections, checked on definition
    methods: tuple[Method, ...] = ()
    eval_samples: int | None = None  # GT surface samples for scoring (None: geometry_metrics' default)
    snapshots: tuple[int, ...] = ()  # TrainConfig.snapshot_iterations
    snapshot_methods: tuple[Method, ...] = ()  # extracted at every snapshot
    budget_s: float = 0.0

    def __post_init__(self):
        check_overrides(self.overrides, f"run {self.name}", self.snapshots)


def check_overrides(overrides: dict, where: str, snapshots=()):
    """Check a run's training overrides when the run is defined, not when it trains: every key path must be a
    field of :class:`~gof_warp.training.trainer.TrainConfig` and its stage configs (``{"densify": {"max_gaussians": …}}``)
    with a value of the field's type; with ``snapshots`` (``TrainConfig.snapshot_iterations``) they must fit
    the run's ``iterations``. Returns the overrides applied to the default ``TrainConfig``.

    Raises:
        ConfigError: (a :class:`~gof_warp.core.errors.GofError`) naming ``where`` and the bad key, e.g.
            ``run default_7k: unknown key 'densify.max_gausians'; valid keys of 'densify': [...]``.
    """
    from ..core.config import ConfigError, merge
    from ..training.trainer import TrainConfig

    if not isinstance(overrides, dict):
        raise ConfigError(f"{where}: overrides must be a mapping of config sections, got {type(overrides).__name__}")
    over = _merge(overrides, {"snapshot_iterations": list(snapshots)}) if snapshots else overrides
    try:
        return merge(TrainConfig(), over, where)
    except ConfigError as e:  # TrainConfig's own checks do not know the run
        if str(e).startswith(where):
            raise
        raise ConfigError(f"{where}: {e}") from None


def tetra(steps):
    return Method(f"tetra_bs{steps}", "tetra", steps)


def cubes(res, steps):
    return Method(f"cubes{res}_bs{steps}", "cubes", steps, res)


def tsdf(res):
    return Method(f"tsdf{res}", "tsdf", 0, res)


RENDER_ONLY = Method("render_only", "none")  # a row for the model itself: no extraction


def scaled_schedule(iterations: int, max_gaussians: int, init_points: int) -> dict:
    """The ``quick`` preset's schedule (written for 1,200 iterations) stretched to ``iterations``."""
    s = iterations / 1200.0

    def at(k):
        return max(1, round(k * s))

    return {"iterations": iterations, "checkpoint_every": 0, "log_every": max(1, iterations // 10),
            "model": {"random_init_points": init_points}, "optim": {"means_lr_max_steps": iterations},
            "densify": {"start_iter": at(100), "stop_iter": at(900), "interval": at(100),
                        "opacity_reset_interval": 10 * iterations, "sh_degree_interval": at(400),
                        "filter_3d_until_iter": at(1100), "max_gaussians": max_gaussians},
            "loss": {"regularization_from_iter": at(600)}}


GOF_SCHEDULE = {"densify": ("start_iter", "stop_iter", "opacity_reset_interval", "prune_big_after",
                            "sh_degree_interval", "filter_3d_until_iter"),
                "loss": ("regularization_from_iter",), "optim": ("means_lr_max_steps",)}


def gof_schedule(iterations: int) -> dict:
    """GOF's 30k-iteration schedule (the stage configs' defaults: densify 500–15k, opacity reset every 3k,
    regularisers from 15k, …) compressed to ``iterations`` (meant for ≥ 3k): the fields of :data:`GOF_SCHEDULE`
    × iterations/30k, the identity at 30k. So a shorter run is a complete training, regularisers included (cut
    at 15k, GOF's own schedule would never switch them on). The densification and 3D-filter intervals stay
    GOF's 100 iterations and ``start_iter`` is rounded to a multiple of it: an opacity reset (to 0.01) must be
    followed by ~100 iterations of recovery before the next prune (opacity < 0.05), or every reset Gaussian
    is pruned. No checkpoints (a bench run is retrained, not resumed)."""
    from ..training.densify import DensifyConfig
    from ..training.losses import LossConfig
    from ..training.optim import OptimConfig
    from ..training.trainer import TrainConfig

    defaults = {"densify": DensifyConfig(), "loss": LossConfig(), "optim": OptimConfig()}
    s = iterations / TrainConfig().iterations
    out = {sec: {k: max(1, round(getattr(defaults[sec], k) * s)) for k in keys} for sec, keys in GOF_SCHEDULE.items()}
    step = defaults["densify"].interval  # the reset at start_iter (blender) is then a full interval before a prune
    out["densify"]["start_iter"] = max(step, step * round(out["densify"]["start_iter"] / step))
    return {"iterations": iterations, "checkpoint_every": 0, "log_every": 100, **out}


NO_REGULARISERS = {"loss": {"lambda_distortion": 0.0, "lambda_normal": 0.0}}


def _merge(a: dict, b: dict) -> dict:
    out = dict(a)
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def preset_overrides(preset: str) -> dict:
    """Training overrides a synthetic preset needs: the ``background`` presets' ground plane and shell reach
    radius 6 (``garden``'s 8), so their random initialisation must too (the presets' init boxes are ±1 or ±1.3)."""
    reach = {"background": 6.0, "background_detail": 6.0, "background_full": 6.0, "garden": 8.0}.get(preset)
    return {"model": {"init_box": [-reach] * 3 + [reach] * 3}} if reach else {}


# ----------------------------------------------------------------------------------------- one run
DATA_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data"  # real scenes (../shared/data)


def data_root(path=None) -> Path:
    """The folder of the real scenes and spot's mesh: ``path``, else ``$GOF_WARP_DATA``, else ``../shared/data``."""
    return Path(path or os.environ.get("GOF_WARP_DATA") or DATA_ROOT)


def scene_folder(run: Run, run_dir: Path, data=None) -> Path:
    """The run's scene: a real scene ``data_root(data)/NAME`` (``real:NAME``), else the synthetic preset rendered
    into ``run_dir/scene`` (once; ``spot`` reads its mesh from ``data_root(data)/spot``)."""
    root = data_root(data)
    if run.preset.startswith("real:"):
        path = root / run.preset[5:]
        if not path.is_dir():
            raise GofError(f"run {run.name}: real scene {path} is absent (pass --data DIR, the folder holding it)")
        return path
    from ..synthetic import make_scene

    scene_dir = run_dir / "scene"
    if not (scene_dir / "gt_mesh.ply").is_file():
        mesh = {"mesh_path": root / "spot"} if run.preset == "spot" else {}
        make_scene(run.preset, scene_dir, views=run.views, resolution=run.resolution, force=True, **mesh)
    return scene_dir


def run_config(run: Run):
    """The run's resolved :class:`~gof_warp.training.trainer.TrainConfig` (preset + overrides + snapshots)."""
    from ..core.config import merge
    from ..training.presets import resolve_config

    over = _merge(run.overrides, {"snapshot_iterations": list(run.snapshots)}) if run.snapshots else run.overrides
    return merge(resolve_config(run.config, [], None), over, f"run {run.name}")


def _trained(run_dir: Path, snapshots) -> dict | None:
    """The metrics of a model already trained in ``run_dir`` with every snapshot asked for, else None."""
    import json

    if not ((run_dir / "metrics.json").is_file() and (run_dir / "point_cloud.ply").is_file()):
        return None
    metrics = json.loads((run_dir / "metrics.json").read_text())
    have = {s["iteration"] for s in metrics.get("snapshots", []) if (run_dir / s["path"]).is_file()}
    return metrics if set(snapshots) <= have else None


def _train_or_load(run: Run, run_dir: Path, device: str, data=None, progress=None):
    """``(gaussians, scene, render_config, metrics, scene_dir)`` of the run's last model; a model already
    trained in ``run_dir`` (with its snapshots) is reused. ``progress``: the trainer's ``progress(it, info)``
    callback (e.g. :class:`gof_warp.core.progress.TrainingProgress`), called while training."""
    from ..data import load_scene
    from ..core.model import Gaussians
    from ..training.trainer import Trainer

    scene_dir = scene_folder(run, run_dir, data)
    cfg = run_config(run)
    scene = load_scene(scene_dir, cfg.data)
    metrics = _trained(run_dir, run.snapshots)
    if metrics is not None:
        log.info("run %s: reusing the trained model in %s", run.name, run_dir)
        render_config = dataclasses.replace(cfg.render, background=tuple(float(c) for c in scene.background))
        return (Gaussians.load_ply(run_dir / "point_cloud.ply", device=device), scene, render_config, metrics,
                scene_dir)
    log.info("run %s: training %d iterations on %s (%d views)", run.name, cfg.iterations, run.preset, len(scene.train))
    reset_peak_memory()
    trainer = Trainer(scene, cfg, run_dir, device)
    metrics = trainer.run(progress=progress)
    metrics["bench_peak_memory"] = peak_memory()  # this run's own peak (the trainer's RSS is the process's)
    return trainer.gaussians, scene, trainer.render_config, metrics, scene_dir
