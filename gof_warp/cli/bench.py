"""``python -m gof_warp.bench [--suite tiny|quick|full|stability] [--out DIR] [--list] [--only PATTERN ...]
[--time-limit SECONDS] [--runs-dir DIR] [--data DIR] [--device D]``

Accuracy against cost, across extraction methods, training lengths, Gaussian budgets and the
regularisers: scenes × training configurations × extraction methods. Each run (scene, training config) is
trained once; its model, and the snapshots it saved on the way (``Run.snapshots``: the 3DGS way of
reporting 3k/7k/… numbers from one run), are extracted with every method of the run, timed, and scored
against the scene's exact ``gt_mesh.ply``. Writes ``DIR/results.json`` and ``DIR/results.csv``: one row per
(run, iteration, method), with ``iteration`` the model's (a snapshot's or the last), the training time
and Gaussian count up to it, test PSNR/SSIM, every extraction time, memory, size and accuracy figure, and
the machine; and the charts of :mod:`gof_warp.benchmarking.report`. Memory is the peak host RSS (Linux VmHWM, reset
before each training and extraction) and torch's peak CUDA allocation. An extraction refused with a clear
error (e.g. an empty model) is a row with ``error`` set and no scores; anything else that fails stops the
suite. Real scenes (no GT mesh) get rows with empty accuracy columns; the method ``render_only`` is a
row with no mesh at all (rendering quality, time and size of the model only).

Continuing and splitting: rows already in ``DIR/results.json`` are skipped (key: run, iteration, method),
so an interrupted suite continues where it stopped, losing at most the run in progress (a run whose model
is still in ``DIR/runs/<run>``, or ``--runs-dir``, is not trained again). ``--only`` keeps the runs whose names match a
shell pattern. ``--time-limit S`` starts no run whose planned cost (``Run.budget_s``) would end more than
``S`` seconds after the command started (it skips to later runs that still fit); when runs are left it
exits with code 3 and says how many: run the same command again (e.g. in the next device call).
``--time-limit 0`` runs nothing: it redraws the charts of the table so far and lists what is left.

A suite is plain data (:func:`suite`; ``--list`` prints it with each run's budget and the total): ``tiny``
(the test's), ``quick`` (a CPU in minutes), ``full`` (the GPU run, sized by :class:`Sizing` for one H100
lent in 10-minute calls: no run over 8 minutes with its extractions, about 48 minutes in all; see
:func:`full_suite`). ``stability`` runs :mod:`gof_warp.benchmarking.stability` (where each method breaks; ``--fast``: only
the hand-made cases) and writes ``stability.json``; its exit code is 1 when any (case, method) crashed.
"""

from __future__ import annotations

import argparse
import dataclasses
import fnmatch
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..benchmarking.report import (
    load_rows,
    machine_info,
    peak_memory,
    reset_peak_memory,
    row_key,
    scores,
    write_charts,
    write_table,
)
from ..benchmarking.runs import (  # noqa: F401 - the run pieces live in the library; re-exported for callers
    Method,
    Run,
    tetra,
    cubes,
    tsdf,
    RENDER_ONLY,
    scaled_schedule,
    GOF_SCHEDULE,
    gof_schedule,
    NO_REGULARISERS,
    _merge,
    preset_overrides,
    DATA_ROOT,
    data_root,
    scene_folder,
    run_config,
    _trained,
    _train_or_load,
)
from .common import HelpFormatter, configure_output, run_command
from ..core.errors import GofError

log = logging.getLogger(__name__)

SUITES = ("tiny", "quick", "full", "stability")
EXIT_RUNS_LEFT = 3  # --time-limit reached with runs left: run the same command again


