"""Data-parallel training over processes (gloo on the CPU): two processes give the one-process result, the
ranks' checksum catches a model that drifted, and bad splits are refused."""

import functools
import gc
import os
import subprocess
import sys
import tempfile
import time
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp

from gof_warp.training.distributed import Ranks, join_process_group
from gof_warp.core.errors import GofError
from gof_warp.cli.extract import main as extract_main
from gof_warp.core.model import Gaussians
from gof_warp.synthetic import make_scene
from gof_warp.cli.train import main as train_main

pytestmark = pytest.mark.slow  # spawns gloo process groups that train

ARGS = ["--config", "quick", "--iterations", "40", "--device", "cpu", "--no-pictures", "--quiet", "views_per_step=2",
        "log_every=10", "performance.checksum_every=10", "checkpoint_every=20", "model.random_init_points=400",
        "densify.start_iter=5", "densify.interval=10", "densify.grad_threshold=1e-6"]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return make_scene("default", tmp_path_factory.mktemp("scene") / "s", views=6, resolution=(32, 32), device="cpu")


def _train(cmd, env_extra=None):
    env = {**os.environ, "OMP_NUM_THREADS": "1", **(env_extra or {})}
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-4000:]


@pytest.fixture(scope="module")
def one_process_run(scene, tmp_path_factory):
    """The one-process run of ARGS (the reference of the two-process training, and the model the extraction test
    meshes), trained by the command's ``main`` in this process (a subprocess start costs ~7 s of CI) with one torch
    thread, as the subprocess had (OMP_NUM_THREADS=1) and as torchrun gives each rank."""
    one = tmp_path_factory.mktemp("one") / "run"
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        assert train_main([str(scene), "--out", str(one), *ARGS]) == 0
    finally:
        torch.set_num_threads(threads)
    return one


def test_two_processes_train_the_one_process_model(scene, one_process_run, tmp_path):
    one, two = one_process_run, tmp_path / "two"
    _train([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
            "-m", "gof_warp.train", str(scene), "--out", str(two), *ARGS])
    a, b = Gaussians.load_ply(one / "point_cloud.ply"), Gaussians.load_ply(two / "point_cloud.ply")
    assert len(a) == len(b) and len(a) != 400, "densification should have changed the model, identically"
    for name in a.params:  # two terms summed in the same order: identical, within float tolerance at worst
        torch.testing.assert_close(a.params[name], b.params[name], rtol=1e-5, atol=1e-6)
    import json

    m = json.loads((two / "metrics.json").read_text())
    assert m["processes"] == 2 and m["views_per_step"] == 2
    assert sorted(p.name for p in (two / "checkpoints").iterdir()) == sorted(p.name for p in (one / "checkpoints").iterdir())


class _Slot:
    """One body's part of the shared result dict: ``slot[key] = value`` stores ``result[(name, key)]``."""

    def __init__(self, result, name):
        self.result, self.name = result, name

    def __setitem__(self, key, value):
        self.result[(self.name, key)] = value


def _native_threads() -> list[str] | None:
    """The names of this process's threads (Linux's /proc), None where there is no /proc."""
    tasks = Path("/proc/self/task")
    if not tasks.is_dir():
        return None
    return [(t / "comm").read_text().strip() for t in tasks.iterdir() if (t / "comm").is_file()]


def _in_gloo_group(rank, world, init_file, result, bodies):
    """Spawned: each ``(name, body)`` in turn runs ``body(Ranks, slot)`` in one gloo group; ``slot[rank]`` is "same",
    or its GofError's message. A collective that one rank never joins fails after 2 minutes instead of gloo's 30.
    The group is joined as the commands join theirs (:func:`join_process_group`) and torch's compiler imported once it
    is up, as the trainer does; ``result[("group", rank)]`` holds the threads left after destroying it."""
    join_process_group(backend="gloo", init_method=f"file://{init_file}", rank=rank, world_size=world,
                       timeout=timedelta(minutes=2))
    import torch._dynamo  # noqa: F401  (what a Trainer's first compile or optimizer step imports)

    try:
        for name, body in bodies:
            slot = _Slot(result, name)
            try:
                body(Ranks(rank=rank, world=world), slot)
                slot[rank] = "same"
            except GofError as e:
                slot[rank] = str(e)
    finally:
        torch.distributed.destroy_process_group()
        gc.collect()
        result[("group", rank)] = _native_threads()


