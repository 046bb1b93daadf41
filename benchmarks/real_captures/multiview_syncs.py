"""Where a training step waits for the GPU, with and without the multi-view term: 30 steps of the small default
scene on CUDA under ``torch.cuda.set_sync_debug_mode("warn")`` after 10 steps of warm-up; prints the number of
synchronising calls per variant and the code lines they come from. ``python multiview_syncs.py`` (GPU machine)."""

import collections
import sys
import tempfile
import traceback
import warnings
from pathlib import Path

import torch

from gof_warp.config import merge
from gof_warp.data import load_scene
from gof_warp.synthetic import make_scene
from gof_warp.trainer import TrainConfig, Trainer


def count(weight: float, scene, folder: Path) -> collections.Counter:
    cfg = merge(TrainConfig(), {"iterations": 40, "checkpoint_every": 0, "log_every": 1000,
                                "model": {"init": "random", "random_init_points": 20000},
                                "densify": {"start_iter": 10_000},
                                "loss": {"regularization_from_iter": 1, "multiview": {"weight": weight, "from_iter": 1,
                                                                                       "max_angle_deg": 90.0}}})
    trainer = Trainer(scene, cfg, folder, "cuda")
    for _ in range(10):
        trainer.step()
    where = collections.Counter()

    def hook(message, category, filename, lineno, file=None, line=None):
        stack = [f for f in traceback.extract_stack() if "gof_warp" in f.filename][-2:]
        where[" <- ".join(f"{Path(f.filename).name}:{f.lineno}" for f in reversed(stack))] += 1

    old = warnings.showwarning
    warnings.showwarning = hook
    torch.cuda.set_sync_debug_mode("warn")
    try:
        for _ in range(30):
            trainer._pending.add(*trainer._step())  # the step without reading its scalars back
    finally:
        torch.cuda.set_sync_debug_mode("default")
        warnings.showwarning = old
    return where


def main() -> int:
    tmp = Path(tempfile.mkdtemp())
    scene = load_scene(make_scene("default", tmp / "s", views=8, resolution=(128, 128), device="cuda"))
    for w in (0.0, 0.15):
        where = count(w, scene, tmp / f"run_{w}")
        print(f"multiview weight {w}: {sum(where.values())} synchronising calls in 30 steps")
        for k, n in where.most_common(12):
            print(f"  {n:4d}  {k}")
    return 0


if __name__ == "__main__":
    warnings.simplefilter("always")
    sys.exit(main())
