"""``python -m gof_warp.bench [--suite tiny|quick|full|stability] --out DIR [--list] [--device D]``

Accuracy against cost, across extraction methods, training lengths, Gaussian budgets and the
regularisers: scenes × training configurations × extraction methods. Each (scene, training config) is
trained once; every method is extracted from that model, timed, and scored against the scene's exact
``gt_mesh.ply``. Writes ``DIR/results.json`` and ``DIR/results.csv`` (one row per (run, method), with every
time, memory, size and accuracy figure and the machine) and charts (``chamfer_vs_time.png``,
``fscore_vs_time.png``, ``chamfer_vs_gaussians.png``, ``chamfer_vs_faces.png``; needs matplotlib, the
``plots`` extra). Memory is the peak host RSS (Linux VmHWM, reset before each training and extraction) and
torch's peak CUDA allocation. An extraction refused with a clear error (e.g. an empty model) is a row with
``error`` set and no scores; anything else that fails stops the suite. Rows already in
``DIR/results.json`` are skipped, so an interrupted suite continues (a run whose model is already trained
in ``DIR/runs/<run>`` is not trained again).

A suite is plain data (:func:`suite`): ``tiny`` (the test's), ``quick`` (a CPU in minutes), ``full`` (the
GPU run: every preset at 800×800, 3k–30k iterations, budgets, the regulariser ablation, every method).
``stability`` runs :mod:`gof_warp.stability` (where each method breaks; ``--fast``: only the hand-made
cases) and writes ``stability.json``; its exit code is 1 when any (case, method) crashed.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import logging
import math
import os
import platform
import resource
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .cli import configure_output, run_command
from .errors import GofError

log = logging.getLogger("gof_warp.bench")

SUITES = ("tiny", "quick", "full", "stability")
CHARTS = (("total_time_s", "chamfer", "chamfer_vs_time.png"), ("total_time_s", "fscore", "fscore_vs_time.png"),
          ("num_gaussians", "chamfer", "chamfer_vs_gaussians.png"), ("faces", "chamfer", "chamfer_vs_faces.png"))


# ----------------------------------------------------------------------------------------- the suites
@dataclass(frozen=True)
class Method:
    """One extraction configuration; ``name`` is its key in the results table."""

    name: str
    method: str  # tetra | cubes | tsdf
    binary_steps: int = 0
    resolution: int | None = None  # grid resolution (cubes, tsdf)

    def mesh_config(self):
        from .extract import MeshConfig

        cfg = MeshConfig(method=self.method, binary_steps=self.binary_steps)
        if self.resolution:
            cfg.cubes_resolution = self.resolution
            cfg.tsdf.resolution = self.resolution
        return cfg


@dataclass(frozen=True)
class Run:
    """One trained model: a synthetic preset at a resolution/view count, a training config, its methods."""

    name: str
    preset: str
    resolution: tuple[int, int]
    views: int | None
    config: str = "quick"  # training preset (configs/NAME.yaml)
    overrides: dict = field(default_factory=dict, hash=False)  # merged into the preset (nested sections)
    methods: tuple[Method, ...] = ()
    eval_samples: int | None = None  # GT surface samples for scoring (None: geometry_metrics' default)


def tetra(steps):
    return Method(f"tetra_bs{steps}", "tetra", steps)


def cubes(res, steps):
    return Method(f"cubes{res}_bs{steps}", "cubes", steps, res)


def tsdf(res):
    return Method(f"tsdf{res}", "tsdf", 0, res)


def scaled_schedule(iterations: int, max_gaussians: int, init_points: int) -> dict:
    """The ``quick`` preset's schedule (written for 1,200 iterations) stretched to ``iterations``."""
    s = iterations / 1200.0

    def at(k):
        return max(1, round(k * s))

    return {"iterations": iterations, "checkpoint_every": 0, "log_every": max(1, iterations // 10),
            "model": {"random_init_points": init_points}, "optim": {"means_lr_max_steps": iterations},
            "densify": {"start_iter": at(100), "stop_iter": at(900), "interval": at(100),
                        "opacity_reset_interval": 10 * iterations, "sh_degree_interval": at(400),
                        "filter_3d_until_iter": at(1100), "max_gaussians": max_gaussians},
            "loss": {"regularization_from_iter": at(600)}}


NO_REGULARISERS = {"loss": {"lambda_distortion": 0.0, "lambda_normal": 0.0}}


def _merge(a: dict, b: dict) -> dict:
    out = dict(a)
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def preset_overrides(preset: str) -> dict:
    """Training overrides a synthetic preset needs: the ``background`` preset's ground plane and shell reach
    radius 6, so its random initialisation must too (the presets' init boxes are ±1 or ±1.3)."""
    return {"model": {"init_box": [-6.0, -6.0, -6.0, 6.0, 6.0, 6.0]}} if preset == "background" else {}


def suite(name: str) -> list[Run]:
    """The runs of a suite (plain data; ``--list`` prints them)."""
    if name == "tiny":  # the test: one scene, one model, every method kind; ~1 minute on 2 CPU cores
        sched = scaled_schedule(200, 2000, 1000)
        return [Run("default_tiny", "default", (40, 40), 12, overrides=sched, eval_samples=20_000,
                    methods=(tetra(0), tetra(2), cubes(24, 0), cubes(24, 4), tsdf(32)))]
    if name == "quick":  # CPU, a few minutes: two scenes, a budget, the regulariser ablation
        sched = scaled_schedule(300, 3000, 1500)
        methods = (tetra(0), tetra(3), tetra(8), cubes(40, 0), cubes(40, 4), tsdf(64))
        base = {"resolution": (48, 48), "views": 12, "methods": methods, "eval_samples": 50_000}
        return [Run("default_300", "default", overrides=sched, **base),
                Run("thin_300", "thin", overrides=sched, **base),
                Run("default_300_budget1k", "default", overrides=_merge(sched, {"densify": {"max_gaussians": 1000}}),
                    **base),
                Run("default_300_noreg", "default", overrides=_merge(sched, NO_REGULARISERS), **base)]
    if name == "full":  # the GPU run (not run on CPU)
        from .synthetic import GPU_RESOLUTION

        methods = (tetra(0), tetra(1), tetra(3), tetra(8), cubes(256, 0), cubes(256, 8), cubes(512, 0),
                   cubes(512, 8), tsdf(512))
        runs = []
        for preset in ("default", "thin", "background", "textureless", "sparse"):
            for it in (3000, 7000, 15000, 30000):
                over = {"iterations": it, "densify": {"max_gaussians": 1_000_000}}
                runs.append(Run(f"{preset}_{it}", preset, GPU_RESOLUTION, None, "blender", over, methods))
            if preset not in ("default", "thin"):
                continue
            for budget in (50_000, 200_000):  # budgets and the ablation on the two geometry-critical scenes
                runs.append(Run(f"{preset}_30000_budget{budget // 1000}k", preset, GPU_RESOLUTION, None, "blender",
                                {"iterations": 30000, "densify": {"max_gaussians": budget}}, methods))
            runs.append(Run(f"{preset}_30000_noreg", preset, GPU_RESOLUTION, None, "blender",
                            _merge({"iterations": 30000}, NO_REGULARISERS), methods))
        runs = [dataclasses.replace(r, overrides=_merge(r.overrides, preset_overrides(r.preset))) for r in runs]
        # spot (a textured mesh from ../shared/data, with GT) and real scenes (no GT mesh: rendering quality, size
        # and time only; their rows leave the accuracy columns empty)
        runs += [Run("spot_30000", "spot", GPU_RESOLUTION, None, "blender", {"iterations": 30000}, methods),
                 Run("real_nerf_mic_30000", "real:nerf_mic", (400, 400), None, "blender", {"iterations": 30000},
                     methods),
                 Run("real_dtu_scan24_30000", "real:dtu_scan24", (800, 600), None, "dtu", {"iterations": 30000},
                     (tetra(8), tsdf(512)))]
        return runs
    raise GofError(f"unknown suite {name!r}; suites: {', '.join(SUITES)}")


# ----------------------------------------------------------------------------------------- one run
def machine_info() -> dict:
    """The machine a row was measured on."""
    import torch
    import warp as wp

    cpu = platform.processor()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                   if line.startswith("model name")) or cpu
    except (OSError, StopIteration):
        pass
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
    return {"platform": platform.platform(), "cpu": cpu, "cpu_count": os.cpu_count(), "gpu": gpu,
            "python": platform.python_version(), "torch": torch.__version__, "warp": wp.config.version}


