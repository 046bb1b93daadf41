"""Is the test PSNR of n-GPU trainings within a margin of one GPU's? (issue 17, dp_psnr.sh)

Equal trainings on one GPU already differ by tenths of a dB (the GPU's atomics change the summation order, and
densification turns that into another model; 0.49 dB was measured between two equal runs). So a single pair of
runs cannot tell 0.1 dB. This reads several runs a side (``metrics_g{n}_s{seed}.json``, one per GPU count n and seed)
and applies the two one-sided tests for equivalence: the n-GPU mean is within ``--margin`` dB of the one-GPU mean when
the 90 % confidence interval of the difference (Welch's, unequal variances) lies inside (−margin, +margin).

    python benchmarks/distributed/psnr_equivalence.py RESULTS_DIR [--margin 0.1] [--out summary.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from gof_warp.benchmarking.equivalence import read_runs, summarise


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--margin", type=float, default=0.1)
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    s = summarise(read_runs(a.folder), a.margin)
    for n, row in s["sides"].items():
        sd = f"{row['sd']:.3f}" if row["sd"] is not None else "-"
        line = f"{n} GPU(s): {len(row['test_psnr'])} runs, test PSNR mean {row['mean']:.3f} dB, sd {sd}"
        if "against_one_gpu" in row:
            w = row["against_one_gpu"]
            line += (f"; minus one GPU {w['difference']:+.3f} dB, 90 % interval [{w['low']:+.3f}, {w['high']:+.3f}]"
                     f" -> {'within' if w['within_margin'] else 'NOT shown within'} ±{a.margin} dB")
        print(line)
    if a.out:
        a.out.write_text(json.dumps(s, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
