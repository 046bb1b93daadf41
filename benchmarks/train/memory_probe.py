"""Where a training run's reserved GPU memory goes: torch's allocator read at every iteration, and a memory snapshot
taken at the iteration where reserved memory first jumps.

    python benchmarks/train/memory_probe.py SCENE --config dtu --iterations 3000 --out DIR [--alloc-conf CONF] [override ...]

The trainer is built as ``python -m gof_warp.train`` builds it (preset + overrides) and runs its own loop one iteration
at a time. After every iteration the script reads ``torch.cuda.memory_allocated / memory_reserved`` (host-side counters:
no synchronisation) and the number of the allocator's ``cudaMalloc`` calls and frees. ``--alloc-conf`` is given to
``torch.cuda.memory._set_allocator_settings`` before the first allocation (e.g. ``expandable_segments:True``).

With ``--history``, torch's allocation history (``torch.cuda.memory._record_memory_history``, Python stacks, the last
``--history`` events) is recorded and dumped (``snapshot.pickle``, readable with ``torch.cuda.memory._snapshot`` tools
or https://pytorch.org/memory_viz) the first time reserved memory grows by more than ``--jump-mb`` in one iteration (or exceeds the allocated memory
by ``--gap-mb``),
together with a summary of the segments: per stream, and the Python frame that allocated each segment.

Writes ``DIR/memory_probe.json``: per-iteration ``[iteration, gaussians, allocated_mb, reserved_mb, mallocs, frees]``,
the phases' peaks and the elapsed training time.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from collections import Counter
from pathlib import Path

import torch


def _segments_summary(snapshot: dict) -> dict:
    """Reserved bytes per stream and per allocating frame (the first frame inside gof_warp), from a snapshot."""
    by_stream: Counter = Counter()
    by_frame: Counter = Counter()
    free_in_segment = 0
    for seg in snapshot["segments"]:
        by_stream[str(seg.get("stream"))] += seg["total_size"]
        free_in_segment += sum(b["size"] for b in seg["blocks"] if b["state"] == "inactive")
        frames = seg.get("frames") or []
        where = next((f"{f['filename'].split('gof_warp/')[-1]}:{f['line']} {f['name']}" for f in frames
                      if "gof_warp" in f["filename"]), frames[0]["filename"] if frames else "?")
        by_frame[where] += seg["total_size"]
    mb = 2**20
    return {"segments": len(snapshot["segments"]), "inactive_mb": round(free_in_segment / mb, 1),
            "by_stream_mb": {k: round(v / mb, 1) for k, v in by_stream.most_common()},
            "by_frame_mb": {k: round(v / mb, 1) for k, v in by_frame.most_common(25)}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--config", default="dtu")
    ap.add_argument("--iterations", type=int, default=3000)
    ap.add_argument("--out", type=Path, default=Path("memory_probe_out"))
    ap.add_argument("--alloc-conf", default=None, help="torch allocator settings, e.g. expandable_segments:True")
    ap.add_argument("--history", type=int, default=0, help="record this many allocation events (0: off)")
    ap.add_argument("--jump-mb", type=float, default=1024.0)
    ap.add_argument("--gap-mb", type=float, default=3072.0,
                    help="also dump when reserved exceeds allocated by this much (a gradual growth)")
    ap.add_argument("--cap-gb", type=float, default=None, help="torch.cuda.set_per_process_memory_fraction to this size")
    ap.add_argument("--cudnn-benchmark", choices=("on", "off"), default="on",
                    help="cuDNN's autotuner during the loop (the trainer keeps it on)")
    ap.add_argument("--empty-cache-on-change", action="store_true",
                    help="torch.cuda.empty_cache() after every iteration that changed the Gaussian count")
    ap.add_argument("overrides", nargs="*")
    a = ap.parse_intermixed_args(argv)

    from gof_warp.core.devices import cudnn_benchmark, resolve_device
    from gof_warp.data import load_scene
    from gof_warp.training.presets import resolve_config
    from gof_warp.training.trainer import Trainer

    a.out.mkdir(parents=True, exist_ok=True)
    if a.alloc_conf:
        torch.cuda.memory._set_allocator_settings(a.alloc_conf)
    device = torch.device(resolve_device("auto"))
    if a.cap_gb:
        total = torch.cuda.get_device_properties(device).total_memory
        torch.cuda.set_per_process_memory_fraction(min(1.0, a.cap_gb * 2**30 / total), device)
    if a.history:
        torch.cuda.memory._record_memory_history(max_entries=a.history, stacks="python")
    cfg = resolve_config(a.config, a.overrides, a.iterations)
    cfg.checkpoint_every = 0
    cfg.snapshot_iterations = []
    scene = load_scene(a.scene, cfg.data)
    trainer = Trainer(scene, cfg, a.out / "run", str(device))
    rows, dumped = [], None
    mb = 2**20
    last_reserved = 0
    t0 = time.perf_counter()
    torch.backends.cudnn.benchmark = False
    with cudnn_benchmark(a.cudnn_benchmark == "on"):
        trainer._warm_up()
        t_loop = time.perf_counter()
        while trainer.iteration < cfg.iterations:
            n_before = len(trainer.gaussians)
            trainer._pending.add(*trainer._step())
            if a.empty_cache_on_change and len(trainer.gaussians) != n_before:
                torch.cuda.empty_cache()
            if len(trainer._pending) >= 50:
                trainer._drain()
            s = torch.cuda.memory_stats(device)
            reserved = s["reserved_bytes.all.current"]
            rows.append([trainer.iteration, len(trainer.gaussians), round(s["allocated_bytes.all.current"] / mb, 1),
                         round(reserved / mb, 1), s.get("num_device_alloc", 0), s.get("num_device_free", 0)])
            allocated = s["allocated_bytes.all.current"]
            if a.history and dumped is None and (reserved - last_reserved > a.jump_mb * mb
                                                 or reserved - allocated > a.gap_mb * mb):
                snap = torch.cuda.memory._snapshot()
                with open(a.out / "snapshot.pickle", "wb") as f:
                    pickle.dump(snap, f)
                dumped = {"iteration": trainer.iteration, "from_mb": round(last_reserved / mb, 1),
                          "to_mb": round(reserved / mb, 1), **_segments_summary(snap)}
                print("jump:", json.dumps(dumped, indent=1), flush=True)
            last_reserved = reserved
        trainer._drain()
        torch.cuda.synchronize(device)
        t_end = time.perf_counter()
    peaks = {"max_reserved_mb": round(torch.cuda.max_memory_reserved(device) / mb, 1),
             "max_allocated_mb": round(torch.cuda.max_memory_allocated(device) / mb, 1)}
    snap_end = _segments_summary(torch.cuda.memory._snapshot())
    stats = torch.cuda.memory_stats(device)
    peaks.update({k: stats.get(k, 0) for k in ("num_alloc_retries", "num_ooms", "num_device_alloc", "num_device_free")})
    result = {"scene": a.scene, "config": a.config, "overrides": a.overrides, "alloc_conf": a.alloc_conf,
              "cap_gb": a.cap_gb, "cudnn_benchmark": a.cudnn_benchmark,
              "empty_cache_on_change": a.empty_cache_on_change, "device": torch.cuda.get_device_name(device), "torch": torch.__version__,
              "loop_s": round(t_end - t_loop, 2), "total_s": round(t_end - t0, 2), **peaks, "jump": dumped,
              "segments_at_end": snap_end, "rows": rows}
    (a.out / "memory_probe.json").write_text(json.dumps(result))
    print(json.dumps({k: v for k, v in result.items() if k != "rows"}, indent=1))
    step = max(1, len(rows) // 40)
    for r in rows[::step]:
        print(*r)
    return 0


if __name__ == "__main__":
    sys.exit(main())
