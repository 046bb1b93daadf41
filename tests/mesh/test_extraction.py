"""Mesh extraction end to end: the analytic sphere of one Gaussian, every method, the CLI and its errors."""

import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from gof_warp.core.camera import look_at
from gof_warp.cli.extract import MeshConfig, StageTimer, extract_mesh, save_mesh
from gof_warp.core.model import Gaussians
from gof_warp.mesh.octree_tets import OctreeConfig
from gof_warp.rendering.render import RenderConfig
from gof_warp.mesh.tetra import TetraConfig

SIGMA, ALPHA = 0.2, 0.9
RADIUS = SIGMA * np.sqrt(2 * np.log(2 * ALPHA))  # 0.5 level set of α·exp(−r²/2σ²)


def _ring_cameras(n=16, size=64):
    cams = []
    for a in range(n):
        ang = 2 * np.pi * a / n
        elev = 0.9 * np.sin(3 * ang)
        cams.append(look_at([2.0 * np.cos(ang), 2.0 * np.sin(ang), elev], [0, 0, 0], fx=80, width=size, height=size,
                            name=f"c{a:02d}"))
    return cams


def _one_gaussian():
    return Gaussians.from_activated(np.zeros((1, 3)), [[1.0, 0, 0, 0]], np.full((1, 3), SIGMA), [ALPHA], device="cpu")


def _radial_error(verts):
    return np.abs(np.linalg.norm(verts, axis=1) - RADIUS)


def test_tetra_extraction_of_one_gaussian_is_its_analytic_sphere():
    cams = _ring_cameras()
    cfg_render = RenderConfig(alpha_min=0.0, k_max=10.0)
    errors = {}
    for steps in (0, 3, 8):
        cfg = MeshConfig(method="tetra", binary_steps=steps, tetra=TetraConfig(filter_cells=False))
        (verts, faces), = extract_mesh(_one_gaussian(), cams, cfg, render_config=cfg_render)
        assert len(faces) >= 8
        errors[steps] = _radial_error(verts).max()
    # The field is a min over views of ray integrals, ≥ the radial profile, equal to it along each view's
    # rays through the centre: with 16 views it sits within ~2% of the analytic sphere.
    assert errors[8] < 0.02 * RADIUS, errors
    assert errors[8] < errors[0], errors


@pytest.mark.slow
def test_face_budget_and_band_keep_the_sphere_closed():
    """--max-faces: the decimated tetra mesh honours the budget, stays closed and on the sphere; --band (only the
    points near the level) gives a closed mesh on the same sphere; bad budgets are clear errors."""
    cams = _ring_cameras()
    cfg_render = RenderConfig(alpha_min=0.0, k_max=10.0)
    full, = extract_mesh(_one_gaussian(), cams, MeshConfig(binary_steps=8, tetra=TetraConfig(filter_cells=False)),
                         render_config=cfg_render)
    budget = len(full[1]) // 2
    (v, f), = extract_mesh(_one_gaussian(), cams, MeshConfig(binary_steps=8, max_faces=budget,
                                                             tetra=TetraConfig(filter_cells=False)),
                           render_config=cfg_render)
    assert 0.8 * budget <= len(f) <= budget and trimesh.Trimesh(v, f).is_watertight  # accuracy: test_decimate.py
    (v, f), = extract_mesh(_one_gaussian(), cams, MeshConfig(binary_steps=8, tetra=TetraConfig(
                               grid="delaunay", filter_cells=False, band=True)),
                           render_config=cfg_render)
    assert trimesh.Trimesh(v, f).is_watertight and _radial_error(v).max() < 0.02 * RADIUS
    for bad in ({"max_faces": 0}, {"max_error": -1.0}):
        with pytest.raises(ValueError, match="max_"):
            MeshConfig(**bad).validate()


