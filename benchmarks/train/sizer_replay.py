"""The tile-list sizer over a short training on the CPU: overflows (renders that dropped entries), exact measurements
(host–device synchronisations on a GPU) and padding, with each view's own count (``--variant new``, today's rule) or
one size for all views (``--variant old``: the per-view key switched off, the rule before session 23), or, as an
experiment not kept, a seen view's own scaled count alone (``--variant own``).

    python benchmarks/train/sizer_replay.py SCENE --variant new --iterations 700 --downscale 16 [--out OUT.json]

The sizer's decisions do not depend on the device (on the CPU each count is read at once instead of a render or two
later), so the counts of a CPU run show what the rule does; the trainer builds no sizer on the CPU, so one is given
to it here. ``unbounded`` preset with densification every 25 iterations from 50 on (the number of Gaussians changes
often, as in the first half of a real run), the loss eager; progress every 100 iterations.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from gof_warp.config import load_yaml, merge
from gof_warp.data import DataConfig, load_scene
from gof_warp.kernels import binning
from gof_warp.kernels.binning import TileListSizer
from gof_warp.trainer import TrainConfig, Trainer

PRESET = Path(__file__).resolve().parents[2] / "configs" / "unbounded.yaml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--variant", choices=("new", "old", "own"), default="new")
    ap.add_argument("--iterations", type=int, default=700)
    ap.add_argument("--downscale", type=int, default=16)
    ap.add_argument("--margin", type=float, default=1.25)
    ap.add_argument("--run", default="/tmp/sizer_replay_run")
    ap.add_argument("--out")
    a = ap.parse_args()
    torch.set_num_threads(1)
    if a.variant == "old":
        binning.view_key = lambda cam: None  # every view under one key: the single size of before
    if a.variant == "own":  # experiment: a view seen before gets its own scaled count only, not the largest since
        def plan(self, n, view=None, _plan=TileListSizer.plan):
            planned = _plan(self, n, view)  # settles, counts the call, resets on a change in the number
            return self.view_estimate(n, view) or planned
        TileListSizer.plan = plan
    scene = load_scene(Path(a.scene), DataConfig(downscale=a.downscale))
    cfg = merge(merge(TrainConfig(), load_yaml(PRESET)), {
        "iterations": a.iterations, "checkpoint_every": 0, "compile_loss": "off",
        "densify": {"start_iter": 50, "interval": 25, "stop_iter": a.iterations, "opacity_reset_interval": 300}})
    trainer = Trainer(scene, cfg, Path(a.run) / a.variant, "cpu")
    trainer.tile_lists = TileListSizer(a.margin)
    t0, rows = time.perf_counter(), []
    for i in range(1, a.iterations + 1):
        trainer.step()
        if i % 100 == 0 or i == a.iterations:
            rows.append({"iteration": i, "gaussians": len(trainer.gaussians), **trainer.tile_lists.stats(),
                         "seconds": round(time.perf_counter() - t0, 1)})
            print(a.variant, json.dumps(rows[-1]), flush=True)
    s = trainer.tile_lists
    result = {"scene": a.scene, "downscale": a.downscale, "variant": a.variant, "margin": a.margin, "history": rows,
              "padding_ratio": round(s.entries_allocated / max(s.entries_needed, 1), 4)}
    if a.out:
        Path(a.out).write_text(json.dumps(result, indent=1))
    print(json.dumps({k: v for k, v in result.items() if k != "history"}))


if __name__ == "__main__":
    main()
