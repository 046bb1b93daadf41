"""End-to-end mesh extraction benchmark, per stage: ``gof_warp.cli.extract.extract_mesh`` for each method
and point-reduction setting, with wall time, host/GPU peak memory and counts per stage (issue 5).

Gaussians: a 3DGS-layout PLY (``--ply``; cameras from ``--cameras cameras.json``, e.g. a run folder's,
or a ring), or ``--gaussians N ...`` synthesised from ``../shared/data/gaussians_54k.npz`` (random
subset, or copies jittered by one σ beyond 54k; synthetic opacities uniform in [0.05, 1]; see
``bench_marching.load_gaussians``) with a ring of ``--views`` cameras looking at the scene's centre.

    python benchmarks/extract/bench_extract.py --gaussians 100000 1000000 --methods tetra tsdf \
        --reductions none grid=delaunay grid=delaunay,opacity_min=0.1,corner_frac=0.002 --device cuda \
        --machine "1x H200" --out benchmarks/extract/results_extract_h200.json

A reduction is ``none`` or comma-separated ``key=value`` with keys ``opacity_min``,
``corner_min_extent`` (world units), ``corner_frac`` (``corner_min_extent`` as a fraction of the
diagonal of the Gaussians' robust box), ``workers`` (``TetraConfig.delaunay_workers``: Delaunay in
chunks on that many workers, 0 = every CPU), ``processes`` (1: the chunks in forked processes, the default;
0: in threads), ``grid`` (``delaunay`` or ``octree``) and ``cell_factor`` (the octree's) — the last four are not
reductions, but set per run the same way. ``none`` is the default grid (``auto``: the octree, or the Delaunay grid for a
small model); the Delaunay-point settings (``corner_*``, ``workers``,
``processes``) need ``grid=delaunay`` first. Reductions apply to ``tetra`` only; ``cubes``/``tsdf`` run once.
Memory per stage: ``host_peak_rss_mb`` (process maximum so far, from ``extract.StageTimer``),
``peak_rss_above_start_mb`` (sampled every 5 ms), ``peak_tree_pss_mb`` (PSS of the process and its forked
workers, sampled every 50 ms: the memory the stage really holds), ``gpu_peak_allocated_mb`` (torch), and
``warp_mempool_high_mb`` (Warp's CUDA mempool high-water mark so far; Warp has no reset).
"""

from __future__ import annotations

import argparse
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_marching import DEFAULT_DATA, Stage, load_gaussians, machine_info

from gof_warp.core.camera import look_at
from gof_warp.cli.extract import MeshConfig, StageTimer, cameras_from_json, extract_mesh
from gof_warp.core.io_utils import write_json_atomic
from gof_warp.core.model import Gaussians
from gof_warp.mesh.tetra import TetraConfig
from gof_warp.mesh.tsdf import gaussian_bounds


def scene_diagonal(gaussians) -> float:
    """Diagonal of the robust box of the Gaussians (as the TSDF/cubes bounds use, unpadded)."""
    box = gaussian_bounds(gaussians.means.detach().cpu().numpy(), 0.5, 0.0)
    return float(np.linalg.norm(box[3:] - box[:3]))


REDUCTION_KEYS = ("opacity_min", "corner_min_extent", "corner_frac", "workers", "processes", "grid", "cell_factor")


class BenchTimer(StageTimer):
    """``StageTimer`` (time, host and GPU peaks) plus the sampled RSS peak above each stage's start and the peak PSS
    of the process tree (the Delaunay's forked workers included)."""

    def __init__(self, device: str):
        super().__init__(device)
        self.device_name = device

    @contextmanager
    def __call__(self, name: str):
        extra: dict = {}
        with Stage(extra, name, self.device_name), super().__call__(name):
            yield
        for key in ("peak_rss_above_start_mb", "peak_tree_pss_mb"):
            self.stages[name][key] = extra[name][key]


def parse_reduction(spec: str, diagonal: float) -> TetraConfig:
    """``none`` | ``key=value[,key=value]`` (see the module docstring) → a ``TetraConfig``."""
    cfg = TetraConfig()
    if spec == "none":
        return cfg
    for item in spec.split(","):
        key, _, value = item.partition("=")
        if key not in REDUCTION_KEYS or not value:
            raise SystemExit(f"bad reduction {spec!r}: use none or key=value with keys {REDUCTION_KEYS}")
        if key == "corner_frac":
            cfg.corner_min_extent = float(value) * diagonal
        elif key == "workers":  # Delaunay workers (0: every CPU)
            cfg.delaunay_workers = int(value)
        elif key == "processes":  # 1: the chunks in forked processes (default), 0: in threads
            cfg.delaunay_processes = bool(int(value))
        elif key == "grid":  # delaunay | octree
            cfg.grid = value
        elif key == "cell_factor":  # the octree grid's leaf size per 3-sigma box width
            cfg.octree.cell_factor = float(value)
        else:
            setattr(cfg, key, float(value))
    return cfg


