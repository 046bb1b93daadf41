"""Time and host memory of the chunked Delaunay against the chunk size (CPU).

    python benchmarks/extract/delaunay_memory.py --points 3000000 --chunks 20 60 120 --workers 2 \
        --out benchmarks/extract/results/delaunay_memory_3m_cpu.json

Points shaped like GOF's grid (clusters of 9 around centres, σ = 0.03 in a cloud of σ = 2), the same seed for
every setting. Each setting runs in its own process (a fresh heap), which samples its resident set size every
20 ms; the JSON has per setting the wall time, the peak above the process's start and the exact-merge counters.
A chunk in flight holds memory ∝ its points, so the peak is ≈ workers × chunk size × a per-point cost + a part
∝ all points (docstring of ``gof_warp/delaunay.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _rss() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS"):
                return int(line.split()[1]) * 1024
    return 0


def one(points: int, chunks: int, workers: int) -> dict:
    import numpy as np

    sys.path.insert(0, str(ROOT))
    from gof_warp.delaunay import delaunay

    rng = np.random.default_rng(0)
    centres = rng.normal(size=(points // 9, 3)) * 2.0
    p = (centres[:, None, :] + rng.normal(size=(len(centres), 9, 3)) * 0.03).reshape(-1, 3).astype(np.float32)
    peak, done = [0], threading.Event()

    def sample():
        while not done.is_set():
            peak[0] = max(peak[0], _rss())
            time.sleep(0.02)

    start = _rss()
    threading.Thread(target=sample, daemon=True).start()
    stats: dict = {}
    t = time.perf_counter()
    tets = delaunay(p, workers=workers, chunks=chunks, stats=stats)
    wall = time.perf_counter() - t
    done.set()
    time.sleep(0.05)
    return {"points": int(len(p)), "chunks": chunks, "workers": workers, "tetrahedra": int(len(tets)),
            "time_s": round(wall, 2), "peak_above_start_gb": round((peak[0] - start) / 1e9, 3),
            **{k: v for k, v in stats.items() if not isinstance(v, (list, dict))}}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=900_000)
    ap.add_argument("--chunks", type=int, nargs="+", default=[6, 18, 36, 72])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--one", type=int, default=None, help=argparse.SUPPRESS)  # child: one setting
    a = ap.parse_args()
    if a.one is not None:
        print(json.dumps(one(a.points, a.one, a.workers)))
        return 0
    rows = []
    for c in a.chunks:
        out = subprocess.run([sys.executable, __file__, "--points", str(a.points), "--workers", str(a.workers),
                              "--one", str(c)], capture_output=True, text=True, check=True,
                             env={**os.environ, "OMP_NUM_THREADS": "1"})
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
        print(rows[-1], flush=True)
    result = {"machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs (the dev box)",
              "settings": rows}
    if a.out:
        sys.path.insert(0, str(ROOT))
        from gof_warp.io_utils import write_json_atomic

        write_json_atomic(a.out, result)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
