"""``python -m gof_warp.train [SCENE] --out RUN [--config NAME|PATH] [--iterations N] [--device D] [--resume] [key=value ...]``

Trains GOF on a scene folder (any format :func:`gof_warp.data.load_scene` reads). With no SCENE it
runs the built-in default: a small synthetic scene is generated into ``RUN/scene`` and trained with
the ``quick`` preset, which finishes on a 2-core CPU in minutes.

Overrides are ``section.key=value`` pairs applied on top of the preset, e.g.
``loss.lambda_normal=0.1 densify.max_gaussians=200000``; values are YAML data (never evaluated).

Progress: a bar with loss, PSNR, Gaussian count and ETA in a terminal, a plain line every few seconds
otherwise (logs, CI); ``--quiet``: neither. At the end ``RUN/pictures/views.png`` and ``RUN/pictures/curves.png``
(loss, train PSNR and Gaussian count against the iteration), and ``RUN/pictures/views_it<N>.png`` at each of
``snapshot_iterations``. ``--viewer``: the live web viewer of
:mod:`gof_warp.viz.viewer` during training (``--viewer-port``, ``--viewer-every N`` iterations), kept up after
training until Ctrl-C.
"""

from __future__ import annotations

import argparse
import logging
import os
import shlex
import sys
from pathlib import Path

from .common import HelpFormatter, configure_output, downscale_arg, run_command
from ..core.errors import GofError
from ..training.presets import PRESETS, preset_path, resolve_config  # noqa: F401 - importable from the command too
from ..core.progress import TrainingProgress

log = logging.getLogger(__name__)

DESCRIPTION = """\
Train Gaussian Opacity Fields on a scene folder (COLMAP, Blender, instant-ngp or NeuS/DTU layout).
With no SCENE it trains the built-in default: a small synthetic scene is generated into RUN/scene and
trained with the quick preset, which finishes on a 2-core CPU in minutes."""
EPILOG = """\
Overrides are section.key=value pairs applied on top of the preset, for example
  loss.lambda_normal=0.1 densify.max_gaussians=200000
Their values are YAML data (never evaluated).

Progress: a bar with loss, PSNR, Gaussian count and ETA in a terminal, a plain line every few
seconds otherwise (logs, CI); --quiet: neither. At the end: RUN/pictures/views.png and
RUN/pictures/curves.png, and RUN/pictures/views_it<N>.png at each snapshot iteration."""


def pick_device(name: str) -> str:
    """``--device`` (cpu, cuda, cuda:N or auto) under the one rule of :mod:`gof_warp.core.devices`."""
    from ..core.devices import resolve_device

    return resolve_device(name)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gof_warp.train", description=DESCRIPTION, epilog=EPILOG,
                                 formatter_class=HelpFormatter)
    ap.add_argument("args", nargs="*", metavar="SCENE | key=value",
                    help="scene folder (none: the built-in synthetic scene), then config overrides")
    ap.add_argument("--out", default=None, help="run folder (default: runs/<scene name>, runs/default for the "
                                                "built-in scene)")
    ap.add_argument("--config", default=None, help=f"preset ({', '.join(PRESETS)}) or YAML path (default: quick "
                                                   "for the built-in scene, else auto: chosen from the scene "
                                                   "folder, printed with its reason)")
    ap.add_argument("--iterations", type=int, default=None,
                    help="training iterations (default: the config's)")
    ap.add_argument("--downscale", type=downscale_arg, default=None, metavar="N",
                    help="divide the image resolution by the integer N >= 1 (same as data.downscale=N, and wins over "
                         "it; default: the preset's: 1 for most, chosen from the image size for cpu)")
    ap.add_argument("--device", default="auto", help="cpu, cuda, cuda:N or auto")
    ap.add_argument("--resume", action="store_true", help="continue from the newest checkpoint in --out")
    ap.add_argument("--overwrite", action="store_true", help="train anew into an --out that holds a finished run or "
                                                              "checkpoints: its model, checkpoints, metrics, meshes and "
                                                              "pictures are removed first (the scene stays)")
    ap.add_argument("--no-pictures", action="store_true", help="do not write RUN/pictures/views.png (photo | render "
                                                               "| depth | normal of a few views) and curves.png "
                                                               "(loss, PSNR, Gaussians) at the end, nor "
                                                               "views_it<N>.png at snapshots")
    ap.add_argument("--quiet", action="store_true", help="no progress bar or log lines (errors and warnings still shown)")
    viewer = ap.add_argument_group("live viewer")
    viewer.add_argument("--viewer", action="store_true", help="serve the live web viewer during training (needs "
                        "pip install 'gof_warp[viewer]'); it stays up after training until Ctrl-C")
    viewer.add_argument("--viewer-port", type=int, default=8080, help="port of the viewer page")
    viewer.add_argument("--viewer-host", default="127.0.0.1", help="interface the viewer listens on: 127.0.0.1 is "
                        "this machine only (from another, SSH port forwarding); 0.0.0.0 is every interface, with a "
                        "warning: anyone who reaches the port and has the printed address (its token) sees the model")
    viewer.add_argument("--viewer-every", type=int, default=100, metavar="N", help="show the model every N iterations")
    a = ap.parse_intermixed_args(argv)
    configure_output(a.quiet)
    return run_command(lambda: _run(a), lambda e: _interrupted_note(a, e))