def ring_cameras(means: np.ndarray, views: int, width: int, height: int):
    """``views`` cameras on a circle 30° above the robust box's centre, all looking at it."""
    box = gaussian_bounds(means, 0.5, 0.0)
    centre, radius = 0.5 * (box[:3] + box[3:]), 0.75 * float(np.linalg.norm(box[3:] - box[:3]))
    cams = []
    for k in range(views):
        a = 2 * np.pi * k / views
        eye = centre + radius * np.array([np.cos(a) * np.cos(np.pi / 6), np.sin(a) * np.cos(np.pi / 6), np.sin(np.pi / 6)])
        cams.append(look_at(eye, centre, fx=0.8 * width, width=width, height=height, name=f"ring{k:03d}"))
    return cams


def synthetic_model(n: int, data: Path, device: str):
    means, quats, scales, opacities, source = load_gaussians(n, data=data)
    colours = np.full((n, 3), 0.5, np.float32)
    return Gaussians.from_activated(means, quats, scales, opacities, colours, device=device), source


def bench_model(gaussians, cameras, methods, reductions, args) -> list[dict]:
    diag = scene_diagonal(gaussians)
    runs = []
    for method in methods:
        for spec in (reductions if method == "tetra" else ["none"]):
            tetra = parse_reduction(spec, diag)
            tetra.backend = args.delaunay
            cfg = MeshConfig(method=method, binary_steps=args.binary_steps, cubes_resolution=args.resolution,
                             tetra=tetra)
            cfg.tsdf.resolution = args.resolution
            timer = BenchTimer(args.device)
            t0 = time.perf_counter()
            (verts, faces), = extract_mesh(gaussians, cameras, cfg, timer=timer)
            total = time.perf_counter() - t0
            runs.append({"method": method, "reduction": spec, "corner_min_extent": tetra.corner_min_extent,
                         "opacity_min": tetra.opacity_min, "total_time_s": round(total, 3),
                         "vertices": len(verts), "faces": len(faces), "stages": timer.stages})
            print(f"{len(gaussians)} Gaussians, {method} [{spec}]: {total:.2f} s, {len(verts)} vertices, "
                  f"{len(faces)} faces; {timer.stages.get('counts', '')}", flush=True)
    return runs


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--ply", type=Path, help="Gaussian PLY in the 3DGS layout")
    src.add_argument("--gaussians", type=int, nargs="+", help="synthesise these many Gaussians from the 54k scene")
    ap.add_argument("--cameras", type=Path, default=None, help="cameras.json of a run (default: a ring)")
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA)
    ap.add_argument("--views", type=int, default=48)
    ap.add_argument("--width", type=int, default=800)
    ap.add_argument("--height", type=int, default=600)
    ap.add_argument("--methods", nargs="+", default=["tetra"], choices=["tetra", "cubes", "tsdf"])
    ap.add_argument("--reductions", nargs="+", default=["none"])
    ap.add_argument("--delaunay", default="scipy", choices=("scipy", "cgal", "auto"))
    ap.add_argument("--binary-steps", type=int, default=8)
    ap.add_argument("--resolution", type=int, default=512, help="cubes/tsdf grid resolution")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--machine", default="")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    wp.init()
    results = {"machine": machine_info(a.machine, a.device), "args": {k: str(v) for k, v in vars(a).items()},
               "models": []}
    models = [a.ply] if a.ply else a.gaussians
    for m in models:
        if a.ply:
            gaussians, source = Gaussians.load_ply(m, device=a.device), str(m)
        else:
            gaussians, source = synthetic_model(m, a.data, a.device)
        cams = cameras_from_json(a.cameras) if a.cameras else ring_cameras(
            gaussians.means.detach().cpu().numpy(), a.views, a.width, a.height)
        runs = bench_model(gaussians, cams, a.methods, a.reductions, a)
        results["models"].append({"num_gaussians": len(gaussians), "source": source, "num_views": len(cams),
                                  "runs": runs})
        write_json_atomic(a.out, results)  # after every model: a long run keeps what it has
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