@pytest.mark.slow
def test_octree_grid_gives_the_closed_analytic_sphere():
    """grid="octree": no Delaunay; the mesh is closed and on the analytic sphere, and finer cells give more faces;
    the level band (a Delaunay-grid option) with it is a clear error."""
    cams = _ring_cameras()
    cfg_render = RenderConfig(alpha_min=0.0, k_max=10.0)
    faces_at = {}
    for factor in (0.5, 0.25):
        cfg = MeshConfig(binary_steps=8, tetra=TetraConfig(grid="octree", octree=OctreeConfig(cell_factor=factor)))
        (v, f), = extract_mesh(_one_gaussian(), cams, cfg, render_config=cfg_render)
        assert trimesh.Trimesh(v, f).is_watertight
        assert _radial_error(v).max() < 0.02 * RADIUS
        faces_at[factor] = len(f)
    assert faces_at[0.25] > faces_at[0.5] >= 8
    with pytest.raises(ValueError, match="band"):
        MeshConfig(tetra=TetraConfig(grid="octree", band=True)).validate()
    for delaunay_only in ({"backend": "cgal"}, {"delaunay_workers": 4}, {"corner_min_extent": 0.1},
                          {"delaunay_processes": False}):
        with pytest.raises(ValueError, match="--grid delaunay"):
            MeshConfig(tetra=TetraConfig(**delaunay_only)).validate()
        MeshConfig(tetra=TetraConfig(grid="delaunay", **delaunay_only)).validate()
    with pytest.raises(ValueError, match="--grid octree"):  # octree settings on the Delaunay grid: not ignored
        MeshConfig(tetra=TetraConfig(grid="delaunay", octree=OctreeConfig(cell_factor=0.3))).validate()
    with pytest.raises(ValueError, match="grid"):
        MeshConfig(tetra=TetraConfig(grid="voronoi")).validate()


@pytest.mark.slow
def test_auto_grid_takes_the_delaunay_grid_for_a_small_model_only():
    """grid="auto" (the default): a model whose octree at the default factor has fewer than small_leaves leaves is
    meshed on the Delaunay grid (the same mesh, and the stage JSON says why); at or over the limit, or with a cell
    factor given, on the octree (the same mesh as grid="octree")."""
    cams = _ring_cameras()
    cfg_render = RenderConfig(alpha_min=0.0, k_max=10.0)

    def mesh(**tetra):
        timer = StageTimer("cpu")
        (v, f), = extract_mesh(_one_gaussian(), cams, MeshConfig(binary_steps=4, tetra=TetraConfig(**tetra)),
                               render_config=cfg_render, timer=timer)
        return v, f, timer.stages["counts"]["grid"]

    assert TetraConfig().grid == "auto"
    v_auto, f_auto, why = mesh()
    v_del, f_del, _ = mesh(grid="delaunay")
    assert why.startswith("delaunay (auto:") and "fewer than 100,000" in why
    assert np.array_equal(f_auto, f_del) and np.array_equal(v_auto, v_del)
    v_oct, f_oct, why_oct = mesh(grid="octree", octree=OctreeConfig(small_leaves=0))
    assert why_oct == "octree" and len(f_oct) != len(f_del)  # a different grid: a different mesh
    for octree in (OctreeConfig(small_leaves=0), OctreeConfig(cell_factor=0.5)):
        v, f, why = mesh(octree=octree)
        assert why == "octree" and np.array_equal(f, f_oct) and np.array_equal(v, v_oct)