# ----------------------------------------------------------------------------------------- the suites
@dataclass(frozen=True)
class Sizing:
    """The ``full`` suite's sizes and cost model, in seconds on one H100: the one place to rescale.

    Training, measured on an H200 with our trainer (per-iteration overhead dominates, so resolution matters
    little; an H100 is assumed equal): nerf_mic 400×400 30k iterations 491 s (168k Gaussians), DTU 800×600
    30k 554 s (520k Gaussians). Extraction and scoring are estimates, to be replaced by the first call's
    measured ``extract_time_s`` / ``eval_time_s``. Not in any budget: a call's start-up (setup script,
    imports, Warp's kernel compilation on a fresh machine) — leave it as margin in ``--time-limit``.
    """

    resolution: tuple[int, int] = (400, 400)  # synthetic presets (nerf_mic is 400×400, DTU 800×600)
    long_iterations: int = 15_000  # the training-length run; 30k (~500 s of training alone) fits no call
    iterations: int = 7_000  # every other run
    snapshots: tuple[int, ...] = (3_000, 7_000)  # of the long run: with it, training lengths 3k/7k/15k
    max_run_s: float = 480.0  # one run with its extractions, inside a 600-s call with start-up
    s_per_iteration: float = 0.0165  # 400×400 (nerf_mic: 491 s / 30k)
    s_per_iteration_dtu: float = 0.0185  # 800×600 with the appearance model (554 s / 30k)
    setup_s: float = 15.0  # scene generation/loading, initialisation, final PLY + test evaluation
    snapshot_s: float = 4.0  # snapshot PLY + its test evaluation + reloading it
    tetra_s: float = 25.0  # tetra grid (octree by default; Delaunay on the host with --grid delaunay), field, marching; 100–200k Gaussians
    tetra_step_s: float = 1.0  # per binary-search step
    cubes256_s: float = 4.0  # field on a 256³ grid + marching cubes; × (res/256)² at other resolutions
    cubes256_step_s: float = 0.5
    tsdf512_s: float = 40.0  # fusion over the train views + marching cubes; × (res/512)³
    score_s: float = 5.0  # per mesh: sampling, Chamfer/F-score, connected components
    dtu_extract_factor: float = 2.0  # DTU models are ~3× larger (520k Gaussians), 49 views at 800×600

    def method_s(self, m: Method) -> float:
        if m.method == "none":
            return 0.0
        if m.method == "tetra":
            t = self.tetra_s + m.binary_steps * self.tetra_step_s
        elif m.method == "cubes":
            t = (m.resolution / 256) ** 2 * (self.cubes256_s + m.binary_steps * self.cubes256_step_s)
        else:
            t = self.tsdf512_s * (m.resolution / 512) ** 3
        return t + self.score_s

    def budget_s(self, run: Run) -> float:
        """Planned seconds of ``run``: set-up, training, snapshots and every extraction with its scoring."""
        dtu = run.config == "dtu"
        train = run.overrides["iterations"] * (self.s_per_iteration_dtu if dtu else self.s_per_iteration)
        extract = sum(map(self.method_s, run.methods)) + len(run.snapshots) * (
            self.snapshot_s + sum(map(self.method_s, run.snapshot_methods)))
        return round(self.setup_s + train + (self.dtu_extract_factor if dtu else 1.0) * extract)