def _out_dir(a) -> Path:
    scenes = [x for x in a.args if "=" not in x]
    return Path(a.out) if a.out else Path("runs") / (Path(scenes[0]).resolve().name if scenes else "default")


def resume_command(a) -> str:
    """The command line that continues this run: the same scene, config, overrides and device, plus ``--resume``."""
    words = ["python", "-m", "gof_warp.train", *a.args, "--out", str(_out_dir(a))]
    if a.config:
        words += ["--config", a.config]
    if a.iterations is not None:
        words += ["--iterations", str(a.iterations)]
    if a.downscale is not None:
        words += ["--downscale", str(a.downscale)]
    if a.device != "auto":
        words += ["--device", a.device]
    words += [flag for flag, on in (("--no-pictures", a.no_pictures), ("--quiet", a.quiet), ("--viewer", a.viewer)) if on]
    if a.viewer:
        words += [f"--viewer-{k}={v}" for k, v, default in (("port", a.viewer_port, 8080), ("host", a.viewer_host, "127.0.0.1"),
                                                             ("every", a.viewer_every, 100)) if v != default]
    return shlex.join(words + ["--resume"])


def _interrupted_note(a, e: KeyboardInterrupt) -> str:
    """One line for Ctrl-C: where training stopped and how to go on (see :meth:`Trainer.run`)."""
    from ..training.trainer import TrainingInterrupted, has_checkpoints

    if isinstance(e, TrainingInterrupted):
        saved = f", saved in {e.checkpoint}" if e.checkpoint else ""
        return f"training stopped at iteration {e.iteration} of {e.total}{saved}; continue with: {resume_command(a)}"
    if has_checkpoints(_out_dir(a)):
        return f"the newest checkpoint in the run folder is intact; continue with: {resume_command(a)}"
    return "no checkpoint was written yet; run the command again to start"


CPU_HINT_ITERATIONS = 10_000  # a preset this long on the CPU gets a hint towards --config cpu


def plan_line(preset: str, cfg, scene, device: str, start: int = 0) -> str:
    """One line on what the run will do: preset, iterations, training resolution and an expected time on
    ``device`` (:func:`gof_warp.training.schedule.expected_train_seconds`, a rough model)."""
    from ..core.progress import format_seconds
    from ..training.schedule import expected_train_seconds

    cams = [v.camera for v in scene.train] or [v.camera for v in scene.all_views]
    w, h = max(((c.width, c.height) for c in cams), key=lambda wh: wh[0] * wh[1])
    left = cfg.iterations - start
    expected = expected_train_seconds(left, w * h, device)
    if expected is None:
        guess = f"no time model for device {device}"
    else:
        guess = f"expected training time on {device} roughly {format_seconds(expected)} (an ETA follows after " \
                f"{_eta_after()} iterations)"
    return (f"plan: preset {preset}, {cfg.iterations} iterations, training views {w}x{h} px "
            f"(data.downscale {cfg.data.downscale:g}); {guess}")


def _eta_after() -> int:
    from ..training.schedule import ETA_AFTER_ITERATIONS

    return ETA_AFTER_ITERATIONS


class _Pace:
    """The progress callback, plus one line after the first :data:`~gof_warp.training.schedule.ETA_AFTER_ITERATIONS`
    iterations of this command: their pace and the time left at it
    (:func:`~gof_warp.training.schedule.eta_from_pace`)."""

    def __init__(self, progress, start: int, total: int, device: str, quiet: bool):
        import time

        self.progress, self.start, self.total, self.device, self.quiet = progress, start, total, device, quiet
        self.clock = time.perf_counter
        self.t_first: float | None = None

    def __call__(self, it: int, info: dict) -> None:
        self.progress(it, info)
        n = _eta_after()
        if self.t_first is None:
            self.t_first = self.clock()  # the first iteration's compiling and caching are not the pace
        elif it == self.start + 1 + n and not self.quiet and self.total - it > n:
            from ..core.progress import format_seconds
            from ..training.schedule import eta_from_pace

            pace = (self.clock() - self.t_first) / n
            log.info("pace after %d iterations: %.3f s an iteration; about %s of training left (rough: later "
                     "iterations draw more Gaussians)", n, pace,
                     format_seconds(eta_from_pace(pace, self.total - it, self.device)))