def reset_peak_memory() -> None:
    """Start a new peak for :func:`peak_memory` (Linux: ``/proc/self/clear_refs``; CUDA: torch's counters)."""
    import torch

    try:
        Path("/proc/self/clear_refs").write_text("5")  # resets VmHWM, the process's resident-set high-water mark
    except OSError:
        pass
    if torch.cuda.is_available():
        torch.cuda.reset_peak_memory_stats()


def peak_memory() -> dict:
    """Peak host RSS since :func:`reset_peak_memory` (VmHWM; where unavailable, the process's lifetime peak)
    and torch's peak CUDA allocation, in MB."""
    import torch

    host = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    try:
        line = next(x for x in Path("/proc/self/status").read_text().splitlines() if x.startswith("VmHWM:"))
        host = int(line.split()[1]) / 1024.0
    except (OSError, StopIteration, ValueError):
        pass
    gpu = torch.cuda.max_memory_allocated() / 2**20 if torch.cuda.is_available() else None
    return {"host_peak_rss_mb": round(host, 1), "gpu_peak_allocated_mb": None if gpu is None else round(gpu, 1)}


DATA_ROOT = Path(__file__).resolve().parents[1].parent / "shared" / "data"  # real scenes (../shared/data)


def scene_folder(run: Run, run_dir: Path) -> Path:
    """The run's scene: a real scene under ``DATA_ROOT`` (``real:NAME``), else the synthetic preset rendered into
    ``run_dir/scene`` (once)."""
    if run.preset.startswith("real:"):
        path = DATA_ROOT / run.preset[5:]
        if not path.is_dir():
            raise GofError(f"run {run.name}: real scene {path} is absent (the full suite reads ../shared/data)")
        return path
    from .synthetic import make_scene

    scene_dir = run_dir / "scene"
    if not (scene_dir / "gt_mesh.ply").is_file():
        make_scene(run.preset, scene_dir, views=run.views, resolution=run.resolution, force=True)
    return scene_dir