def full_suite(z: Sizing = Sizing()) -> list[Run]:
    """The GPU suite. Every run uses GOF's schedule compressed to its length (:func:`gof_schedule`); images
    ``z.resolution``, the presets' 40 train / 8 test views, the ``blender`` preset (``dtu`` for DTU).

    * ``default_15k``: the training lengths — snapshots at 3k and 7k (before the regularisers, which start at
      half the schedule, as 3DGS's 7k of 30k) and the end, each with tetra(8) and cubes 256 (8 steps), TSDF at 15k.
    * ``default_7k``: every method (tetra 0/1/3/8 steps, cubes 256/512 with 0 and 8 steps, TSDF 512).
    * ``thin_7k``: the methods that differ on thin structures (tetra 0/3/8, cubes 256/512 with 8, TSDF).
    * ``garden``, ``textureless``, ``sparse``, ``spot`` 7k: GOF tetra(8) against TSDF. ``garden`` (ground,
      objects, thin parts and far background in metres) took the place of ``background`` (its subset): both
      do not fit the total device time (``background`` stays a preset and a stability case).
    * ``default_7k_budget50k`` (tetra 8) and ``default_7k_noreg`` (tetra 8, TSDF): against ``default_7k``
      (at 7k, not 15k, to fit: the compressed schedule switches the regularisers on at 3.5k).
    * real scenes (no GT mesh): ``nerf_mic`` 7k, rendering quality at 3k and 7k; ``dtu_scan24`` 7k, time and
      size of tetra(8) and TSDF.
    """
    every = (tetra(0), tetra(1), tetra(3), tetra(8), cubes(256, 0), cubes(256, 8), cubes(512, 0), cubes(512, 8),
             tsdf(512))
    pair = (tetra(8), tsdf(512))
    long, short = z.long_iterations, z.iterations

    def run(name, preset, iterations, methods, extra=None, *, suffix="", config="blender", resolution=z.resolution,
            **kw):
        over = _merge(_merge(gof_schedule(iterations), preset_overrides(preset)), extra or {})
        r = Run(f"{name}_{iterations // 1000}k{suffix}", preset, resolution, None, config, over, methods, **kw)
        return dataclasses.replace(r, budget_s=z.budget_s(r))

    runs = [
        run("default", "default", long, (tetra(8), cubes(256, 8), tsdf(512)), snapshots=z.snapshots,
            snapshot_methods=(tetra(8), cubes(256, 8))),
        run("default", "default", short, every),
        run("thin", "thin", short, (tetra(0), tetra(3), tetra(8), cubes(256, 8), cubes(512, 8), tsdf(512))),
        *(run(p, p, short, pair) for p in ("garden", "textureless", "sparse", "spot")),
        run("default", "default", short, (tetra(8),), {"densify": {"max_gaussians": 50_000}}, suffix="_budget50k"),
        run("default", "default", short, pair, NO_REGULARISERS, suffix="_noreg"),
        run("real_nerf_mic", "real:nerf_mic", short, (RENDER_ONLY,), resolution=(400, 400),
            snapshots=(z.snapshots[0],), snapshot_methods=(RENDER_ONLY,)),
        run("real_dtu_scan24", "real:dtu_scan24", short, pair, config="dtu", resolution=(800, 600)),
    ]
    for r in runs:
        if r.budget_s > z.max_run_s:
            log.warning("run %s: budget %.0f s is over Sizing.max_run_s (%.0f s): it will not fit one call", r.name,
                        r.budget_s, z.max_run_s)
    return runs


def suite(name: str) -> list[Run]:
    """The runs of a suite (plain data; ``--list`` prints them). ``budget_s`` of tiny/quick: 2-core CPU."""
    if name == "tiny":  # the test: one scene, one model + one snapshot, every method kind; ~30 s on 2 CPU cores
        sched = scaled_schedule(200, 2000, 1000)
        return [Run("default_tiny", "default", (40, 40), 12, overrides=sched, eval_samples=20_000,
                    methods=(tetra(0), tetra(2), cubes(24, 0), cubes(24, 4), tsdf(32)), snapshots=(100,),
                    snapshot_methods=(tetra(2), RENDER_ONLY), budget_s=40)]
    if name == "quick":  # CPU, a few minutes: two scenes, a budget, the regulariser ablation
        sched = scaled_schedule(300, 3000, 1500)
        methods = (tetra(0), tetra(3), tetra(8), cubes(40, 0), cubes(40, 4), tsdf(64))
        base = {"resolution": (48, 48), "views": 12, "methods": methods, "eval_samples": 50_000, "budget_s": 150}
        return [Run("default_300", "default", overrides=sched, **base),
                Run("thin_300", "thin", overrides=sched, **base),
                Run("default_300_budget1k", "default", overrides=_merge(sched, {"densify": {"max_gaussians": 1000}}),
                    **base),
                Run("default_300_noreg", "default", overrides=_merge(sched, NO_REGULARISERS), **base)]
    if name == "full":
        return full_suite()
    raise GofError(f"unknown suite {name!r}; suites: {', '.join(SUITES)}")