def _start_viewer(a, trainer, out: Path):
    """The live viewer of ``trainer``'s model (:mod:`gof_warp.viz.viewer`), started, its address printed."""
    from ..viz.viewer import Viewer

    logging.getLogger("websockets").setLevel(logging.WARNING)  # not a line per browser connection
    viewer = Viewer(trainer.gaussians, trainer.cameras, render_config=trainer.render_config, host=a.viewer_host,
                    port=a.viewer_port, title=f"gof_warp · training {out.name}").start()
    print(viewer.how_to_open(), flush=True)
    return viewer


def _on_iteration(progress, viewer, every: int, trainer):
    """The trainer's per-iteration callback: the progress bar, and the viewer's model every ``every`` iterations."""
    if viewer is None:
        return progress

    def callback(it: int, info: dict) -> None:
        progress(it, info)
        if it % every == 0:
            viewer.update(trainer.gaussians, it)

    return callback


def _keep_serving(viewer) -> None:
    """Serve the viewer after training until Ctrl-C (which ends the command normally)."""
    try:
        viewer.serve_forever()
    except KeyboardInterrupt:
        print("viewer stopped", file=sys.stderr)


def _snapshot_pictures(trainer, record: dict) -> None:
    """The trainer's snapshot callback: ``RUN/pictures/views_it<N>.png`` (a failure only warns)."""
    from ..viz.pictures import snapshot_pictures_or_warning

    for p in snapshot_pictures_or_warning(trainer, record):
        log.info("wrote %s", p)


def _spike_pictures(trainer, event: dict) -> None:
    """The trainer's loss-spike callback: ``RUN/pictures/spike_it<N>_<view>.png`` (a failure only warns)."""
    from ..viz.pictures import spike_picture_or_warning

    for p in spike_picture_or_warning(trainer, event):
        log.info("loss spike on view %s at iteration %s (%sx its median): wrote %s", event.get("view"),
                 event.get("iteration"), event.get("ratio"), p)


def _run(a) -> int:
    from ..core.io_utils import ensure_writable_dir
    from ..training.run_folder import lock_run_folder, remove_if_empty

    scenes = [x for x in a.args if "=" not in x]
    overrides = [x for x in a.args if "=" in x] + ([f"data.downscale={a.downscale}"] if a.downscale else [])
    if len(scenes) > 1:
        raise GofError(f"give one scene folder, got {scenes}")
    builtin = not scenes
    if a.viewer:
        from ..viz.viewer import require_viser

        if a.viewer_every < 1:
            raise GofError(f"--viewer-every must be >= 1, got {a.viewer_every}")
        require_viser()  # before any work: a missing optional dependency is named at once
    if a.resume and a.overwrite:
        raise GofError("--resume continues the run in --out and --overwrite starts it anew: give one of them")
    out = _out_dir(a)
    created = not out.exists() and not out.is_symlink()
    ensure_writable_dir(out)
    try:
        if not _main_process():  # under torchrun rank 0 holds the lock for all
            return _train(a, out, scenes, overrides, builtin)
        with lock_run_folder(out):
            return _train(a, out, scenes, overrides, builtin)
    except BaseException:
        if created and _main_process():
            remove_if_empty(out)  # the folder this command made, when nothing was written into it
        raise


def _check_device_memory(scene, cfg, device: str) -> None:
    """Log the run's estimated peak device memory and warn before training when a CUDA device has less free
    (:mod:`gof_warp.training.memory_estimate`)."""
    from ..training.memory_estimate import memory_warning, scene_estimate

    if not str(device).startswith("cuda"):
        return
    import torch

    estimate = scene_estimate(scene, cfg)
    free, total = torch.cuda.mem_get_info(torch.device(device))
    log.info("estimated peak device memory: %s; %s has %.1f GB free", estimate.describe(), device, free / 1e9)
    warning = memory_warning(estimate, free, total, device)
    if warning:
        log.warning("%s", warning)


def _main_process() -> bool:
    """Whether this process is rank 0 of a torchrun launch, or the only one."""
    return int(os.environ.get("WORLD_SIZE", "1") or 1) <= 1 or os.environ.get("RANK", "0") == "0"


