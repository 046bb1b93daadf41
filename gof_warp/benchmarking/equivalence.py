"""Is the test PSNR of n-GPU trainings within a margin of one GPU's? Welch's interval and the equivalence verdict.

Equal trainings on one GPU already differ by tenths of a dB (the GPU's atomics change the summation order, and
densification turns that into another model), so a single pair of runs cannot tell 0.1 dB. :func:`summarise` takes
several runs a side and applies the two one-sided tests for equivalence: the n-GPU mean is within ``margin`` dB of
the one-GPU mean when the 90 % confidence interval of the difference (Welch's, unequal variances) lies inside
(−margin, +margin). :func:`read_runs` reads a folder of ``metrics_g{n}_s{seed}.json`` (one per GPU count n and seed),
as ``benchmarks/distributed/dp_psnr.sh`` writes them.
"""

from __future__ import annotations

import json
import math
import re
import statistics
from pathlib import Path

from scipy import stats

RUN_NAME = re.compile(r"metrics_g(\d+)_s(\d+)\.json$")


def welch_interval(a: list[float], b: list[float], confidence: float = 0.90) -> dict:
    """Mean of b − mean of a with Welch's ``confidence`` interval; a and b need two or more values each."""
    if len(a) < 2 or len(b) < 2:
        raise ValueError(f"need two or more runs a side, got {len(a)} and {len(b)}")
    ma, mb = statistics.fmean(a), statistics.fmean(b)
    va, vb = statistics.variance(a, ma), statistics.variance(b, mb)
    se2 = va / len(a) + vb / len(b)
    if se2 == 0.0:
        return {"difference": mb - ma, "se": 0.0, "df": math.inf, "low": mb - ma, "high": mb - ma}
    df = se2**2 / ((va / len(a)) ** 2 / (len(a) - 1) + (vb / len(b)) ** 2 / (len(b) - 1))
    half = stats.t.ppf(0.5 + confidence / 2.0, df) * math.sqrt(se2)
    return {"difference": mb - ma, "se": math.sqrt(se2), "df": df, "low": mb - ma - half, "high": mb - ma + half}


def read_runs(folder: Path) -> dict[int, dict[int, dict]]:
    """{GPU count: {seed: metrics.json contents}} from the folder's ``metrics_g{n}_s{seed}.json``."""
    runs: dict[int, dict[int, dict]] = {}
    for f in sorted(folder.glob("metrics_g*_s*.json")):
        m = RUN_NAME.search(f.name)
        if m:
            runs.setdefault(int(m.group(1)), {})[int(m.group(2))] = json.loads(f.read_text())
    return runs


def summarise(runs: dict[int, dict[int, dict]], margin: float) -> dict:
    """Per GPU count: the runs' PSNRs, mean and spread; against one GPU: the difference, its 90 % interval, verdict."""
    out: dict = {"margin_db": margin, "sides": {}}
    by_seed = {n: [r for _, r in sorted(side.items())] for n, side in sorted(runs.items())}
    psnr = {n: [r["test"]["psnr"] for r in side] for n, side in by_seed.items()}
    for n, side in by_seed.items():
        values = psnr[n]
        row = {"seeds": sorted(runs[n]), "test_psnr": values, "mean": statistics.fmean(values),
               "sd": statistics.stdev(values) if len(values) > 1 else None,
               "train_time_s": [r["train_time_s"] for r in side],
               "num_gaussians": [r["num_gaussians"] for r in side],
               "largest_loss_ratio": [r.get("loss_spikes", {}).get("max_ratio") for r in side]}
        if n != 1 and 1 in psnr and len(values) > 1 and len(psnr[1]) > 1:
            w = welch_interval(psnr[1], values)
            row["against_one_gpu"] = {**w, "within_margin": bool(-margin < w["low"] and w["high"] < margin)}
        out["sides"][n] = row
    return out
