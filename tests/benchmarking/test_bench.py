"""The benchmark: the ``tiny`` suite end to end through the CLI (train once with a snapshot, every method at the
end and at the snapshot, table, charts), resume, ``--only`` / ``--time-limit``, and the ``full`` suite's plan."""

import csv
import json
import math

import pytest

from gof_warp.cli import bench
from gof_warp.cli.bench import (
    EXIT_RUNS_LEFT,
    Run,
    Sizing,
    main,
    pending,
    run_suite,
    suite,
    tetra,
)
from gof_warp.benchmarking.report import load_rows, row_key
from gof_warp.core.errors import GofError

NUMERIC = ("chamfer", "accuracy", "completeness", "fscore", "precision", "recall", "tau", "test_psnr", "test_ssim",
           "train_time_s", "extract_time_s", "total_time_s", "num_gaussians", "faces", "vertices", "components",
           "mesh_psnr", "mesh_ssim", "mesh_coverage")
MODEL_NUMERIC = ("test_psnr", "test_ssim", "train_time_s", "total_time_s", "num_gaussians")  # render_only rows
MIN_FSCORE_2TAU = 0.05  # 200 iterations at 40x40 is a rough model, but its surface must be near the GT's
MAX_CHAMFER = 0.2  # ~3% of the default scene's diagonal (~3.4); a mesh of floaters would score far worse
FULL_MAX_TOTAL_MIN = 50  # the full suite must fit the lead's ~55 minutes of device time, call start-ups included


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    rc = main(["--suite", "tiny", "--out", str(out), "--device", "cpu", "--only", "default_*", "--time-limit",
               "3600", "--runs-dir", str(out / "models"), "--quiet"])
    assert rc == 0
    return out, load_rows(out)


def _expected_keys(runs):
    return sorted((r.name, k, m.name) for r in runs for k, methods in
                  [*((s, r.snapshot_methods) for s in r.snapshots), (r.overrides["iterations"], r.methods)]
                  for m in methods)