def _train(a, out: Path, scenes: list[str], overrides: list[str], builtin: bool) -> int:
    """The command's work in the locked run folder ``out``."""
    from ..core.devices import expandable_cuda_segments
    from ..data import load_scene
    from ..training.distributed import rank_device, ranks_from_environment
    from ..training.run_folder import is_finished_run, remove_run_outputs
    from ..training.trainer import Trainer, has_checkpoints

    if is_finished_run(out) and not (a.resume or a.overwrite):
        raise GofError(f"{out} already holds a run (point_cloud.ply or checkpoints): pass --resume to continue it, "
                       "--overwrite to train anew in its place, or choose another --out")
    preset = a.config or ("quick" if builtin else "auto")
    if preset == "auto":
        from ..training.presets import choose_preset

        resolve_config("unbounded", overrides, a.iterations)  # a bad override is named before the scene is read
        choice = choose_preset(scenes[0])
        log.info("%s", choice.describe())
        preset = choice.preset
    cfg = resolve_config(preset, overrides, a.iterations, scene=None if builtin else scenes[0])
    ranks = ranks_from_environment()  # several processes under torchrun: data-parallel (gof_warp.training.distributed)
    device = rank_device(pick_device(a.device), ranks)
    expandable_cuda_segments(device)  # reserved memory stays near what is in use as densification grows the tensors
    if a.config is None and not builtin and device == "cpu" and cfg.iterations >= CPU_HINT_ITERATIONS:
        log.info("on the CPU %d iterations take hours; --config cpu trains a real capture in minutes at a reduced "
                 "resolution (README: your own photos)", cfg.iterations)
    if builtin:
        from ..synthetic import make_scene

        scene_dir = out / "scene"
        if ranks.is_main and not (scene_dir / "transforms_train.json").is_file():
            log.info("generating the built-in default scene into %s", scene_dir)
            make_scene("default", scene_dir, force=True)
        ranks.barrier()
    else:
        scene_dir = Path(scenes[0])
    scene = load_scene(scene_dir, cfg.data)
    if a.overwrite and ranks.is_main:  # the scene and config are good: now the old run's outputs go
        removed = remove_run_outputs(out)
        if removed:
            log.info("--overwrite: removed %d outputs of the earlier run in %s", len(removed), out)
    ranks.barrier()
    log.info("scene %s: %d train / %d test views, extent %.3f; device %s", scene_dir, len(scene.train), len(scene.test),
             scene.extent, device)
    _check_device_memory(scene, cfg, device)
    if ranks.is_main:
        print(plan_line(preset, cfg, scene, device, start=0), flush=True)
    trainer = Trainer(scene, cfg, out, device, scene_path=scene_dir, ranks=ranks)
    if ranks.active:
        log.info("rank %d of %d on %s, %d views per step", ranks.rank, ranks.world, device, trainer.views_per_step)
    if a.resume and has_checkpoints(out):
        it = trainer.resume()
        log.info("resuming from iteration %d (%s)", it, trainer.resumed_from)
    viewer = _start_viewer(a, trainer, out) if a.viewer and ranks.is_main else None
    try:
        with TrainingProgress(cfg.iterations, start=trainer.iteration, quiet=a.quiet or not ranks.is_main) as progress:
            pace = _Pace(progress, trainer.iteration, cfg.iterations, device, quiet=a.quiet or not ranks.is_main)
            metrics = trainer.run(progress=_on_iteration(pace, viewer, a.viewer_every, trainer),
                                  on_snapshot=None if a.no_pictures else _snapshot_pictures,
                                  on_spike=None if a.no_pictures else _spike_pictures)
        if not ranks.is_main:
            ranks.barrier()  # wait for rank 0's evaluation and writes: leaving earlier can abort the whole job
            return 0
        if not a.no_pictures:
            from ..viz.curves import curves_or_warning
            from ..viz.pictures import pictures_or_warning

            for p in pictures_or_warning(out, device=device) + curves_or_warning(out):
                log.info("wrote %s", p)
        t = metrics["test"]
        print(f"done: {metrics['iterations']} iterations in {metrics['train_time_s']:.1f} s, {metrics['num_gaussians']} "
              f"Gaussians, {t['split']} PSNR {t.get('psnr', float('nan')):.2f} dB SSIM {t.get('ssim', float('nan')):.4f}; "
              f"outputs in {out}")
        ranks.barrier()  # the other ranks wait here for the run folder to be complete
        if viewer is not None:
            viewer.update(trainer.gaussians, trainer.iteration)
            print(f"training done; the viewer is still at {viewer.url} (Ctrl-C to stop)", flush=True)
            _keep_serving(viewer)
    finally:
        if viewer is not None:
            viewer.stop()
        ranks.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