def select_runs(runs: list[Run], patterns: list[str] | None) -> list[Run]:
    """The runs whose names match one of the shell patterns (all when ``patterns`` is None); a pattern that
    matches no run is an error (a typo would otherwise run nothing)."""
    if not patterns:
        return runs
    unmatched = [p for p in patterns if not any(fnmatch.fnmatchcase(r.name, p) for r in runs)]
    if unmatched:
        raise GofError(f"--only {' '.join(unmatched)}: no run matches; runs: {', '.join(r.name for r in runs)}")
    return [r for r in runs if any(fnmatch.fnmatchcase(r.name, p) for p in patterns)]


@dataclass
class Model:
    """What a row is extracted from: the run's last model or one of its snapshots."""

    gaussians: object
    iteration: int
    snapshot: bool
    train_time_s: float | None  # training time up to this model
    test: dict  # the trainer's evaluate() of this model


def _model_at(iteration: int, last, metrics: dict, run_dir: Path, device: str) -> Model:
    from ..core.model import Gaussians

    if iteration == metrics.get("iterations"):
        return Model(last, iteration, False, metrics.get("train_time_s"), metrics.get("test", {}))
    rec = next(s for s in metrics["snapshots"] if s["iteration"] == iteration)
    return Model(Gaussians.load_ply(run_dir / rec["path"], device=device), iteration, True, rec["train_time_s"],
                 rec.get("test", {}))


def _variant(run: Run) -> dict:
    """The training variant's columns: Gaussian budget and regularisers on/off."""
    loss = run.overrides.get("loss", {})
    return {"max_gaussians": run.overrides.get("densify", {}).get("max_gaussians"),
            "regularisers": not (loss.get("lambda_distortion") == 0.0 and loss.get("lambda_normal") == 0.0)}


def _extract(method: Method, model: Model, scene, render_config, grid_cache: dict | None = None):
    """``(verts, faces, error, grid_shared)``: the mesh (None for ``render_only``), or empty with the refusal's
    message; ``grid_shared``: the tetrahedral grid came from ``grid_cache`` (built by an earlier method of the
    same model: this row's time leaves it out)."""
    from ..mesh.extraction import StageTimer, extract_mesh

    if method.method == "none":
        return None, None, None, False
    timer = StageTimer(model.gaussians.device)
    try:
        (verts, faces), = extract_mesh(model.gaussians, scene.train_cameras, method.mesh_config(),
                                       render_config=render_config, views=scene.train, timer=timer,
                                       grid_cache=grid_cache)
        return verts, faces, None, "grid_shared" in timer.stages
    except GofError as e:  # a clear refusal is a result of the configuration (recorded), not a bench failure
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), str(e), "grid_shared" in timer.stages


def _mesh_photo_scores(verts, faces, scene, render_config, device) -> dict:
    """The mesh coloured from the training photos (per vertex, with visibility) and rendered from the test views:
    PSNR/SSIM against their photos (:func:`gof_warp.mesh.colour.mesh_render_psnr`); {} without test views."""
    from ..core.devices import warp_device
    from ..mesh.colour import colours_from_images, mesh_render_psnr

    if not scene.test:
        return {}
    device = warp_device(device)
    colours = colours_from_images(verts, faces, scene.train_cameras, [v.image for v in scene.train], device=device)
    return mesh_render_psnr(verts, faces, colours, [v.camera for v in scene.test], [v.image for v in scene.test],
                            background=tuple(render_config.background), device=device)