def _spawn_two(*bodies) -> dict:
    """``{name: {key: value}}``: the ``(name, body)`` pairs run by two spawned ranks of one gloo group."""
    with tempfile.TemporaryDirectory() as d, mp.Manager() as manager:
        result = manager.dict()
        mp.spawn(_in_gloo_group, args=(2, os.path.join(d, "init"), result, bodies), nprocs=2, join=True)
        out: dict = {name: {} for name, _ in bodies}
        for (name, key), value in dict(result).items():
            out.setdefault(name, {})[key] = value  # also "group": each rank's threads after the group's end
        return out


@pytest.fixture(scope="module")
def two_ranks(scene, one_process_run, tmp_path_factory):
    """The two-rank bodies below, run in turn by ONE pair of spawned processes (a pair costs ~12 s of CI: two
    interpreters importing torch and the package); each test reads its body's results. The late-rank body runs
    last: the ranks enter it together, just out of the previous body's collectives."""
    out = tmp_path_factory.mktemp("two_ranks_extract") / "two_delaunay.ply"
    return _spawn_two(("drift", _drift), ("rows", _other_points),
                      ("extract", functools.partial(_extract_delaunay, str(one_process_run), str(out))),
                      ("late", functools.partial(_late_rank_one, str(scene))))


def _extract_common(run: Path, grid: str) -> list[str]:
    common = [str(run), "--grid", grid, "--binary-steps", "3", "--device", "cpu", "--no-pictures", "--quiet"]
    # this tiny model's few large Gaussians need cells finer than the default (0.4: ~330 faces; 0.2 took 3x longer)
    return common + (["--cell-factor", "0.4"] if grid == "octree" else [])


def _extract_delaunay(run, out, ranks, result):
    """The extract command's work on the Delaunay grid by two ranks of the spawned group (the octree grid goes
    through torchrun and the CLI's own process-group set-up in the test below)."""
    from gof_warp.cli.extract import extract_run, parse_args

    extract_run(parse_args([*_extract_common(run, "delaunay"), "--out", out]), ranks, "cpu")
    result["mesh"] = out


def _drift(ranks, result):
    ranks.check_identical({"means": torch.zeros(4, 3) + (ranks.rank == 1) * 1e-7}, 7)


def test_the_process_group_ends_with_its_threads(two_ranks):
    """destroy_process_group ends the gloo group's threads although torch's compiler was imported after the group
    began (joined the other way round, dynamo kept the group alive into interpreter shutdown, where its threads
    aborted 2 of 82 two-rank trainings on a loaded 2-core machine, after the run had been written: CI's red run)."""
    threads = two_ranks["group"]
    if threads[0] is None:
        pytest.skip("no /proc/self/task on this system: thread names unknown")
    assert all(threads[r] and not any("gloo" in t for t in threads[r]) for r in (0, 1)), threads


def test_the_checksum_stops_ranks_that_drifted_apart(two_ranks):
    result = two_ranks["drift"]
    assert all("differs" in result[r] and "iteration 7" in result[r] for r in (0, 1)), result


def test_views_are_shared_out_and_bad_splits_refused(scene, tmp_path):
    assert Ranks(rank=1, world=2).my_views([5, 3, 8, 1]) == [3, 1] and Ranks().my_views([5, 3]) == [5, 3]
    from gof_warp.core.config import merge
    from gof_warp.data import load_scene
    from gof_warp.training.trainer import TrainConfig, Trainer

    cfg = merge(TrainConfig(), {"views_per_step": 3, "model": {"init": "random", "random_init_points": 50}})
    with pytest.raises(GofError, match="does not divide among 2 processes"):
        Trainer(load_scene(scene), cfg, tmp_path / "r", "cpu", ranks=Ranks(rank=0, world=2))