def _train_or_load(run: Run, run_dir: Path, device: str):
    """``(gaussians, scene, render_config, metrics, scene_dir)``; a model already trained in ``run_dir`` is reused."""
    import json

    from .config import merge
    from .data import load_scene
    from .model import Gaussians
    from .train import resolve_config
    from .trainer import Trainer

    scene_dir = scene_folder(run, run_dir)
    cfg = merge(resolve_config(run.config, [], None), run.overrides, f"run {run.name}")
    scene = load_scene(scene_dir, cfg.data)
    metrics_file = run_dir / "metrics.json"
    if metrics_file.is_file() and (run_dir / "point_cloud.ply").is_file():
        log.info("run %s: reusing the trained model in %s", run.name, run_dir)
        render_config = dataclasses.replace(cfg.render, background=tuple(float(c) for c in scene.background))
        return (Gaussians.load_ply(run_dir / "point_cloud.ply", device=device), scene, render_config,
                json.loads(metrics_file.read_text()), scene_dir)
    log.info("run %s: training %d iterations on %s (%d views)", run.name, cfg.iterations, run.preset, len(scene.train))
    reset_peak_memory()
    trainer = Trainer(scene, cfg, run_dir, device)
    metrics = trainer.run()
    metrics["bench_peak_memory"] = peak_memory()  # this run's own peak (the trainer's RSS is the process's)
    return trainer.gaussians, scene, trainer.render_config, metrics, scene_dir


def _scores(verts, faces, gt_path: Path, eval_samples: int | None) -> tuple[dict, dict]:
    """``(metrics, mesh_stats)`` of :func:`evaluate_mesh` (default τ); metrics are ``{}`` without a GT mesh."""
    from .geometry_metrics import (
        default_eval_params,
        evaluate_mesh,
        load_geometry,
        mesh_statistics,
    )

    if not gt_path.is_file():
        return {}, mesh_statistics((verts, faces))
    gt = load_geometry(gt_path)
    kw = {}
    if eval_samples and float(gt.area) > 0:  # coarser sampling than the default, same τ and truncation
        params = default_eval_params(gt)
        kw = {"density": math.sqrt(float(gt.area) / eval_samples), "tau": params["tau"], "max_dist": params["max_dist"]}
    ev = evaluate_mesh((verts, faces), gt, **kw)
    return ev["metrics"], ev["mesh_stats"]


def _finite(x):
    return x if isinstance(x, (int, float)) and math.isfinite(x) else None