def _extract_row(run: Run, method: Method, model: Model, scene, render_config, metrics, scene_dir: Path,
                 machine: dict, grid_cache: dict | None = None) -> dict:
    """Extract one mesh from ``model``, score it, and return its results row (with the machine it ran on).
    ``grid_cache``: one dict per model, so its tetrahedral grid is built once (the row says ``grid_shared``)."""
    reset_peak_memory()
    t0 = time.perf_counter()
    verts, faces, error, grid_shared = _extract(method, model, scene, render_config, grid_cache)
    if error:
        log.warning("run %s @%d, %s: %s", run.name, model.iteration, method.name, error)
    extract_time = time.perf_counter() - t0 if verts is not None else None
    extract_mem = peak_memory()
    t1 = time.perf_counter()
    m, st = scores(verts, faces, scene_dir / "gt_mesh.ply", run.eval_samples) if verts is not None else ({}, {})

    photo = (_mesh_photo_scores(verts, faces, scene, render_config, model.gaussians.device)
             if verts is not None and len(faces) else {})

    def first(key):  # the score at the first τ (0.5 % of the GT diagonal)
        return m[key][0] if m else None

    train_mem = metrics.get("bench_peak_memory", {})
    return {
        "run": run.name, "scene": run.preset, "resolution": f"{run.resolution[0]}x{run.resolution[1]}",
        "train_views": len(scene.train), "test_views": model.test.get("views"), "iterations": metrics.get("iterations"),
        "iteration": model.iteration, "snapshot": model.snapshot, **_variant(run),
        "method": method.name, "method_kind": method.method, "binary_steps": method.binary_steps,
        "grid_resolution": method.resolution,
        "chamfer": m.get("chamfer"), "accuracy": m.get("accuracy"), "completeness": m.get("completeness"), "fscore": first("fscore"), "precision": first("precision"),
        "recall": first("recall"), "tau": first("tau"), "fscore_2tau": m["fscore"][-1] if m else None,
        "tau_2": m["tau"][-1] if m else None,
        "components": st.get("connected_components"), "watertight": st.get("watertight"),
        "faces": st.get("faces"), "vertices": st.get("vertices"),
        "test_psnr": model.test.get("psnr"), "test_ssim": model.test.get("ssim"), "num_gaussians": len(model.gaussians),
        "mesh_psnr": photo.get("psnr"), "mesh_ssim": photo.get("ssim"), "mesh_coverage": photo.get("coverage"),
        "train_time_s": model.train_time_s,
        "extract_time_s": None if extract_time is None else round(extract_time, 3), "grid_shared": grid_shared,
        "total_time_s": round(float(model.train_time_s or 0.0) + (extract_time or 0.0), 3),
        "eval_time_s": round(time.perf_counter() - t1, 3) if verts is not None else None,
        "train_host_peak_rss_mb": train_mem.get("host_peak_rss_mb", metrics.get("host_peak_rss_mb")),
        "train_gpu_peak_allocated_mb": train_mem.get("gpu_peak_allocated_mb", metrics.get("gpu_peak_allocated_mb")),
        "train_gpu_peak_reserved_mb": train_mem.get("gpu_peak_reserved_mb", metrics.get("gpu_peak_reserved_mb")),
        "train_device_used_peak_mb": metrics.get("device_used_peak_mb"),
        "extract_host_peak_rss_mb": extract_mem["host_peak_rss_mb"],
        "extract_gpu_peak_allocated_mb": extract_mem["gpu_peak_allocated_mb"],
        "device": str(model.gaussians.device), "error": error,
        **{f"machine_{k}": v for k, v in machine.items()},
    }


# ----------------------------------------------------------------------------------------- the suite
def pending(run: Run, done: set) -> list[tuple[int, tuple[Method, ...]]]:
    """``[(iteration, methods), …]`` of the run still missing from the table (keys in ``done``), snapshots first."""
    plan = [(k, run.snapshot_methods) for k in run.snapshots] + [(run_config(run).iterations, run.methods)]
    left = [(k, tuple(m for m in methods if (run.name, k, m.name) not in done)) for k, methods in plan]
    return [(k, methods) for k, methods in left if methods]


