"""How long a checkpoint holds up training: the synchronous save against the background writer.

    python benchmarks/train/checkpoint_cost.py --gaussians 814124 --out results/checkpoint_cost_h200.json

A state shaped like the trainer's (`Trainer.state_dict`: the Gaussians' parameters at SH degree 3, their two Adam
moments) on the device. Timed, five times each: the synchronous `save_checkpoint` (the trainer before session 7),
and `CheckpointWriter.submit` (what the training waits for now) with a pinned and with a pageable host copy, plus
how long the background write then takes. Needs only torch (no Warp).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from gof_warp.checkpoint import CheckpointWriter, save_checkpoint  # noqa: E402
from gof_warp.io_utils import write_json_atomic  # noqa: E402

WIDTHS = {"means": 3, "sh_dc": 3, "sh_rest": 45, "log_scales": 3, "quats": 4, "opacity_logits": 1}


def state_of(n: int, device: str) -> dict:
    params = {k: torch.randn(n, w, device=device) for k, w in WIDTHS.items()}
    moments = {k: {"exp_avg": torch.randn_like(v), "exp_avg_sq": torch.rand_like(v)} for k, v in params.items()}
    return {"iteration": 1000, "params": params, "optimizer": {"state": moments}}


def sync(device):
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--gaussians", type=int, default=814_124)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    state = state_of(a.gaussians, a.device)
    mb = sum(t.numel() * 4 for t in [*state["params"].values(),
                                     *[m for d in state["optimizer"]["state"].values() for m in d.values()]]) / 1e6
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        def timed(name, fn):
            stalls, writes = [], []
            for i in range(a.repeats):
                sync(a.device)
                t0 = time.perf_counter()
                done = fn(Path(tmp) / name, i)
                stalls.append(time.perf_counter() - t0)
                done()
                writes.append(time.perf_counter() - t0)
            rows[name] = {"stall_s_median": round(statistics.median(stalls), 4), "stall_s": [round(s, 4) for s in stalls],
                          "until_written_s_median": round(statistics.median(writes), 4)}
            print(name, rows[name], flush=True)

        timed("synchronous_save", lambda d, i: (save_checkpoint(d, i, state), _noop)[1])
        for pinned in (True, False):
            writer = CheckpointWriter(pinned=pinned)
            timed("background_writer_" + ("pinned" if pinned else "pageable"),
                  lambda d, i, w=writer: (w.submit(d, i, state), w.wait)[1])
    result = {"machine": torch.cuda.get_device_name() if a.device.startswith("cuda") else platform.processor() or "cpu",
              "torch": torch.__version__, "gaussians": a.gaussians, "state_mb": round(mb, 1), "repeats": a.repeats,
              "note": "stall = time the training thread is held up; until_written = until the file is in place",
              "results": rows}
    if a.out:
        write_json_atomic(a.out, result)
    print(json.dumps(result, indent=1))
    return 0


def _noop():
    return None


if __name__ == "__main__":
    raise SystemExit(main())
