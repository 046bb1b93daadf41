"""Summary of run_cpu.sh's three runs: test PSNR (mean, worst view), per-view PSNR, Gaussians, training time; and a
picture of every test view per run (photo | triangulated | random | random + surface bounds) in OUT/test_views.png."""

from __future__ import annotations

import json
import sys
from pathlib import Path

RUNS = ("auto", "random", "surface")


def main(out: Path) -> int:
    rows = {}
    for run in RUNS:
        m = json.loads((out / run / "metrics.json").read_text())
        per = [round(v["psnr"], 2) for v in m["test"]["per_image"]]
        rows[run] = {"test_psnr": round(m["test"]["psnr"], 2), "worst_view_psnr": min(per), "per_view_psnr": per,
                     "num_gaussians": m["num_gaussians"], "train_time_s": round(m["train_time_s"], 1),
                     "surface_points": m.get("init", {}).get("surface_points")}
    (out / "summary.json").write_text(json.dumps(rows, indent=1))
    print(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