def run_suite(name: str, out, device: str = "cpu", runs: list[Run] | None = None, *,
              time_limit: float | None = None, started: float | None = None, data=None, runs_dir=None,
              stages=None) -> list[dict]:
    """Run (or continue) a suite into ``out``; returns every row of the table.

    Args:
        stages: a :class:`gof_warp.core.progress.Stages` reporting each run as a stage (its training bar, then a bar
            over its extractions); None: no progress.
        runs_dir: where each run's scene, model and snapshots go (``runs_dir/<run>``; default ``out/runs``), so
            that ``out`` can hold only the table and charts (what a device call brings back).
        time_limit: seconds after ``started`` (a ``time.perf_counter()``; default: now) past which no run may be
            planned to end (``Run.budget_s``): such runs are skipped (see :func:`pending` for what is left).
        data: the folder of the real scenes (:func:`data_root`).
    """
    from ..core.io_utils import ensure_writable_dir

    from ..core.progress import as_stages

    reporter = as_stages(stages)
    started = time.perf_counter() if started is None else started
    out = ensure_writable_dir(out)
    runs = suite(name) if runs is None else runs
    rows = load_rows(out)
    machine = machine_info()
    done = {row_key(r) for r in rows}
    for run in runs:
        todo = pending(run, done)
        if not todo:
            log.info("run %s: every row already in the table, skipped", run.name)
            continue
        elapsed = time.perf_counter() - started
        if time_limit is not None and elapsed + run.budget_s > time_limit:
            log.warning("run %s not started: %.0f s elapsed + its budget %.0f s > --time-limit %.0f s", run.name,
                        elapsed, run.budget_s, time_limit)
            continue
        run_dir = ensure_writable_dir(Path(runs_dir or out / "runs") / run.name)
        with reporter.stage(f"run {run.name}"):
            if stages is None:
                trained = _train_or_load(run, run_dir, device, data)
            else:
                with reporter.training(run_config(run).iterations) as progress:
                    trained = _train_or_load(run, run_dir, device, data, progress=progress)
            gaussians, scene, render_config, metrics, scene_dir = trained
            with reporter.bar(sum(len(m) for _, m in todo), "extract", unit="mesh") as bar:
                for iteration, methods in todo:
                    model = _model_at(iteration, gaussians, metrics, run_dir, device)
                    grid_cache: dict = {}  # the model's tetrahedral grid, built by its first tetra method
                    for method in methods:
                        log.info("run %s @%d: %s", run.name, iteration, method.name)
                        row = _extract_row(run, method, model, scene, render_config, metrics, scene_dir, machine,
                                           grid_cache)
                        rows.append(row)
                        write_table(out, name, rows, machine)  # after every row: an interruption loses one at most
                        log.info("  %s: chamfer %s, F %s, %s faces, %s s", method.name, row.get("chamfer"),
                                 row.get("fscore"), row.get("faces"), row.get("extract_time_s"))
                        bar.update(postfix=f"@{iteration} {method.name}")
    charts = write_charts(out, rows) if rows else []  # the table is as the last row left it (or untouched)
    if charts:
        log.info("charts: %s", ", ".join(str(c) for c in charts))
    return rows


def describe(runs: list[Run]) -> str:
    """The plan: each run with its budget, training, methods; then the total."""
    lines = []
    for r in runs:
        v = _variant(r)
        extra = "".join([f", budget {v['max_gaussians']:,} Gaussians" if v["max_gaussians"] else "",
                         "" if v["regularisers"] else ", regularisers off",
                         f", snapshots at {', '.join(map(str, r.snapshots))}" if r.snapshots else ""])
        views = r.views or ("all" if r.preset.startswith("real:") else "preset")
        lines.append(f"{r.name}  [{r.budget_s:.0f} s]  {r.preset} {r.resolution[0]}x{r.resolution[1]}, views {views}, "
                     f"config {r.config}, {run_config(r).iterations} iterations{extra}")
        lines.append(f"    methods: {', '.join(m.name for m in r.methods)}")
        if r.snapshots:
            lines.append(f"    at each snapshot: {', '.join(m.name for m in r.snapshot_methods) or '-'}")
    total = sum(r.budget_s for r in runs)
    longest = max(runs, key=lambda r: r.budget_s)
    lines.append(f"total budget: {total:.0f} s = {total / 60:.1f} min for {len(runs)} runs "
                 f"(longest: {longest.name}, {longest.budget_s:.0f} s)")
    return "\n".join(lines)