def _extract_row(run: Run, method: Method, gaussians, scene, render_config, metrics, scene_dir: Path,
                 machine: dict) -> dict:
    """Extract one mesh, score it, and return its results row (with the machine it ran on)."""
    from .extract import StageTimer, extract_mesh

    reset_peak_memory()
    t0 = time.perf_counter()
    try:
        (verts, faces), = extract_mesh(gaussians, scene.train_cameras, method.mesh_config(),
                                       render_config=render_config, views=scene.train, timer=StageTimer())
        error = None
    except GofError as e:  # a clear refusal is a result of the configuration (recorded), not a bench failure
        log.warning("run %s, %s: %s", run.name, method.name, e)
        verts, faces, error = np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), str(e)
    extract_time = time.perf_counter() - t0
    extract_mem = peak_memory()
    t1 = time.perf_counter()
    m, st = _scores(verts, faces, scene_dir / "gt_mesh.ply", run.eval_samples)

    def first(key):  # the score at the first τ (0.5 % of the GT diagonal)
        return m[key][0] if m else None

    test = metrics.get("test", {})
    train_mem = metrics.get("bench_peak_memory", {})
    row = {
        "run": run.name, "scene": run.preset, "resolution": f"{run.resolution[0]}x{run.resolution[1]}",
        "train_views": len(scene.train), "test_views": test.get("views"), "iterations": metrics.get("iterations"),
        "max_gaussians": run.overrides.get("densify", {}).get("max_gaussians"),
        "regularisers": not (run.overrides.get("loss", {}).get("lambda_distortion") == 0.0
                             and run.overrides.get("loss", {}).get("lambda_normal") == 0.0),
        "method": method.name, "method_kind": method.method, "binary_steps": method.binary_steps,
        "grid_resolution": method.resolution,
        "chamfer": _finite(m.get("chamfer")), "accuracy": _finite(m.get("accuracy")),
        "completeness": _finite(m.get("completeness")), "fscore": first("fscore"), "precision": first("precision"),
        "recall": first("recall"), "tau": first("tau"), "fscore_2tau": m["fscore"][-1] if m else None,
        "tau_2": m["tau"][-1] if m else None,
        "components": st["connected_components"], "watertight": st["watertight"],
        "faces": st["faces"], "vertices": st["vertices"],
        "test_psnr": test.get("psnr"), "test_ssim": test.get("ssim"), "num_gaussians": len(gaussians),
        "train_time_s": metrics.get("train_time_s"), "extract_time_s": round(extract_time, 3),
        "total_time_s": round(float(metrics.get("train_time_s") or 0.0) + extract_time, 3),
        "eval_time_s": round(time.perf_counter() - t1, 3),
        "train_host_peak_rss_mb": train_mem.get("host_peak_rss_mb", metrics.get("host_peak_rss_mb")),
        "train_gpu_peak_allocated_mb": train_mem.get("gpu_peak_allocated_mb", metrics.get("gpu_peak_allocated_mb")),
        "extract_host_peak_rss_mb": extract_mem["host_peak_rss_mb"],
        "extract_gpu_peak_allocated_mb": extract_mem["gpu_peak_allocated_mb"],
        "device": str(gaussians.device), "error": error,
        **{f"machine_{k}": v for k, v in machine.items()},
    }
    return row


# ----------------------------------------------------------------------------------------- table + charts
def load_rows(out: Path) -> list[dict]:
    import json

    path = out / "results.json"
    if not path.is_file():
        return []
    try:
        return list(json.loads(path.read_text())["rows"])
    except (ValueError, KeyError, TypeError) as e:
        raise GofError(f"{path} is not a results table ({e}); move it away or choose another --out") from None


def write_table(out: Path, suite_name: str, rows: list[dict], machine: dict) -> None:
    """``results.json`` (rows + the current machine) and ``results.csv`` (the rows; each names its machine in
    its ``machine_*`` columns, so a table continued elsewhere stays honest), atomically."""
    from .io_utils import write_json_atomic, write_text_atomic

    write_json_atomic(out / "results.json", {"suite": suite_name, "machine": machine, "rows": rows})
    columns = list(dict.fromkeys(k for r in rows for k in r))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    write_text_atomic(out / "results.csv", buf.getvalue())


