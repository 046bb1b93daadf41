"""gof_warp.benchmarking.equivalence: Welch's interval and the equivalence verdict of issue 17's PSNR runs."""

import json

import numpy as np
import pytest
from scipy import stats

from gof_warp.benchmarking.equivalence import read_runs, summarise, welch_interval


def test_welch_interval_matches_scipy():
    rng = np.random.default_rng(3)
    a, b = list(rng.normal(30.0, 0.05, 5)), list(rng.normal(30.02, 0.11, 4))
    w = welch_interval(a, b, 0.90)
    ci = stats.ttest_ind(b, a, equal_var=False).confidence_interval(0.90)
    assert w["difference"] == pytest.approx(np.mean(b) - np.mean(a), abs=1e-12)
    assert (w["low"], w["high"]) == pytest.approx((ci.low, ci.high), abs=1e-9)


def test_welch_interval_needs_two_runs_a_side():
    with pytest.raises(ValueError, match="two or more"):
        welch_interval([1.0], [1.0, 2.0])


def _write(folder, n, seed, psnr):
    (folder / f"metrics_g{n}_s{seed}.json").write_text(
        json.dumps({"test": {"psnr": psnr}, "train_time_s": 1.0, "num_gaussians": 10}))


def test_verdict_within_and_not_shown(tmp_path):
    for s, (one, two, four) in enumerate([(37.70, 37.71, 37.20), (37.75, 37.74, 37.30), (37.72, 37.73, 37.25)]):
        _write(tmp_path, 1, s, one)
        _write(tmp_path, 2, s, two)
        _write(tmp_path, 4, s, four)
    _write(tmp_path, 8, 0, 37.7)  # a single run: no interval
    s = summarise(read_runs(tmp_path), 0.1)
    assert s["sides"][2]["against_one_gpu"]["within_margin"] is True
    assert s["sides"][4]["against_one_gpu"]["within_margin"] is False  # 0.47 dB lower
    assert "against_one_gpu" not in s["sides"][8] and s["sides"][8]["sd"] is None
    assert s["sides"][1]["seeds"] == [0, 1, 2]