@pytest.mark.slow
def test_octree_grid_marched_in_pieces_is_the_mesh_marched_at_once():
    """OctreeConfig.piece_tets: the grid's tetrahedra made, marched and their crossing edges collected a piece at a
    time, the search run once on the union, the pieces joined by edge key: the same vertices and faces, bit for bit,
    as the whole grid marched at once; the counts say how many pieces and tetrahedra there were."""
    cams = _ring_cameras()
    cfg_render = RenderConfig(alpha_min=0.0, k_max=10.0)
    meshes, counts = {}, {}
    for piece_tets in (OctreeConfig.piece_tets, 500):
        timer = StageTimer("cpu")
        cfg = MeshConfig(binary_steps=4, tetra=TetraConfig(octree=OctreeConfig(cell_factor=0.25, piece_tets=piece_tets)))
        (meshes[piece_tets],) = extract_mesh(_one_gaussian(), cams, cfg, render_config=cfg_render, timer=timer)
        counts[piece_tets] = timer.stages["counts"]
    whole, pieced = counts[OctreeConfig.piece_tets], counts[500]
    assert whole["pieces"] == 1 and pieced["pieces"] == -(-pieced["tetrahedra_made"] // 500) >= 4
    assert whole["tetrahedra"] == pieced["tetrahedra"] > 0
    assert whole["tetrahedra"] + whole["tetrahedra_out_of_view"] == whole["tetrahedra_made"]
    (v1, f1), (v2, f2) = meshes[OctreeConfig.piece_tets], meshes[500]
    assert len(f1) >= 8 and np.array_equal(v1, v2) and np.array_equal(f1, f2)


def test_every_method_gives_a_closed_sphere_like_mesh():
    cams = _ring_cameras(n=12, size=48)
    g = _one_gaussian()
    cfg_render = RenderConfig(alpha_min=0.0, k_max=10.0)
    box = (-0.4, -0.4, -0.4, 0.4, 0.4, 0.4)
    for method in ("cubes", "tsdf"):
        cfg = MeshConfig(method=method, binary_steps=4, cubes_resolution=24, crop=None)
        cfg.tsdf.bounds = box
        cfg.tsdf.resolution = 40
        if method == "cubes":
            cfg.crop = box
        (verts, faces), = extract_mesh(g, cams, cfg, render_config=cfg_render)
        assert len(faces) > 100, method
        r = np.linalg.norm(verts, axis=1)
        # cubes: the opacity field's 0.5 level set; tsdf: the median-depth surface (where T crosses 0.5 along
        # rays), which for one Gaussian lies inside the 0.5 opacity level set but within σ of it
        tol = 0.03 if method == "cubes" else SIGMA
        assert abs(np.median(r) - RADIUS) < tol, (method, np.median(r), RADIUS)
        if method == "cubes":
            assert trimesh.Trimesh(verts, faces).is_watertight


def test_no_gaussian_in_view_is_a_clear_error_on_the_octree_grid():
    behind = Gaussians.from_activated(np.array([[0.0, 0.0, 50.0]]), [[1.0, 0, 0, 0]], np.full((1, 3), SIGMA), [ALPHA],
                                      device="cpu")
    with pytest.raises(ValueError, match="none has its centre in some camera's view"):
        extract_mesh(behind, _ring_cameras(n=4), MeshConfig())


def test_search_planner_serves_many_steps_per_call_only_where_a_call_costs_more_than_its_points():
    """SearchPlanner fits the field's fixed and per-point cost from the grid points' call and the search's first
    call: a costly fixed part with few edges takes several steps a call, a per-point cost keeps one; a fixed setting,
    no grid sample or a grid no larger than twice the edges keep what they say; the automatic setting is one step a
    call on the CPU; the extraction's mesh is the same bit for bit for any steps per call (the plan is recorded in
    the counts)."""
    from gof_warp.training.distributed import Ranks
    from gof_warp.mesh.extraction import SearchPlanner, StageTimer

    def planned(grid_call, first_call, edges, fixed=0):
        plan = SearchPlanner(lambda x: x, 8, "cpu", Ranks.single(), fixed=fixed, grid_call=grid_call)
        plan.timings.append(first_call)
        return [plan(edges, 0), plan(edges, 1)]

    # 3M jittered Gaussians on one H100: ~7 s a call before any point, 2.4M grid points in 12.8 s, 25k edges
    assert planned((2_400_000, 12.8), (25_000, 7.0), 25_000) == [1, 7]
    # a dense mesh whose calls cost their points: one step a call
    assert planned((550_000, 13.8), (72_000, 2.2), 72_000) == [1, 1]
    assert planned(None, (25_000, 7.0), 25_000) == [1, 1]
    assert planned((40_000, 12.8), (25_000, 7.0), 25_000) == [1, 1]
    assert planned((2_400_000, 12.8), (25_000, 7.0), 25_000, fixed=3) == [3, 3]
    # the README job on the 2-core CPU: the grid's call no slower than the first search call (forked workers): no fit
    assert planned((95_000, 2.87), (32_356, 3.02), 32_356) == [1, 1]
    # a plan of several steps whose call then costs its points: the fit from the search's own calls takes over
    plan = SearchPlanner(lambda x: x, 8, "cpu", Ranks.single(), grid_call=(2_400_000, 12.8))
    plan.timings.append((25_000, 7.0))
    assert plan(25_000, 0) == 1 and plan(25_000, 1) == 7
    plan.timings.append((25_000 * 3, 40.0))  # 3 points per edge took 40 s, not ~7.1 s
    assert plan(25_000, 3) == 1 and plan.decisions["refit_from"] == [75_000, 40.0]
    with pytest.raises(ValueError, match="search_steps_per_call"):
        MeshConfig(search_steps_per_call=13).validate()
    cams = _ring_cameras()
    meshes = {}
    for per_call in (1, 3, 0):
        timer = StageTimer("cpu")
        meshes[per_call], = extract_mesh(_one_gaussian(), cams, MeshConfig(binary_steps=5, search_steps_per_call=per_call),
                                         render_config=RenderConfig(alpha_min=0.0), timer=timer)
        asked = timer.stages["counts"]["search"]["steps_per_call"]  # as asked before each call; the last takes what is left
        assert asked == {1: [1] * 5, 3: [3, 3], 0: [1] * 5}[per_call]  # automatic: one step a call on the CPU
        assert sum(min(d, 5 - sum(asked[:i])) for i, d in enumerate(asked)) == 5
    for per_call in (3, 0):
        np.testing.assert_array_equal(meshes[per_call][0], meshes[1][0])
        np.testing.assert_array_equal(meshes[per_call][1], meshes[1][1])


def test_empty_model_is_a_clear_error():
    empty = _one_gaussian().subset(np.zeros(1, bool))
    with pytest.raises(ValueError, match="no Gaussians"):
        extract_mesh(empty, _ring_cameras(n=2))


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    """A run folder as training writes it: point_cloud.ply + cameras.json."""
    from gof_warp.training.trainer import Trainer  # noqa: F401  (the layout below is Trainer's)

    run = tmp_path_factory.mktemp("run")
    g = Gaussians.from_activated(np.array([[0.0, 0, 0], [0.25, 0, 0]]), [[1.0, 0, 0, 0], [1.0, 0, 0, 0]],
                                 np.full((2, 3), 0.15), [0.95, 0.95], device="cpu")
    g.save_ply(run / "point_cloud.ply")
    cams = _ring_cameras(n=8, size=40)
    (run / "cameras.json").write_text(json.dumps({"train": [c.to_dict() for c in cams], "test": []}))
    return run


@pytest.mark.slow
@pytest.mark.parametrize("method", ["tetra", "cubes", "tsdf"])
def test_cli_writes_mesh_and_stats(run_folder, method, tmp_path, cli_in_process):
    """The command's ``main`` in this process (a ``python -m`` start costs ~7 s of CI per method). Real processes of
    this command: test_cli_errors_name_the_problem (a bad input), test_volume.py's ``--volume`` run and
    test_distributed.py's torchrun extractions (a mesh)."""
    from gof_warp.cli.extract import main

    out = tmp_path / f"m_{method}.ply"
    rc, err = cli_in_process(main, str(run_folder), "--method", method, "--out", str(out), "--device", "cpu",
                             "--resolution", "32", "--quiet")
    assert rc == 0, err[-3000:]
    mesh = trimesh.load(out, process=False)
    stats = json.loads(out.with_suffix(".json").read_text())
    min_faces = {"tetra": 8, "cubes": 50, "tsdf": 50}[method]  # two Gaussians give 18 tetra points only
    assert stats["meshes"][0]["faces"] == len(mesh.faces) >= min_faces
    assert stats["num_gaussians"] == 2 and stats["total_time_s"] > 0
    assert all("time_s" in v for k, v in stats["stages"].items() if k != "counts")
    # the whole command's other phases: loading, writing the mesh, its picture; the hidden faces counted
    assert set(stats["command"]) == {"load_s", "save_s", "pictures_s"}
    dropped = stats["stages"]["hidden_faces"]["dropped"]
    assert len(dropped) == 1 and 0 <= dropped[0] < stats["meshes"][0]["faces"] + dropped[0]
    assert (run_folder / "pictures" / f"mesh_m_{method}.png").is_file()


def test_cli_keep_hidden_skips_the_drop(run_folder, tmp_path, cli_in_process):
    """``--keep-hidden``: no hidden-face stage, and no fewer faces than the default mesh."""
    from gof_warp.cli.extract import main

    faces = {}
    for name, extra in (("drop", []), ("keep", ["--keep-hidden"])):
        out = tmp_path / f"{name}.ply"
        rc, err = cli_in_process(main, str(run_folder), "--out", str(out), "--device", "cpu", "--no-pictures", "--quiet",
                                 *extra)
        assert rc == 0, err[-3000:]
        stats = json.loads(out.with_suffix(".json").read_text())
        faces[name] = (stats["meshes"][0]["faces"], "hidden_faces" in stats["stages"])
    assert faces["drop"][1] and not faces["keep"][1] and faces["keep"][0] >= faces["drop"][0] > 0


@pytest.mark.slow
def test_cli_errors_name_the_problem(run_folder, tmp_path, cli_in_process):
    from gof_warp.cli.extract import main

    proc = subprocess.run([sys.executable, "-m", "gof_warp.extract", str(tmp_path / "nothing")], capture_output=True,
                          text=True, timeout=300)  # the real process once; the other cases in this one (CI seconds)
    assert proc.returncode == 2 and "neither a run folder nor a .ply" in proc.stderr and "Traceback" not in proc.stderr

    ply_only = tmp_path / "model.ply"
    ply_only.write_bytes((run_folder / "point_cloud.ply").read_bytes())
    rc, err = cli_in_process(main, str(ply_only))
    assert rc == 2 and "--scene" in err
    rc, err = cli_in_process(main, str(run_folder), "--levels", "1.5")
    assert rc == 2 and "levels" in err


def test_save_mesh_is_atomic_and_loadable(tmp_path):
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    save_mesh(tmp_path / "tri.ply", verts, np.array([[0, 1, 2]]))
    assert len(trimesh.load(tmp_path / "tri.ply").faces) == 1
    assert not list(tmp_path.glob(".*.tmp"))


def test_grid_cache_builds_the_tetrahedral_grid_once_per_model():
    """Two extractions of one model that differ in search steps share the grid: the second says so, skips the
    grid stages, and gives the mesh a fresh extraction with its settings gives."""
    from gof_warp.mesh.extraction import StageTimer

    cams = _ring_cameras(n=8)
    cfg_render = RenderConfig(alpha_min=0.0, k_max=10.0)
    g = _one_gaussian()
    cache: dict = {}
    first, second = StageTimer("cpu"), StageTimer("cpu")
    extract_mesh(g, cams, MeshConfig(binary_steps=2), render_config=cfg_render, timer=first, grid_cache=cache)
    (v, f), = extract_mesh(g, cams, MeshConfig(binary_steps=6), render_config=cfg_render, timer=second,
                           grid_cache=cache)
    assert "grid_shared" not in first.stages and "octree_grid" in first.stages
    assert second.stages["grid_shared"]["built_s"] > 0 and "octree_grid" not in second.stages
    (v2, f2), = extract_mesh(g, cams, MeshConfig(binary_steps=6), render_config=cfg_render)
    np.testing.assert_array_equal(f, f2)
    np.testing.assert_allclose(v, v2, atol=1e-6)
    grids = lambda: sum(isinstance(k, tuple) for k in cache)  # noqa: E731 - beside them: the cameras' check, once
    assert grids() == 1 and cache["cameras_inside"] == []
    extract_mesh(g, cams, MeshConfig(binary_steps=2, tetra=TetraConfig(filter_cells=False)), render_config=cfg_render,
                 grid_cache=cache)
    assert grids() == 2  # another grid setting is another grid