DESCRIPTION = """\
Accuracy against cost, across extraction methods, training lengths, Gaussian budgets and the
regularisers: scenes x training configurations x extraction methods. Each run (scene, training
configuration) is trained once; its model and the snapshots saved on the way are extracted with
every method of the run, timed, and scored against the scene's exact gt_mesh.ply. Writes
DIR/results.json and DIR/results.csv (one row per run, iteration and method) and charts."""
EPILOG = """\
Rows already in DIR/results.json are skipped, so an interrupted suite continues where it stopped
(a run whose model is still in DIR/runs/<run>, or --runs-dir, is not trained again). With
--time-limit S no run starts whose planned cost would end more than S seconds after the command
started; when runs are left the exit code is 3: run the same command again. --time-limit 0 runs
nothing: it redraws the charts of the table so far and lists what is left.

The stability suite writes stability.json; its exit code is 1 when any (case, method) crashed."""


def main(argv=None) -> int:
    started = time.perf_counter()
    ap = argparse.ArgumentParser(prog="python -m gof_warp.bench", description=DESCRIPTION, epilog=EPILOG,
                                 formatter_class=HelpFormatter)
    ap.add_argument("--suite", default="quick", choices=SUITES,
                    help="tiny (the test's), quick (a CPU in minutes), full (the GPU run) or stability (where each "
                         "extraction method breaks)")
    ap.add_argument("--out", default=None, help="results folder (default: benchmarks/results/<suite>)")
    ap.add_argument("--list", action="store_true", help="print the runs of the suite (budgets, total) and exit")
    ap.add_argument("--only", nargs="+", metavar="PATTERN", help="only the runs whose names match one of these "
                                                                  "shell patterns, e.g. 'default_*' thin_7k (default: "
                                                                  "every run)")
    ap.add_argument("--time-limit", type=float, metavar="SECONDS", help="start no run whose budget would end later "
                    "than this after the command started; exit code 3 when runs are left (default: "
                    "no limit)")
    ap.add_argument("--runs-dir", default=None, help="folder for the trained models and generated scenes "
                                                     "(default: OUT/runs)")
    ap.add_argument("--data", default=None, help="folder of the real scenes and spot's mesh "
                                                 "(default: $GOF_WARP_DATA, else ../shared/data)")
    ap.add_argument("--device", default="auto", help="cpu, cuda, cuda:N or auto")
    ap.add_argument("--fast", action="store_true", help="stability: only the hand-made cases (no training)")
    ap.add_argument("--quiet", action="store_true", help="no progress bars or log lines (errors and warnings shown)")
    a = ap.parse_args(argv)
    configure_output(a.quiet)

    def body():
        from ..core.devices import resolve_device as pick_device

        if a.suite == "stability":
            from ..benchmarking.stability import run_stability

            if a.list:
                from ..benchmarking.stability import CASES, TRAINED_PRESETS

                print("\n".join([*CASES, *(f"{p} (trained)" for p in TRAINED_PRESETS)]))
                return 0
            report = run_stability(Path(a.out or "benchmarks/results/stability"), device=pick_device(a.device),
                                   trained=not a.fast)
            crashed = [f"{r['case']}/{r['method']}" for r in report if r["outcome"] == "crash"]
            print(f"{len(report)} (case, method) reports; crashes: {', '.join(crashed) or 'none'}")
            return 1 if crashed else 0
        runs = select_runs(suite(a.suite), a.only)
        if a.list:
            print(describe(runs))
            return 0
        out = Path(a.out or f"benchmarks/results/{a.suite}")
        from ..core.progress import Stages

        rows = run_suite(a.suite, out, pick_device(a.device), runs, time_limit=a.time_limit, started=started,
                         data=a.data, runs_dir=a.runs_dir, stages=Stages(quiet=a.quiet))
        print(f"{len(rows)} rows in {out}/results.json")
        done = {row_key(r) for r in rows}
        left = [r for r in runs if pending(r, done)]
        if left:
            never = [r.name for r in left if a.time_limit is not None and r.budget_s > a.time_limit]
            print(f"{len(left)} runs left ({', '.join(r.name for r in left)}); run the same command again"
                  + (f". Over --time-limit on their own: {', '.join(never)} (raise it, or run them alone)"
                     if never else ""), file=sys.stderr)
            return EXIT_RUNS_LEFT
        return 0

    return run_command(body, "rows written so far are kept; run the same command again to continue")


if __name__ == "__main__":
    sys.exit(main())
