"""Per-iteration profile of the trainer: where one training step's time goes, on the GPU and on the host.

    python benchmarks/train/profile_train.py SCENE --config dtu [--ply MODEL.ply] --start 20000 \
        [--iterations 300] [--trace 30] [--out DIR] [override ...]

The trainer is built as ``python -m gof_warp.train`` builds it (preset + overrides), then optionally given a
trained model (``--ply``, e.g. a trained DTU scan 24 run's ``point_cloud.ply``; higher SH
bands are zero if the PLY has none) and moved to iteration ``--start`` — ≥ ``densify.stop_iter`` for the
regularised phase (distortion + normal terms, no densification statistics), below it for the densification
phase — so that a step is timed on the model size and in the phase of a real run without training to it.

Measured:

* ``wall_ms_per_it``: wall time of ``--iterations`` iterations of the trainer's own loop
  (``Trainer._train_loop``: the same reads-back, history and progress path as a run), after 20 warm-up
  iterations, synchronised at both ends.
* with ``torch.profiler`` over ``--trace`` further iterations (CPU + CUDA activities): for each part of the
  step that the trainer names (``train.render``, ``train.loss``, ``train.backward``, ``train.densify``,
  ``train.optimizer``; :func:`torch.profiler.record_function`, absent in code before the change) the host time
  and the device time of the kernels it launched; the device's busy time per iteration (sum of kernel
  times) against the wall time (the rest is the GPU waiting for the host); the 25 costliest kernels.

Writes ``DIR/profile.json`` and ``DIR/trace.json.gz`` (chrome://tracing / Perfetto). Under
``torchrun --nproc_per_node N benchmarks/train/profile_train.py SCENE --start-iteration I ... views_per_step=V`` every
rank profiles its own share of the data-parallel step (``train.all_reduce``: the gradients' sum over the ranks) into
``DIR/rank<r>/``.
"""

from __future__ import annotations

import argparse
import contextlib
import gzip
import json
import platform
import shutil
import sys
import time
from pathlib import Path

import torch

STAGES = ("train.render", "train.loss", "train.backward", "train.all_reduce", "train.densify", "train.optimizer")


def _sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _with_model(trainer, ply: Path) -> None:
    """Give ``trainer`` the Gaussians of ``ply`` (SH padded with zeros to the preset's degree), fresh Adam state."""
    from gof_warp.core.model import Gaussians, num_sh_coeffs
    from gof_warp.training.optim import make_optimizer

    g = Gaussians.load_ply(ply, device=trainer.device)
    want = num_sh_coeffs(trainer.config.model.sh_degree) - 1
    rest = g.params["sh_rest"]
    if rest.shape[1] < want:
        pad = torch.zeros(rest.shape[0], want - rest.shape[1], 3, device=rest.device)
        g.params["sh_rest"] = torch.cat([rest, pad], 1)
    g.max_sh_degree = trainer.config.model.sh_degree
    trainer.gaussians = g
    trainer.optimizer = make_optimizer(g, trainer.config.optim, trainer.scene.extent)
    trainer.densifier.reset_stats()


def _cudnn_setting(cfg):
    """``gof_warp.core.devices.cudnn_benchmark`` as the trainer's config asks (a no-op in trees from before it)."""
    try:
        from gof_warp.core.devices import cudnn_benchmark
    except ImportError:
        return contextlib.nullcontext()
    return cudnn_benchmark(getattr(cfg, "cudnn_benchmark", False))


def _run_loop(trainer, n: int) -> float:
    """``n`` iterations of the trainer's loop; wall seconds, synchronised."""
    trainer.config.iterations = trainer.iteration + n
    trainer.config.checkpoint_every = 0
    trainer.config.snapshot_iterations = []
    _sync(trainer.device)
    t0 = time.perf_counter()
    trainer._train_loop(None, lambda: False)
    _sync(trainer.device)
    return time.perf_counter() - t0


def _union_ms(spans) -> float:
    """Milliseconds covered by the union of ``(start_us, duration_us)`` spans."""
    busy, end = 0.0, -1.0
    for start, dur in sorted(spans):
        if start > end:
            busy, end = busy + dur, start + dur
        elif start + dur > end:
            busy, end = busy + start + dur - end, start + dur
    return busy / 1e3


def summarise_trace(events: list[dict], n: int) -> dict:
    """Per-iteration figures from a chrome trace of ``n`` iterations: the GPU's busy time (union of kernel,
    memcpy and memset spans), each named stage's host time (its ``record_function`` range) and device time
    (the same range on the GPU timeline), host waits in synchronisations, and the costliest kernels."""
    spans = [e for e in events if e.get("ph") == "X"]
    gpu = [e for e in spans if e.get("cat") in ("kernel", "gpu_memcpy", "gpu_memset")]
    stages = {}
    for name in STAGES:
        host = [e["dur"] for e in spans if e.get("cat") == "user_annotation" and e["name"] == name]
        device = [e["dur"] for e in spans if e.get("cat") == "gpu_user_annotation" and e["name"] == name]
        stages[name] = {"host_ms_per_it": round(sum(host) / 1e3 / n, 3), "device_ms_per_it": round(sum(device) / 1e3 / n, 3),
                        "calls_per_it": round(len(host) / n, 2)}
    syncs = [e for e in spans if e["name"] in ("cudaStreamSynchronize", "cudaDeviceSynchronize")]
    by_name: dict[str, list] = {}
    for e in gpu:
        by_name.setdefault(e["name"][:120], []).append(e["dur"])
    top = sorted(by_name.items(), key=lambda kv: -sum(kv[1]))[:25]
    return {
        "device_busy_ms_per_it": round(_union_ms((e["ts"], e["dur"]) for e in gpu) / n, 3),
        "stages": stages,
        "syncs_per_it": round(len(syncs) / n, 2),
        "sync_wait_ms_per_it": round(sum(e["dur"] for e in syncs) / 1e3 / n, 3),
        "kernel_launches_per_it": round(sum(1 for e in gpu if e.get("cat") == "kernel") / n, 1),
        "top_kernels": [{"name": k, "ms_per_it": round(sum(d) / 1e3 / n, 3), "calls_per_it": round(len(d) / n, 2)}
                        for k, d in top],
    }


