"""Region scoring (gof_warp.eval.region_metrics) on tiny hand-built scenes: crop-then-sample against the old
sample-then-crop, the exact mesh at the floor, ground holes and waves, unseen faces left out, the CLI."""

import json

import numpy as np
import pytest

from gof_warp import look_at
from gof_warp.cli.evaluate import main as evaluate_main
from gof_warp.eval.geometry_metrics import mesh_accuracy_completeness
from gof_warp.eval.region_metrics import Ground, crop_mesh, in_region, observe, region_scores, seen_faces
from gof_warp.synthetic import meshes as M

SIZE = 32  # pixels per image side: enough rays for metre-sized faces, seconds on a CPU
FLOOR_GAP = 0.02  # the exact mesh's F-score must be within this of the floor (independent samples)
# Ground tests: ~80k samples on ~16 m^2 of seen ground = 1.4 cm spacing; a point of the exact surface has no
# sample within TAU = 3 cm with probability exp(-pi (3 / 1.4)^2) ~ 5e-7, so exact surfaces score exactly 1.
GROUND_SAMPLES = 80_000
TAU = 0.03


def union(*parts):
    """``(vertices [V, 3], faces [F, 3])`` of synthetic parts, plus each part's face range."""
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
    V = np.concatenate([p.vertices for p in parts])
    F = np.concatenate([p.faces + o for p, o in zip(parts, offsets)])
    ranges = np.cumsum([0] + [len(p.faces) for p in parts])
    return V, F, [slice(a, b) for a, b in zip(ranges[:-1], ranges[1:])]


def ring(n, radius, height, target=(0.0, 0.0, 0.0), size=SIZE, fov_deg=40.0):
    """``n`` cameras on a horizontal circle at ``height`` above ``target``, looking at it."""
    fx = (size / 2) / np.tan(np.deg2rad(fov_deg) / 2)
    eyes = [np.asarray(target) + (radius * np.cos(a), radius * np.sin(a), height)
            for a in np.linspace(0, 2 * np.pi, n, endpoint=False)]
    return [look_at(e, target, fx=fx, width=size, height=size, name=f"c{k}") for k, e in enumerate(eyes)]


def ground_grid(half, cell):
    return M.grid_plane(center=(0, 0, 0), half_size=half, cell=cell)


@pytest.mark.slow
def test_crop_then_sample_scores_the_exact_mesh_at_the_floor_where_sample_then_crop_understates():
    # a 40 m ground and a 1 m box; the cameras see a few square metres around the box
    box = M.box(center=(0, 0, 0.505), size=(1, 1, 1))
    V, F, _ = union(ground_grid(20.0, 1.0), box)
    cams = ring(6, 2.0, 2.0, target=(0, 0, 0.3))
    rep = region_scores((V, F), (V, F), cams, gt_max_edge=0.25, gt_samples=20_000)
    m, fl, reg = rep["metrics"], rep["floor"]["metrics"], rep["region"]
    assert reg["gt_seen_area"] < 0.1 * reg["gt_area"]  # the region is a small part of the GT
    assert m["fscore"][0] > 0.95 and abs(m["fscore"][0] - fl["fscore"][0]) < FLOOR_GAP
    assert m["chamfer"] == pytest.approx(fl["chamfer"], rel=0.1)
    # the same sample budget spread over the whole mesh, cropped afterwards to the region's box
    old = mesh_accuracy_completeness((V, F), (V, F), density=np.sqrt(reg["gt_area"] / 20_000), max_dist=reg["max_dist"],
                                     tau_list=reg["tau"], crop=tuple(reg["bbox"]))
    assert old.fscore[0] < 0.5 and old.num_gt_samples < 0.2 * m["num_gt_samples"]


@pytest.mark.slow
def test_exact_flat_ground_scores_one_and_the_ground_metrics_pass():
    V, F, _ = union(ground_grid(2.0, 0.1))
    cams = ring(4, 1.0, 2.5)
    ground = Ground(0.0, ((-2, -2), (2, 2)), np.zeros((0, 2, 2)))
    rep = region_scores((V, F), (V, F), cams, ground=ground, tau=[TAU], gt_samples=GROUND_SAMPLES)
    # the floor's GT-as-prediction also holds the in-image edges of faces no sub-ray hit: a sample or so
    assert rep["metrics"]["fscore"] == [1.0] and rep["floor"]["metrics"]["fscore"][0] > 0.999
    g = rep["ground"]
    assert g["patches"] > 100 and g["patches_over_limit"] == 0 and g["worst_patch_completeness"] == 1.0
    assert g["patches_over_limit_list"] == []
    assert g["flat_target_met"] and g["patch_target_met"] and g["flat_fraction"] == 1.0


@pytest.mark.slow
def test_hole_in_the_seen_ground_fails_patch_completeness():
    G = ground_grid(2.0, 0.1)
    cams = ring(4, 1.0, 2.5)
    centres = G.vertices[G.faces].mean(1)
    hole = np.all(np.abs(centres[:, :2] - (0.3, -0.2)) < 0.2, axis=1)  # a 40 x 40 cm hole in the seen ground
    ground = Ground(0.0, ((-2, -2), (2, 2)), np.zeros((0, 2, 2)))
    rep = region_scores((G.vertices, G.faces[~hole]), (G.vertices, G.faces), cams, ground=ground, tau=[TAU],
                        gt_samples=GROUND_SAMPLES)
    g = rep["ground"]
    assert not g["patch_target_met"] and g["patches_over_limit"] >= 4 and g["worst_patch_completeness"] < 0.2
    # every listed incomplete patch lies in or at the hole (its 10-cm patches overlap x 0.1..0.5, y -0.4..0), worst first
    listed = g["patches_over_limit_list"]
    assert len(listed) == g["patches_over_limit"]
    assert all(0.1 - 0.1 <= e["center"][0] <= 0.5 + 0.1 and -0.4 - 0.1 <= e["center"][1] <= 0.0 + 0.1 for e in listed)
    assert [e["completeness"] for e in listed] == sorted(e["completeness"] for e in listed)
    assert listed[0]["completeness"] == g["worst_patch_completeness"]
    assert rep["floor"]["ground"]["patch_target_met"]
    assert g["flat_target_met"]  # what is there is flat