@pytest.mark.slow
def test_one_row_per_run_iteration_and_method_with_finite_numbers(tiny):
    out, rows = tiny
    assert sorted(row_key(r) for r in rows) == _expected_keys(suite("tiny"))
    assert {r["method_kind"] for r in rows} == {"tetra", "cubes", "tsdf", "none"}
    for r in rows:
        mesh = r["method_kind"] != "none"
        for key in NUMERIC if mesh else MODEL_NUMERIC:
            assert isinstance(r[key], (int, float)) and math.isfinite(r[key]), (r["method"], key, r[key])
        assert r["error"] is None and r["machine_torch"] and r["extract_host_peak_rss_mb"] > 0
        assert r["total_time_s"] == pytest.approx(r["train_time_s"] + (r["extract_time_s"] or 0), abs=2e-3)
        if mesh:
            assert r["faces"] > 0 and r["chamfer"] < MAX_CHAMFER and r["fscore_2tau"] > MIN_FSCORE_2TAU, r
            # the vertex-coloured mesh looks like the photos: well above a flat grey guess, at most the Gaussians' + 3
            assert 12.0 < r["mesh_psnr"] < r["test_psnr"] + 3.0 and 0.0 < r["mesh_coverage"] <= 1.0, r
        else:
            assert r["faces"] is None and r["chamfer"] is None and r["extract_time_s"] is None
    # one model per (run, iteration): its methods report the same training; the snapshot is the trainer's
    models = {(r["iteration"], r["snapshot"], r["num_gaussians"], r["train_time_s"], r["test_psnr"]) for r in rows}
    assert len(models) == 2
    (k, snap, n, t, psnr), (last, last_is_snapshot, _, t_last, _) = sorted(models)
    metrics = json.loads((out / "models" / "default_tiny" / "metrics.json").read_text())
    assert not (out / "runs").exists()  # --runs-dir: the results folder holds only the table and charts
    rec, = metrics["snapshots"]
    assert snap and not last_is_snapshot and last == metrics["iterations"]
    assert (k, n, t, psnr) == (rec["iteration"], rec["num_gaussians"], rec["train_time_s"], rec["test"]["psnr"])
    assert 0 < t < t_last == metrics["train_time_s"]
    saved = json.loads((out / "results.json").read_text())
    assert saved["rows"] == rows and saved["machine"]["torch"] and saved["machine"]["cpu_count"] >= 1
    with open(out / "results.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert len(table) == len(rows) and "machine_platform" in table[0] and "iteration" in table[0]


@pytest.mark.slow
def test_charts_are_written(tiny):
    pytest.importorskip("matplotlib")
    out, _ = tiny
    for name in ("chamfer_vs_time.png", "fscore_vs_time.png", "chamfer_vs_gaussians.png", "chamfer_vs_faces.png",
                 "psnr_vs_train_time.png", "mesh_psnr_vs_faces.png"):
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000, name


@pytest.mark.slow
def test_resume_skips_done_rows_and_reuses_the_trained_model_and_snapshot(tiny, monkeypatch):
    out, rows = tiny

    def no_training(*a, **k):
        raise AssertionError("a finished run was trained or loaded again")

    monkeypatch.setattr(bench, "_train_or_load", no_training)
    assert run_suite("tiny", out, device="cpu") == rows  # complete: nothing recomputed (nor looked for)
    monkeypatch.undo()

    snapshot_tetra = next(i for i, r in enumerate(rows) if r["snapshot"] and r["method_kind"] == "tetra")
    dropped = {row_key(rows[i]): rows[i] for i in (snapshot_tetra, len(rows) - 1)}
    saved = json.loads((out / "results.json").read_text())
    saved["rows"] = [r for r in saved["rows"] if row_key(r) not in dropped]
    (out / "results.json").write_text(json.dumps(saved))
    from gof_warp.training.trainer import Trainer

    monkeypatch.setattr(Trainer, "run", no_training)  # the model and snapshot in models/<run> are reused
    again = run_suite("tiny", out, device="cpu", runs_dir=out / "models")
    assert sorted(row_key(r) for r in again) == sorted(row_key(r) for r in rows)
    for r in again[-2:]:
        before = dropped[row_key(r)]
        assert (r["faces"], r["num_gaussians"], r["train_time_s"]) == (before["faces"], before["num_gaussians"],
                                                                        before["train_time_s"])


def test_time_limit_starts_only_runs_that_fit(tmp_path, monkeypatch, capsys):
    trained = []

    def fake_training(run, run_dir, device, data=None):
        trained.append(run.name)
        return object(), None, None, {"iterations": 10}, run_dir

    monkeypatch.setattr(bench, "_train_or_load", fake_training)
    monkeypatch.setattr(bench, "_extract_row", lambda run, method, model, *a: {
        "run": run.name, "iteration": model.iteration, "method": method.name, "scene": run.preset})
    monkeypatch.setattr(bench, "write_charts", lambda *a: [])
    runs = [Run(name, "default", (8, 8), 2, overrides={"iterations": 10}, methods=(tetra(0), tetra(1)), budget_s=b)
            for name, b in (("big", 100.0), ("small", 10.0))]
    rows = run_suite("tiny", tmp_path, runs=runs, time_limit=50)
    assert trained == ["small"] and [row_key(r) for r in rows] == [("small", 10, "tetra_bs0"), ("small", 10, "tetra_bs1")]
    assert [r.name for r in runs if pending(r, {row_key(x) for x in rows})] == ["big"]
    rows = run_suite("tiny", tmp_path, runs=runs, time_limit=500)  # the next call does what is left
    assert trained == ["small", "big"] and len(rows) == 4 and not any(pending(r, {row_key(x) for x in rows}) for r in runs)

    assert main(["--suite", "tiny", "--out", str(tmp_path / "t0"), "--time-limit", "0", "--quiet"]) == EXIT_RUNS_LEFT
    err = capsys.readouterr().err
    assert "1 runs left (default_tiny); run the same command again" in err and "Over --time-limit" in err
    assert load_rows(tmp_path / "t0") == []


def test_full_suite_fits_the_gpu_calls():
    full = suite("full")
    z = Sizing()
    assert {r.preset for r in full} >= {"default", "thin", "garden", "textureless", "sparse", "spot",
                                        "real:nerf_mic", "real:dtu_scan24"}
    assert len({r.name for r in full}) == len(full)
    for r in full:
        cfg = bench.run_config(r)  # every override is a real config key; snapshots lie inside the run
        assert 0 < r.budget_s <= z.max_run_s, (r.name, r.budget_s)
        assert cfg.snapshot_iterations == list(r.snapshots) and (r.snapshot_methods or not r.snapshots)
    lengths = {k for r in full if r.preset == "default" for k in (*r.snapshots, r.overrides["iterations"])}
    assert lengths >= {3000, 7000, 15000}
    assert sum(r.budget_s for r in full) <= FULL_MAX_TOTAL_MIN * 60
    garden = next(r for r in full if r.preset == "garden")  # its far background must be inside the initialisation
    assert tuple(bench.run_config(garden).model.init_box) == (-8.0, -8.0, -8.0, 8.0, 8.0, 8.0)
    noreg = next(r for r in full if r.name.endswith("_noreg"))
    assert bench.run_config(noreg).loss.lambda_normal == 0.0
    assert bench.run_config(noreg).loss.regularization_from_iter < noreg.overrides["iterations"]
    slower = bench.full_suite(Sizing(s_per_iteration=2 * z.s_per_iteration))  # the cost model scales
    assert max(r.budget_s for r in slower) > z.max_run_s


def test_gof_schedule_is_the_identity_at_30k_and_compresses_below():
    from gof_warp.core.config import merge
    from gof_warp.training.trainer import TrainConfig

    base = TrainConfig()
    full = merge(base, bench.gof_schedule(30_000))
    assert (full.densify, full.loss, full.optim) == (base.densify, base.loss, base.optim)
    half = merge(base, bench.gof_schedule(15_000))
    assert half.loss.regularization_from_iter == 7_500 and half.densify.stop_iter == 7_500
    assert half.densify.opacity_reset_interval == 1_500 and half.optim.means_lr_max_steps == 15_000
    assert half.densify.interval == base.densify.interval  # ~100 iterations to recover from a reset before a prune
    assert half.densify.start_iter % half.densify.interval == 0 and half.densify.start_iter == 200


def test_list_only_and_bad_input(capsys, tmp_path):
    assert main(["--suite", "full", "--list", "--only", "default_*", "real_dtu*"]) == 0
    listed = capsys.readouterr().out
    names = [r.name for r in suite("full") if r.name.startswith(("default_", "real_dtu"))]
    assert [line.split()[0] for line in listed.splitlines() if not line.startswith((" ", "total"))] == names
    assert "total budget" in listed and "tetra_bs8" in listed and "snapshots at 3000, 7000" in listed
    assert main(["--suite", "full", "--list", "--only", "nope*"]) == 2
    assert "nope*" in capsys.readouterr().err
    (tmp_path / "results.json").write_text("not json")
    assert main(["--suite", "tiny", "--out", str(tmp_path)]) == 2
    assert "not a results table" in capsys.readouterr().err
    with pytest.raises(GofError, match="--data"):
        bench.scene_folder(Run("r", "real:nope", (8, 8), None), tmp_path / "r", data=tmp_path)


@pytest.mark.parametrize("overrides, message", [
    ({"densify": {"max_gausians": 1000}}, r"run typo: unknown key 'densify\.max_gausians'; valid keys of 'densify'"),
    ({"densfy": {"max_gaussians": 1000}}, r"run typo: unknown key 'densfy'"),
    ({"loss": {"lambda_normal": "off"}}, r"run typo\.loss\.lambda_normal: expected a number"),
    ({"iterations": 100, "densify": {"max_gaussians": {"n": 1}}}, r"run typo.*max_gaussians"),
])
def test_a_typo_in_a_run_definition_is_an_error_naming_the_key(overrides, message):
    with pytest.raises(GofError, match=message):  # at definition, not minutes later when the run trains
        Run("typo", "default", (8, 8), 2, overrides=overrides)


def test_snapshots_outside_the_run_are_an_error_naming_the_run():
    with pytest.raises(GofError, match=r"run late: snapshot_iterations"):
        Run("late", "default", (8, 8), 2, overrides={"iterations": 100}, snapshots=(100,))


def test_every_built_in_suite_and_stability_run_is_a_checked_config():
    from gof_warp.benchmarking.runs import check_overrides
    from gof_warp.benchmarking.stability import TRAINED_PRESETS, trained_run

    runs = [r for name in ("tiny", "quick", "full") for r in suite(name)] + [trained_run(p) for p in TRAINED_PRESETS]
    for r in runs:  # Run checks on construction; checked again here so the test fails if that check goes away
        cfg = check_overrides(r.overrides, r.name, r.snapshots)
        assert cfg.iterations == r.overrides["iterations"], r.name
    budget = next(r for r in suite("quick") if r.name.endswith("budget1k"))
    assert check_overrides(budget.overrides, budget.name).densify.max_gaussians == 1000