def profile(trainer, n_trace: int, out_dir: Path) -> dict:
    from torch.profiler import ProfilerActivity, profile as torch_profile

    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if trainer.device.type == "cuda" else [])
    with torch_profile(activities=acts) as prof:
        wall = _run_loop(trainer, n_trace)
    trace = out_dir / "trace.json"
    prof.export_chrome_trace(str(trace))
    events = json.loads(trace.read_text())
    events = events["traceEvents"] if isinstance(events, dict) else events
    with open(trace, "rb") as src, gzip.open(str(trace) + ".gz", "wb") as dst:
        shutil.copyfileobj(src, dst)
    trace.unlink()
    return {"traced_iterations": n_trace, "wall_ms_per_it_traced": round(wall * 1e3 / n_trace, 3),
            **summarise_trace(events, n_trace)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--config", default="dtu")
    ap.add_argument("--ply", type=Path, default=None, help="start from this model (e.g. a trained run's point_cloud.ply)")
    ap.add_argument("--start-iteration", "--start", dest="start", type=int, default=20000,
                    help="iteration to profile at (under torchrun spell it --start-iteration: torchrun's own parser "
                         "takes --start for an abbreviation of its --start-method)")
    ap.add_argument("--iterations", type=int, default=300)
    ap.add_argument("--trace", type=int, default=30)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--out", type=Path, default=Path("profile_out"))
    ap.add_argument("--label", default="", help="free text stored in the JSON (e.g. the commit)")
    ap.add_argument("--reduce-min-lanes", type=int, default=None,
                    help="the CUDA backward's RasterSettings.reduce_min_lanes for every render (default: the kernels' own)")
    ap.add_argument("overrides", nargs="*", help="section.key=value, as for gof_warp.cli.train")
    a = ap.parse_intermixed_args(argv)

    from gof_warp.data import load_scene
    from gof_warp.core.devices import resolve_device
    from gof_warp.training.distributed import rank_device, ranks_from_environment
    from gof_warp.training.presets import resolve_config
    from gof_warp.training.trainer import Trainer

    if a.reduce_min_lanes is not None:  # a benchmark knob, not a training option: every render's settings get it
        import functools

        import gof_warp.rendering.render

        gof_warp.rendering.render.make_raster_settings = functools.partial(gof_warp.rendering.render.make_raster_settings,
                                                                 reduce_min_lanes=a.reduce_min_lanes)
    ranks = ranks_from_environment()  # under torchrun: every rank profiles its own step, into DIR/rank<r>/
    if ranks.active:
        a.out = a.out / f"rank{ranks.rank}"
    a.out.mkdir(parents=True, exist_ok=True)
    cfg = resolve_config(a.config, a.overrides, None)
    device = rank_device(resolve_device(a.device), ranks)
    scene = load_scene(a.scene, cfg.data)
    trainer = Trainer(scene, cfg, a.out / "run", device, ranks=ranks)
    if a.ply is not None:
        _with_model(trainer, a.ply)
    trainer.iteration = a.start
    trainer.densifier.update_sh_degree(a.start + 1, trainer.gaussians)
    # the cuDNN setting a run trains under (Trainer.run sets it around its loop; this script calls the loop itself)
    with _cudnn_setting(cfg):
        _run_loop(trainer, 20)  # warm-up: Warp module loads, allocator pools, Adam state
        n0 = len(trainer.gaussians)
        wall = _run_loop(trainer, a.iterations)
        traced = profile(trainer, a.trace, a.out)
    result = {
        "label": a.label, "scene": str(a.scene), "config": a.config, "overrides": a.overrides,
        "start_iteration": a.start, "phase": "regularised" if a.start >= cfg.densify.stop_iter else "densifying",
        "num_gaussians": [n0, len(trainer.gaussians)], "image": [trainer.cameras[0].width, trainer.cameras[0].height],
        "device": torch.cuda.get_device_name(trainer.device) if trainer.device.type == "cuda" else platform.processor(),
        "torch": torch.__version__, "iterations": a.iterations, "wall_ms_per_it": round(wall * 1e3 / a.iterations, 3),
        "processes": ranks.world, "rank": ranks.rank, "views_per_step": trainer.views_per_step,
    }
    result.update(traced)
    sizer = getattr(trainer, "tile_lists", None)  # absent in code before the TileListSizer
    result["tile_lists"] = None if sizer is None else sizer.stats()
    (a.out / "profile.json").write_text(json.dumps(result, indent=1))
    print(json.dumps({k: v for k, v in result.items() if k != "top_kernels"}, indent=1))
    for k in result["top_kernels"][:12]:
        print(f"{k['ms_per_it']:8.3f} ms  x{k['calls_per_it']:<6} {k['name']}")
    ranks.barrier()
    ranks.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