@pytest.mark.slow
def test_wavy_ground_fails_flatness_and_flat_passes():
    G = ground_grid(2.0, 0.05)
    cams = ring(4, 1.0, 2.5)
    wavy = G.vertices.copy()
    wavy[:, 2] = 0.05 * np.sin(2 * np.pi * wavy[:, 0] / 0.5)  # +-5 cm
    ground = Ground(0.0, ((-2, -2), (2, 2)), np.zeros((0, 2, 2)))
    rep = region_scores((wavy, G.faces), (G.vertices, G.faces), cams, ground=ground, gt_samples=20_000)
    g, gf = rep["ground"], rep["floor"]["ground"]
    assert g["flat_tolerance"] < 0.02 and g["flat_points"] > 1000
    assert not g["flat_target_met"] and g["flat_fraction"] < 0.5 and g["height_error_p95"] > 0.04
    assert gf["flat_target_met"] and gf["height_error_p95"] < 1e-9


@pytest.mark.slow
def test_unseen_faces_are_not_scored():
    # a box 5 mm above the ground with one triangle sealed inside it: its bottom and the inner face are unseen
    box = M.box(center=(0, 0, 0.305), size=(0.6, 0.6, 0.6))
    inner = M.SyntheticMesh("inner", np.array([[-0.2, -0.2, 0.3], [0.2, -0.2, 0.3], [0.0, 0.2, 0.35]]),
                            np.array([[0, 1, 2]]), np.tile([0, 0, 1.0], (3, 1)))
    V, F, (g, b, i) = union(ground_grid(1.5, 0.1), box, inner)
    cams = ring(6, 1.5, 1.5, target=(0, 0, 0.2))
    seen = seen_faces(V, F, cams)
    bottom = np.flatnonzero(np.isclose(V[F[b]][:, :, 2], 0.005).all(axis=1)) + b.start
    top = np.flatnonzero(np.isclose(V[F[b]][:, :, 2], 0.605).all(axis=1)) + b.start
    assert len(bottom) == 2 and not seen[bottom].any() and not seen[i].any() and seen[top].all()
    under = np.all(np.abs(V[F[g]].mean(1)[:, :2]) < 0.2, axis=1)  # ground cells under the box
    assert under.sum() >= 4 and not seen[g][under].any() and seen[g].mean() > 0.5

    keep = np.ones(len(F), bool)
    keep[bottom], keep[i] = False, False
    keep[np.flatnonzero(under) + g.start] = False  # the prediction lacks every unseen face
    rep = region_scores((V, F[keep]), (V, F), cams, tau=[0.06], gt_max_edge=0.1, gt_samples=20_000)
    assert rep["metrics"]["recall"] == [1.0]
    whole = mesh_accuracy_completeness((V, F[keep]), (V, F), density=0.01, max_dist=0.2, tau_list=[0.06])
    assert whole.recall[0] < 0.99  # scoring the whole GT counts the unseen faces as missing


def test_region_is_the_observed_volume():
    G = ground_grid(1.0, 0.1)
    cams = ring(3, 1.0, 2.0)
    obs = observe(G.vertices, G.faces, cams, supersample=1)
    pts = np.array([[0, 0, 0.5],  # free space in front of the ground: observed
                    [0, 0, -0.05],  # just behind the ground: inside the margin
                    [0, 0, -0.5],  # deep behind it: unobservable
                    [0, 0, 50.0]])  # behind every camera
    assert in_region(pts, obs, margin=0.1).tolist() == [True, True, False, False]
    assert in_region(pts, obs, margin=0.1, bbox=((-1, -1, 0), (1, 1, 1))).tolist() == [True, False, False, False]
    # a triangle half inside the box of interest is cut at its edge, then sampled
    tri = crop_mesh(np.array([[-0.5, -0.5, 0.2], [0.5, -0.5, 0.2], [0.0, 0.5, 0.2]]), np.array([[0, 1, 2]]),
                    lambda p: p[:, 0] < 0.0, resolution=0.01)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert area == pytest.approx(0.25, rel=0.03) and tri[:, :, 0].mean(1).max() < 0.0


@pytest.mark.slow
def test_cli_with_a_scene_folder(tmp_path, capsys):
    from gof_warp.synthetic import make_scene

    out = make_scene("garden", tmp_path / "g", views=4, resolution=(24, 18), device="cpu")
    js = tmp_path / "r.json"
    assert evaluate_main(["--mesh", str(out / "gt_mesh.ply"), "--gt", str(out / "gt_mesh.ply"), "--scene", str(out),
                          "--density", "0.05", "--supersample", "2", "--json", str(js)]) == 0
    rep = json.loads(js.read_text())
    assert {"metrics", "region", "floor", "ground", "mesh_stats", "gt_stats"} <= set(rep)
    assert abs(rep["metrics"]["fscore"][0] - rep["floor"]["metrics"]["fscore"][0]) < FLOOR_GAP
    assert rep["region"]["cameras"] == 4 and rep["region"]["gt_seen_area"] < rep["region"]["gt_area"]
    assert rep["ground"]["patch_target_met"] and rep["ground"]["flat_target_met"]
    assert "floor" in capsys.readouterr().out
