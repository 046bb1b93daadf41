"""Where the GPU waits for the host: idle gaps of a ``torch.profiler`` trace, by the op that launched the next kernel.

    python benchmarks/train/gpu_gaps.py TRACE.json.gz --iterations N [--out F.json]

For a trace written by ``profile_train.py`` (``trace.json.gz``, ``N`` traced iterations): every gap of more than
``--min-us`` between consecutive GPU activities (kernels, memsets, copies) is charged to the innermost CPU op around
the runtime call that launched the activity after it, and to the trainer stage (``train.render``, ``train.loss``,
``train.backward``, ...) that call fell in. A gap there means the GPU had run out of queued work: the host was the
bottleneck at that point of the step.
"""

from __future__ import annotations

import argparse
import bisect
import gzip
import json
import sys
from collections import Counter
from pathlib import Path


def gaps(events: list[dict], min_us: float = 5.0) -> tuple[Counter, Counter, float, float]:
    """``(by_op, by_stage, gap_us, span_us)`` for the trace's GPU timeline."""
    spans = [e for e in events if e.get("ph") == "X"]
    gpu = sorted((e for e in spans if e.get("cat") in ("kernel", "gpu_memcpy", "gpu_memset")), key=lambda e: e["ts"])
    runtime = {e["args"].get("correlation"): e for e in spans if e.get("cat") == "cuda_runtime" and "args" in e}
    ops = sorted((e for e in spans if e.get("cat") == "cpu_op"), key=lambda e: e["ts"])
    starts = [e["ts"] for e in ops]
    stages = [e for e in spans if e.get("cat") == "user_annotation" and e["name"].startswith("train.")]

    def innermost(ts):
        best = None
        for e in ops[max(0, bisect.bisect_right(starts, ts) - 400) : bisect.bisect_right(starts, ts)]:
            if e["ts"] <= ts <= e["ts"] + e["dur"] and (best is None or e["dur"] < best["dur"]):
                best = e
        return best["name"] if best else "(python)"

    def stage(ts):
        return next((s["name"] for s in stages if s["ts"] <= ts <= s["ts"] + s["dur"]), "(outside a stage)")

    by_op, by_stage, total = Counter(), Counter(), 0.0
    for a, b in zip(gpu[:-1], gpu[1:]):
        g = b["ts"] - (a["ts"] + a["dur"])
        call = runtime.get(b.get("args", {}).get("correlation"))
        if g <= min_us or call is None:
            continue
        total += g
        by_op[innermost(call["ts"])] += g
        by_stage[stage(call["ts"])] += g
    span = gpu[-1]["ts"] + gpu[-1]["dur"] - gpu[0]["ts"] if gpu else 0.0
    return by_op, by_stage, total, span


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("trace")
    ap.add_argument("--iterations", type=int, required=True)
    ap.add_argument("--min-us", type=float, default=5.0)
    ap.add_argument("--out")
    a = ap.parse_args(argv)
    with gzip.open(a.trace) if a.trace.endswith(".gz") else open(a.trace) as f:
        events = json.load(f)
    events = events["traceEvents"] if isinstance(events, dict) else events
    by_op, by_stage, total, span = gaps(events, a.min_us)
    n = a.iterations
    res = {"iterations": n, "gpu_span_ms_per_it": round(span / 1e3 / n, 3), "gpu_idle_ms_per_it": round(total / 1e3 / n, 3),
           "idle_ms_per_it_by_stage": {k: round(v / 1e3 / n, 3) for k, v in by_stage.most_common()},
           "idle_ms_per_it_by_launching_op": {k: round(v / 1e3 / n, 3) for k, v in by_op.most_common(30)}}  # fmt: skip
    print(json.dumps(res, indent=1))
    if a.out:
        Path(a.out).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
