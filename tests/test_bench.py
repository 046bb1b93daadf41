"""The benchmark: the ``tiny`` suite end to end (train once, every method, table, charts), and resume."""

import csv
import json
import math

import pytest

from gof_warp import bench
from gof_warp.bench import main, run_suite, suite

NUMERIC = ("chamfer", "accuracy", "completeness", "fscore", "precision", "recall", "tau", "test_psnr", "test_ssim",
           "train_time_s", "extract_time_s", "total_time_s", "num_gaussians", "faces", "vertices", "components")
MIN_FSCORE_2TAU = 0.05  # 200 iterations at 40x40 is a rough model, but its surface must be near the GT's
MAX_CHAMFER = 0.2  # ~3% of the default scene's diagonal (~3.4); a mesh of floaters would score far worse


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    return out, run_suite("tiny", out, device="cpu")


def test_one_row_per_run_and_method_with_finite_numbers(tiny):
    out, rows = tiny
    expected = [(r.name, m.name) for r in suite("tiny") for m in r.methods]
    assert sorted((r["run"], r["method"]) for r in rows) == sorted(expected)
    assert len({r["method_kind"] for r in rows}) == 3
    for r in rows:
        for key in NUMERIC:
            assert isinstance(r[key], (int, float)) and math.isfinite(r[key]), (r["method"], key, r[key])
        assert r["error"] is None and r["machine_torch"] and r["extract_host_peak_rss_mb"] > 0
        assert r["total_time_s"] == pytest.approx(r["train_time_s"] + r["extract_time_s"], abs=2e-3)
        assert r["faces"] > 0 and r["chamfer"] < MAX_CHAMFER and r["fscore_2tau"] > MIN_FSCORE_2TAU, r
    # one model per run: every method of a run reports the same training
    assert len({(r["num_gaussians"], r["train_time_s"], r["test_psnr"]) for r in rows}) == 1
    saved = json.loads((out / "results.json").read_text())
    assert saved["rows"] == rows and saved["machine"]["torch"] and saved["machine"]["cpu_count"] >= 1
    with open(out / "results.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(rows) and "machine_platform" in table[0] and "chamfer" in table[0]


def test_charts_are_written(tiny):
    pytest.importorskip("matplotlib")
    out, _ = tiny
    for name in ("chamfer_vs_time.png", "fscore_vs_time.png", "chamfer_vs_gaussians.png", "chamfer_vs_faces.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000, name


def test_resume_skips_done_rows_and_reuses_the_trained_model(tiny, monkeypatch):
    out, rows = tiny

    def no_training(*a, **k):
        raise AssertionError("a finished run was trained or loaded again")

    monkeypatch.setattr(bench, "_train_or_load", no_training)
    assert run_suite("tiny", out, device="cpu") == rows  # complete: nothing recomputed
    monkeypatch.undo()

    dropped = rows[-1]
    saved = json.loads((out / "results.json").read_text())
    saved["rows"] = saved["rows"][:-1]
    (out / "results.json").write_text(json.dumps(saved))
    from gof_warp.trainer import Trainer

    monkeypatch.setattr(Trainer, "run", no_training)  # the model in runs/<run> is reused, not retrained
    again = run_suite("tiny", out, device="cpu")
    assert [(r["run"], r["method"]) for r in again] == [(r["run"], r["method"]) for r in rows]
    assert again[-1]["faces"] == dropped["faces"] and again[-1]["num_gaussians"] == dropped["num_gaussians"]


def test_list_and_bad_input(capsys, tmp_path):
    assert main(["--suite", "quick", "--list"]) == 0
    listed = capsys.readouterr().out
    assert all(r.name in listed for r in suite("quick")) and "tetra_bs8" in listed
    full = suite("full")
    assert {r.preset for r in full} >= {"default", "thin", "background", "textureless", "sparse"}
    assert {r.overrides["iterations"] for r in full} == {3000, 7000, 15000, 30000}
    (tmp_path / "results.json").write_text("not json")
    assert main(["--suite", "tiny", "--out", str(tmp_path)]) == 2
    assert "not a results table" in capsys.readouterr().err
