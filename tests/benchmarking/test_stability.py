"""Stability: degenerate hand-made models never crash or produce NaN/inf, and give sensible meshes."""

import json

import numpy as np
import pytest

from gof_warp.cli.bench import main
from gof_warp.benchmarking.stability import BLOB_RADIUS, CASES, FAR_RADIUS, STABILITY_METHODS, make_case

SHAPE_TOL = 0.25  # the blob's 0.5 level set lies within ~2σ (σ = 0.08) of its radius-0.5 sphere of centres
EMPTY_SIDE_TOL = 0.15  # half blob: centres at x > 0.05, σ = 0.08, so its level set ends near x = -0.07 (not -0.6)


_saved_inputs: dict = {}  # the bad-input part of the same stability.json


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    out = tmp_path_factory.mktemp("stability")
    assert main(["--suite", "stability", "--fast", "--quiet", "--device", "cpu", "--out", str(out)]) == 0
    data = json.loads((out / "stability.json").read_text())
    saved = data["reports"]
    _saved_inputs.update(summary=data["summary"], inputs=data["inputs"])
    assert len(saved) == len(CASES) * len(STABILITY_METHODS)
    by_case = {}
    for r in saved:
        by_case.setdefault(r["case"], {})[r["method"]] = r
    return by_case


@pytest.mark.slow
def test_every_case_and_method_reports_without_crash_or_nan(reports):
    for case, by_method in reports.items():
        assert set(by_method) == set(STABILITY_METHODS), case
        for method, r in by_method.items():
            assert r["outcome"] in ("ok", "error"), (case, method, r["message"])
            assert r["outcome"] != "crash"
            assert not r["nan_inf"], (case, method)
            if r["faces"]:
                assert np.isfinite(r["bbox_min"]).all() and np.isfinite(r["bbox_max"]).all(), (case, method)


@pytest.mark.slow
def test_good_blob_is_one_closed_component_near_the_sphere(reports):
    for method in ("tetra", "cubes"):
        r = reports["good"][method]
        assert r["outcome"] == "ok" and r["faces"] > 100 and r["components"] == 1, (method, r)
        half = np.maximum(np.abs(r["bbox_min"]), np.abs(r["bbox_max"]))
        assert np.all(np.abs(half - BLOB_RADIUS) < SHAPE_TOL), (method, half)


@pytest.mark.slow
def test_opacity_zero_model_gives_an_empty_mesh_not_an_error(reports):
    for method, r in reports["opacity_0"].items():
        assert r["outcome"] == "ok" and r["faces"] == 0, (method, r)


@pytest.mark.slow
def test_tiny_and_flat_gaussians_do_not_change_the_gof_mesh(reports):
    good = reports["good"]["tetra"]
    for case in ("tiny_scales", "flat_scales", "opacity_1"):
        r = reports[case]["tetra"]
        assert r["outcome"] == "ok" and r["components"] == 1, (case, r)
        assert np.allclose(r["bbox_min"], good["bbox_min"], atol=0.05), case
        assert np.allclose(r["bbox_max"], good["bbox_max"], atol=0.05), case


@pytest.mark.slow
def test_gaussians_outside_every_camera_stay_out_of_the_gof_mesh(reports):
    r = reports["far_outside"]["tetra"]
    assert r["outcome"] == "ok" and r["faces"] > 100 and r["faces_far"] == 0, r
    assert np.all(np.abs(r["bbox_min"]) < FAR_RADIUS) and np.all(np.abs(r["bbox_max"]) < FAR_RADIUS)


@pytest.mark.slow
def test_empty_region_seen_by_cameras_gets_no_surface(reports):
    for method in ("tetra", "cubes"):
        r = reports["empty_region"][method]
        assert r["outcome"] == "ok" and r["faces"] > 0, (method, r)
        assert r["bbox_min"][0] > -EMPTY_SIDE_TOL, (method, r["bbox_min"])


def test_cases_build_the_degenerate_values_they_name():
    g, cams = make_case("tiny_scales")
    assert float(g.raw_scales.min()) < 1e-7 and len(cams) == 8
    g, _ = make_case("huge_scales")
    assert float(g.raw_scales.max()) > 999
    g, _ = make_case("opacity_0")
    assert float(g.raw_opacities.max()) < 1e-5
    with pytest.raises(ValueError, match="unknown stability case"):
        make_case("nope")


@pytest.mark.slow
def test_dense_grid_bounds_ignore_huge_and_unseen_gaussians(reports):
    """cubes/TSDF size their grid from the Gaussians the cameras see, with capped 3σ widening."""
    for case in ("huge_scales", "far_outside"):
        for method in ("cubes", "tsdf"):
            r = reports[case][method]
            assert r["outcome"] == "ok" and r["faces"] > 100 and r["faces_far"] == 0, (case, method, r)
            assert np.all(np.abs(r["bbox_min"]) < FAR_RADIUS) and np.all(np.abs(r["bbox_max"]) < FAR_RADIUS), (case, method)


@pytest.mark.slow
def test_bad_inputs_are_counted_per_kind_with_no_crash_or_nan(reports):
    """The bad-input cases (stability_inputs.run_input_cases) as the suite ran them: all as expected, no crash or NaN,
    nothing overwritten, each a clear error or a warning (tests/cli/test_bad_inputs.py ran them a second time for these
    checks; they are here now)."""
    summary, inputs = _saved_inputs["summary"], _saved_inputs["inputs"]
    assert set(summary) == {"model", "scene", "ply", "config", "options"}
    assert {r["kind"] for r in inputs} == {"scene", "ply", "config", "options"}
    assert summary["model"]["tried"] == len(CASES) * len(STABILITY_METHODS)
    for kind, c in summary.items():
        assert c["crash"] == 0 and c["nan_inf"] == 0, (kind, c)
        if kind != "model":
            assert c["overwritten"] == 0 and c["error"] + c["warning"] == c["tried"], (kind, c)
    assert all(r["as_expected"] for r in inputs), [r for r in inputs if not r["as_expected"]]
    assert summary["scene"]["warning"] >= 2 and summary["ply"]["error"] >= 6
    # the cases: scene files outside the folder, FIFOs, oversized headers, bad matrices and camera files,
    # bad config files, nonsense extract/evaluate options, an output over the model: each a clear error
    named = {r["case"] for r in inputs}
    assert {"path_outside_scene_ingp", "fifo_image_colmap", "header_20000x20000_colmap", "config_latin1",
            "resolution_negative", "levels_repeated", "binary_steps_1000", "extract_out_over_the_model",
            "evaluate_mesh_without_faces", "render_near_negative", "scene_at_1e-6_scale"} <= named