def test_two_processes_extract_the_one_process_mesh(one_process_run, two_ranks, tmp_path):
    """Extraction by two processes: the grid points' field shared out by views (the minimum over ranks is exact), the
    marching split by space (each rank its share of the tetrahedra, joined by edge key on rank 0), the search by views
    (every rank searches the union of the crossing edges over its views), rank 0 writes; the mesh is the one-process
    mesh exactly on both grids: the octree (the default, built alike on every rank, its tetrahedra made and marched
    in five pieces shared out among the ranks; the CLI under torchrun) and the
    Delaunay grid (computed on rank 0 and broadcast; the command's work in the spawned pair of ``two_ranks``)."""
    import json

    import trimesh

    run = one_process_run
    assert two_ranks["extract"][0] == two_ranks["extract"][1] == "same", two_ranks["extract"]
    for grid, stage in (("octree", "octree_grid"), ("delaunay", "delaunay+filter")):
        common = _extract_common(run, grid)
        # the one-process mesh in this process (a subprocess start costs ~5 s of CI per run); the test sets no
        # process group, so the CLI runs as one process
        assert extract_main([*common, "--out", str(tmp_path / f"one_{grid}.ply")]) == 0
        if grid == "octree":  # in five pieces (--piece-tets): a rank marches several, one at a time
            made = json.loads((tmp_path / "one_octree.json").read_text())["stages"]["counts"]["tetrahedra_made"]
            _train([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                    "-m", "gof_warp.extract", *common, "--piece-tets", str(-(-made // 5)),
                    "--out", str(tmp_path / f"two_{grid}.ply")])
            two_path = tmp_path / f"two_{grid}.ply"
        else:
            two_path = Path(two_ranks["extract"]["mesh"])
        one = trimesh.load(tmp_path / f"one_{grid}.ply", process=False)
        two = trimesh.load(two_path, process=False)
        assert len(one.faces) > 100, grid
        assert np.array_equal(one.vertices, two.vertices) and np.array_equal(one.faces, two.faces), grid
        info = json.loads(two_path.with_suffix(".json").read_text())
        assert info["processes"] == 2 and stage in info["stages"], grid
        counts = info["stages"]["counts"]  # the marching was split by space: each rank marched its share
        assert len(counts["tetrahedra_per_rank"]) == 2 and sum(counts["tetrahedra_per_rank"]) == counts["tetrahedra"]
        assert min(counts["tetrahedra_per_rank"]) > 0, grid
        assert [r["rank"] for r in info["ranks"]] == [0, 1], grid  # each process's own time and memory
        assert all(r["host_peak_rss_mb"] > 0 and r["total_time_s"] > 0 for r in info["ranks"]), grid
        if grid == "delaunay":
            assert info["stages"][stage]["substages"]["computed_on_rank"] == 0
        else:
            assert counts["pieces"] == 5


def _other_points(ranks, result):
    rows = np.arange(12, dtype=np.int32).reshape(3, 4) if ranks.is_main else None
    result[f"tets{ranks.rank}"] = ranks.broadcast_rows(rows).tolist()
    ranks.check_same_points(np.zeros((5, 3), np.float32) + (ranks.rank == 1) * 1e-3, "opacity field")


def test_rank_zero_rows_reach_every_rank_and_different_points_are_refused(two_ranks):
    result = two_ranks["rows"]
    assert result["tets1"] == result["tets0"] == np.arange(12).reshape(3, 4).tolist()
    assert all("evaluates other points" in result[r] for r in (0, 1)), result


LATE_S = 6.0  # the ranks' set-up times differ by up to ~2 s on a loaded 2-core box: the lateness must dominate


def _late_rank_one(scene_dir, ranks, result):
    """Rank 1 starts training LATE_S after rank 0; rank 0 reports its warm-up and training times."""
    from gof_warp.core.config import merge
    from gof_warp.data import load_scene
    from gof_warp.training.trainer import TrainConfig, Trainer

    cfg = merge(TrainConfig(), {"iterations": 4, "views_per_step": 2, "checkpoint_every": 0,
                                "model": {"init": "random", "random_init_points": 100}})
    with tempfile.TemporaryDirectory() as out:
        trainer = Trainer(load_scene(scene_dir), cfg, out, "cpu", ranks=ranks)
        if ranks.rank == 1:
            time.sleep(LATE_S)
        metrics = trainer.run()
    if ranks.is_main:
        result["warmup_s"], result["train_time_s"] = trainer.warmup_s, metrics["train_time_s"]


def test_the_clock_starts_when_every_rank_is_ready(two_ranks):
    """The warm-up ends at a barrier: a rank that starts late (or NCCL setting up its communicators at the first
    collective) is waited for before the clock starts, not inside the first step's all-reduce."""
    result = two_ranks["late"]
    assert result[0] == result[1] == "same", result
    assert result["warmup_s"] > LATE_S / 2, result  # rank 0 waited for rank 1 in its warm-up
    assert result["train_time_s"] < result["warmup_s"], result  # ... and not in its timed steps
