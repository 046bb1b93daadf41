"""The benchmark's measurements and outputs: the machine, peak memory and scores a row records, the results
table (``results.json`` + ``results.csv``) and its charts.

One row per (run, iteration, method): ``iteration`` is the model's (a snapshot's, or the run's last);
:func:`row_key` is the key a continued suite skips on. Charts are scatter plots of accuracy (or test PSNR)
against cost, one point per row: colour = method, marker = scene, each point labelled with the run's
training variant (``7k_noreg``; ``15k@3000`` for a snapshot). They need matplotlib (the ``plots`` extra).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import os
import platform
import resource
from pathlib import Path

from ..core.errors import GofError

log = logging.getLogger("gof_warp.benchmarking")  # one logger for the harness

CHARTS = (("total_time_s", "chamfer", "chamfer_vs_time.png"), ("total_time_s", "fscore", "fscore_vs_time.png"),
          ("num_gaussians", "chamfer", "chamfer_vs_gaussians.png"), ("faces", "chamfer", "chamfer_vs_faces.png"),
          ("train_time_s", "test_psnr", "psnr_vs_train_time.png"), ("faces", "mesh_psnr", "mesh_psnr_vs_faces.png"))
Y_LABELS = {"chamfer": "Chamfer (lower is better)", "fscore": "F-score at τ (higher is better)",
            "test_psnr": "test PSNR, dB (higher is better)",
            "mesh_psnr": "vertex-coloured mesh, test PSNR, dB (higher is better)"}


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
    and torch's peak CUDA allocated and reserved memory, in MB (MiB)."""
    import torch

    host = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    try:
        line = next(x for x in Path("/proc/self/status").read_text().splitlines() if x.startswith("VmHWM:"))
        host = int(line.split()[1]) / 1024.0
    except (OSError, StopIteration, ValueError):
        pass
    cuda = torch.cuda.is_available()
    gpu = torch.cuda.max_memory_allocated() / 2**20 if cuda else None
    reserved = torch.cuda.max_memory_reserved() / 2**20 if cuda else None
    return {"host_peak_rss_mb": round(host, 1), "gpu_peak_allocated_mb": None if gpu is None else round(gpu, 1),
            "gpu_peak_reserved_mb": None if reserved is None else round(reserved, 1)}


FINITE = ("chamfer", "accuracy", "completeness")  # means that are infinite for an empty mesh


def _finite(x):
    return x if isinstance(x, (int, float)) and math.isfinite(x) else None


def scores(verts, faces, gt_path: Path, eval_samples: int | None) -> tuple[dict, dict]:
    """``(metrics, mesh_stats)`` of :func:`evaluate_mesh` (default τ; infinite means → None); metrics are
    ``{}`` without a GT mesh."""
    from ..eval.geometry_metrics import (
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
    return {k: _finite(v) if k in FINITE else v for k, v in ev["metrics"].items()}, ev["mesh_stats"]


def row_key(row: dict) -> tuple:
    """``(run, iteration, method)``; rows written before snapshots existed have only ``iterations``."""
    return row["run"], row.get("iteration", row.get("iterations")), row["method"]


def load_rows(out: Path) -> list[dict]:
    """The rows of ``out/results.json`` ([] when there is none yet)."""
    path = Path(out) / "results.json"
    if not path.is_file():
        return []
    try:
        return list(json.loads(path.read_text())["rows"])
    except (ValueError, KeyError, TypeError) as e:
        raise GofError(f"{path} is not a results table ({e}); move it away or choose another --out") from None


def write_table(out: Path, suite_name: str, rows: list[dict], machine: dict) -> None:
    """``results.json`` (rows + the current machine) and ``results.csv`` (the rows; each names its machine in
    its ``machine_*`` columns, so a table continued elsewhere stays honest), atomically."""
    from ..core.io_utils import write_json_atomic, write_text_atomic

    write_json_atomic(out / "results.json", {"suite": suite_name, "machine": machine, "rows": rows})
    columns = list(dict.fromkeys(k for r in rows for k in r))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    w.writerows(rows)
    write_text_atomic(out / "results.csv", buf.getvalue())


def point_label(row: dict) -> str:
    """The training variant of a row: its run name without the scene (``7k_noreg``), ``@k`` for a snapshot."""
    label = row["run"].removeprefix("real_").removeprefix(f"{row['scene'].removeprefix('real:')}_")
    return f"{label}@{row['iteration']}" if row.get("snapshot") else label


def write_charts(out: Path, rows: list[dict]) -> list[Path]:
    """The scatter charts of :data:`CHARTS` (colour = method, marker = scene; the PSNR chart has one point per
    model, since every method of a model has the same PSNR); [] without matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log.warning("matplotlib is not installed (pip install 'gof_warp[plots]'): charts skipped, results written")
        return []
    from ..core.io_utils import atomic_path

    scenes = sorted({r["scene"] for r in rows})
    markers = "osD^vP*Xh<>"
    one_per_model = list({(r["run"], r.get("iteration")): {**r, "method": "(every method)"} for r in rows}.values())
    written = []
    for xkey, ykey, name in CHARTS:
        chart_rows = one_per_model if ykey == "test_psnr" else rows
        methods = sorted({r["method"] for r in chart_rows})
        colours = plt.get_cmap("tab10" if len(methods) <= 10 else "tab20")
        fig, ax = plt.subplots(figsize=(7, 5))
        for i, meth in enumerate(methods):
            for j, sc in enumerate(scenes):
                pts = [r for r in chart_rows if r["method"] == meth and r["scene"] == sc
                       and r.get(xkey) is not None and r.get(ykey) is not None]
                if not pts:
                    continue
                x, y = [r[xkey] for r in pts], [r[ykey] for r in pts]
                ax.scatter(x, y, color=colours(i % colours.N), marker=markers[j % len(markers)],
                           label=f"{meth} / {sc}", s=36, alpha=0.85)
                for xi, yi, r in zip(x, y, pts):
                    ax.annotate(point_label(r), (xi, yi), fontsize=5, alpha=0.6, xytext=(3, 3),
                                textcoords="offset points")
        ax.set_xlabel(xkey.replace("_", " "))
        ax.set_ylabel(Y_LABELS[ykey])
        if all((r.get(xkey) or 0) > 0 for r in chart_rows):
            ax.set_xscale("log")
        ax.grid(alpha=0.3)
        if ax.collections:
            ax.legend(fontsize=6, ncol=2, loc="best")
        per = "(run, iteration)" if ykey == "test_psnr" else "(run, iteration, method)"
        ax.set_title(f"{ykey} vs {xkey.replace('_', ' ')}: one point per {per}")
        fig.tight_layout()
        with atomic_path(out / name) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
        plt.close(fig)
        written.append(out / name)
    return written