def write_charts(out: Path, rows: list[dict]) -> list[Path]:
    """The four accuracy-vs-cost scatter charts (colour = method, marker = scene); [] without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log.warning("matplotlib is not installed (pip install 'gof_warp[plots]'): charts skipped, results written")
        return []
    from .io_utils import atomic_path

    methods = sorted({r["method"] for r in rows})
    scenes = sorted({r["scene"] for r in rows})
    colours = plt.get_cmap("tab10" if len(methods) <= 10 else "tab20")
    markers = "osD^vP*Xh<>"
    written = []
    for xkey, ykey, name in CHARTS:
        fig, ax = plt.subplots(figsize=(7, 5))
        for i, meth in enumerate(methods):
            for j, sc in enumerate(scenes):
                pts = [(r[xkey], r[ykey], r["run"]) for r in rows if r["method"] == meth and r["scene"] == sc
                       and r.get(xkey) is not None and r.get(ykey) is not None]
                if pts:
                    x, y, names = zip(*pts)
                    ax.scatter(x, y, color=colours(i % colours.N), marker=markers[j % len(markers)],
                               label=f"{meth} / {sc}", s=36, alpha=0.85)
                    for xi, yi, run_name in zip(x, y, names):  # the training variant, e.g. "300_noreg"
                        ax.annotate(run_name.removeprefix(f"{sc}_"), (xi, yi), fontsize=5, alpha=0.6,
                                    xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel(xkey.replace("_", " "))
        ax.set_ylabel(ykey + (" (lower is better)" if ykey == "chamfer" else " at τ (higher is better)"))
        if all((r.get(xkey) or 0) > 0 for r in rows):
            ax.set_xscale("log")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, ncol=2, loc="best")
        ax.set_title(f"{ykey} vs {xkey.replace('_', ' ')}: one point per (run, method)")
        fig.tight_layout()
        with atomic_path(out / name) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
        plt.close(fig)
        written.append(out / name)
    return written


def run_suite(name: str, out, device: str = "cpu", runs: list[Run] | None = None) -> list[dict]:
    """Run (or continue) a suite into ``out``; returns every row of the table."""
    from .io_utils import ensure_writable_dir

    out = ensure_writable_dir(out)
    runs = suite(name) if runs is None else runs
    rows = load_rows(out)
    machine = machine_info()
    done = {(r["run"], r["method"]) for r in rows}
    for run in runs:
        todo = [m for m in run.methods if (run.name, m.name) not in done]
        if not todo:
            log.info("run %s: all %d methods already in the table, skipped", run.name, len(run.methods))
            continue
        run_dir = ensure_writable_dir(out / "runs" / run.name)
        gaussians, scene, render_config, metrics, scene_dir = _train_or_load(run, run_dir, device)
        for method in todo:
            log.info("run %s: extracting %s", run.name, method.name)
            row = _extract_row(run, method, gaussians, scene, render_config, metrics, scene_dir, machine)
            rows.append(row)
            write_table(out, name, rows, machine)  # after every row: an interruption loses one extraction at most
            log.info("  %s: chamfer %s, F %s, %d faces, %.1f s", method.name, row["chamfer"], row["fscore"],
                     row["faces"], row["extract_time_s"])
    write_table(out, name, rows, machine)
    charts = write_charts(out, rows)
    if charts:
        log.info("charts: %s", ", ".join(str(c) for c in charts))
    return rows


def describe(runs: list[Run]) -> str:
    lines = []
    for r in runs:
        over = {k: v for k, v in r.overrides.items() if k in ("iterations", "densify", "loss")}
        lines.append(f"{r.name}: preset {r.preset} {r.resolution[0]}x{r.resolution[1]} views {r.views or 'preset'}, "
                     f"config {r.config} {over}\n    methods: {', '.join(m.name for m in r.methods)}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gof_warp.bench", description=__doc__.split("\n\n")[1])
    ap.add_argument("--suite", default="quick", choices=SUITES)
    ap.add_argument("--out", default=None, help="results folder (default benchmarks/results/<suite>)")
    ap.add_argument("--list", action="store_true", help="print the runs of the suite and exit")
    ap.add_argument("--device", default="auto", help="cpu, cuda or auto")
    ap.add_argument("--fast", action="store_true", help="stability: only the hand-made cases (no training)")
    ap.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    configure_output(a.quiet)

    def body():
        from .train import pick_device

        if a.suite == "stability":
            from .stability import run_stability

            if a.list:
                from .stability import CASES, TRAINED_PRESETS

                print("\n".join([*CASES, *(f"{p} (trained)" for p in TRAINED_PRESETS)]))
                return 0
            report = run_stability(Path(a.out or "benchmarks/results/stability"), device=pick_device(a.device),
                                   trained=not a.fast)
            crashed = [f"{r['case']}/{r['method']}" for r in report if r["outcome"] == "crash"]
            print(f"{len(report)} (case, method) reports; crashes: {', '.join(crashed) or 'none'}")
            return 1 if crashed else 0
        runs = suite(a.suite)
        if a.list:
            print(describe(runs))
            return 0
        rows = run_suite(a.suite, Path(a.out or f"benchmarks/results/{a.suite}"), pick_device(a.device), runs)
        print(f"{len(rows)} rows in {a.out or f'benchmarks/results/{a.suite}'}/results.json")
        return 0

    return run_command(body, "rows written so far are kept; run the same command again to continue")


if __name__ == "__main__":
    sys.exit(main())
