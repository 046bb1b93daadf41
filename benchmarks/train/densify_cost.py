"""What one densification event costs a training run: 100-iteration windows of the trainer's loop with densification
off and on (one event per window), alternating, on a trained model in the densifying phase.

    python benchmarks/train/densify_cost.py SCENE --config dtu --ply MODEL.ply --start 12000 [--reps 3] [--out DIR]

Set up as ``profile_train.py`` does (the preset, the model, the iteration). Each window is ``interval`` iterations of
``Trainer._train_loop`` synchronised at both ends; "on" windows have ``densify.interval = interval`` aligned so that
exactly one densification (with the 3D filter's update and, every 3,000 iterations, the opacity reset that GOF does
with it) falls inside; "off" windows have none. The difference of the means is the event's cost, everything it
brings included (its host synchronisations, the GPU idling while the host rebuilds the model and Adam's state, the
first render at the new size). The model grows in "on" windows, so the windows alternate and the count is recorded.
Then one "on" window is traced (``torch.profiler``): the host time of each named stage in the event's iteration and
the iteration's wall time against the window's median, and the costliest host calls of that iteration.

Writes ``DIR/densify_cost.json``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from profile_train import _cudnn_setting, _sync, _with_model  # noqa: E402


def window(trainer, n: int, densify: bool, interval: int) -> dict:
    """``n`` iterations from the current one (a multiple of ``interval``), one densification inside when ``densify``;
    wall seconds (synchronised), per-iteration host seconds and the Gaussian count before/after."""
    cfg = trainer.config
    trainer.densifier.config.interval = interval if densify else 10**9
    cfg.iterations = trainer.iteration + n
    cfg.checkpoint_every = 0
    cfg.snapshot_iterations = []
    n0 = len(trainer.gaussians)
    step_times: list[float] = []
    original = trainer._step

    def timed_step():
        t = time.perf_counter()
        out = original()
        step_times.append(time.perf_counter() - t)
        return out

    trainer._step = timed_step
    try:
        _sync(trainer.device)
        t0 = time.perf_counter()
        trainer._train_loop(None, lambda: False)
        _sync(trainer.device)
        wall = time.perf_counter() - t0
    finally:
        trainer._step = original
    return {"densify": densify, "start": trainer.iteration - n, "wall_s": wall, "n_before": n0,
            "n_after": len(trainer.gaussians), "step_host_ms": [round(s * 1e3, 3) for s in step_times]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--config", default="dtu")
    ap.add_argument("--ply", type=Path, required=True)
    ap.add_argument("--start", type=int, default=12000, help="a multiple of --interval, in the densifying phase")
    ap.add_argument("--interval", type=int, default=100)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--device", default="auto")
    ap.add_argument("--out", type=Path, default=Path("densify_cost_out"))
    ap.add_argument("overrides", nargs="*")
    a = ap.parse_intermixed_args(argv)
    if a.start % a.interval:
        ap.error("--start must be a multiple of --interval")

    from gof_warp.data import load_scene
    from gof_warp.devices import resolve_device
    from gof_warp.preset_choice import resolve_config
    from gof_warp.trainer import Trainer

    a.out.mkdir(parents=True, exist_ok=True)
    cfg = resolve_config(a.config, ["model.init=random", *a.overrides], None)
    trainer = Trainer(load_scene(a.scene, cfg.data), cfg, a.out / "run", resolve_device(a.device))
    _with_model(trainer, a.ply)
    trainer.iteration = a.start - a.interval
    trainer.densifier.update_sh_degree(trainer.iteration + 1, trainer.gaussians)
    windows = []
    with _cudnn_setting(cfg):
        window(trainer, a.interval, False, a.interval)  # warm-up: module loads, the compiled graphs, Adam's state
        window(trainer, a.interval, True, a.interval)  # and a first densification (the dynamic-N graphs)
        for _ in range(a.reps):
            for densify in (False, True):
                windows.append(window(trainer, a.interval, densify, a.interval))
        from torch.profiler import ProfilerActivity, profile as torch_profile

        acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if trainer.device.type == "cuda" else [])
        with torch_profile(activities=acts) as prof:
            traced = window(trainer, a.interval, True, a.interval)
    events = prof.key_averages()
    top_host = sorted(events, key=lambda e: -e.self_cpu_time_total)[:30]
    mean = {d: statistics.mean(w["wall_s"] for w in windows if w["densify"] == d) for d in (False, True)}
    result = {
        "scene": a.scene, "config": a.config, "start": a.start, "interval": a.interval, "reps": a.reps,
        "device": torch.cuda.get_device_name(trainer.device) if trainer.device.type == "cuda" else "cpu",
        "torch": torch.__version__,
        "ms_per_window": {"off": round(mean[False] * 1e3, 2), "on": round(mean[True] * 1e3, 2)},
        "event_cost_ms": round((mean[True] - mean[False]) * 1e3, 2),
        "windows": [{k: v for k, v in w.items() if k != "step_host_ms"} for w in windows],
        "traced_window": {"wall_s": traced["wall_s"], "step_host_ms": traced["step_host_ms"],
                          "step_host_median_ms": statistics.median(traced["step_host_ms"])},
        "traced_top_host_self_ms": [{"name": e.key[:100], "self_cpu_ms": round(e.self_cpu_time_total / 1e3, 3),
                                     "calls": e.count} for e in top_host],
    }
    (a.out / "densify_cost.json").write_text(json.dumps(result, indent=1))
    print(json.dumps({k: result[k] for k in ("ms_per_window", "event_cost_ms", "device")}, indent=1))
    steps = traced["step_host_ms"]
    worst = sorted(range(len(steps)), key=lambda i: -steps[i])[:5]
    print("traced window, slowest steps (index: host ms):", {i: steps[i] for i in worst},
          "median", statistics.median(steps))
    return 0


if __name__ == "__main__":
    sys.exit(main())
