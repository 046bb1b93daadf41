"""Benchmark of the tetrahedral-grid extraction stages: points, Delaunay (per backend), cell filter,
marching tetrahedra + binary search.

Gaussians come from ``../shared/data/gaussians_54k.npz`` (a real trained scene, geometry only),
subsampled or replicated with jitter to each requested size; opacities are synthetic. The field is a
stand-in for GOF's opacity field (``1 - Π (1 - α_k G_k(x))`` over the 8 nearest Gaussians, via a KD-tree);
its time is reported separately and subtracted from the marching stage.

    python benchmarks/extract/bench_marching.py --gaussians 10000 100000 --backends scipy cgal \
        --device cpu --machine "2-core CPU dev box" --out benchmarks/extract/results_cpu.json

Per stage: wall time (s), peak resident memory above the stage's start (MB, sampled every 5 ms), and on
CUDA the peak torch allocation and Warp's mempool high-water mark.
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import json
import os
import platform
import sys
import threading
import time
from pathlib import Path

import numpy as np
import scipy
import torch
import warp as wp
from scipy.spatial import cKDTree

from gof_warp.core.io_utils import write_json_atomic
from gof_warp.mesh.marching import marching_tetrahedra
from gof_warp.core.model import quat_to_rotmat as quat_to_rotation
from gof_warp.mesh.tetra import delaunay, filter_cells, tetra_points

DEFAULT_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "gaussians_54k.npz"
KNN = 8  # Gaussians per field evaluation in the stand-in field


def _release_freed_memory() -> None:
    """Return freed heap pages to the OS (glibc), so a stage's RSS above its start is its own peak."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _descendants(pid: int) -> list[int]:
    """Process ids of ``pid``'s children, their children, ... (Linux ``/proc``)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                kids = [int(c) for c in (task / "children").read_text().split()]
            except OSError:
                continue
            out += kids
            todo += kids
    return out


def _tree_pss_bytes() -> int:
    """Proportional set size of this process and its descendants (forked workers share the parent's pages: PSS
    counts each shared page once over the tree, where summing RSS would count it in every process)."""
    total = 0
    for pid in [os.getpid(), *_descendants(os.getpid())]:
        try:
            for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
                if line.startswith("Pss:"):
                    total += int(line.split()[1]) * 1024
                    break
        except OSError:  # the worker ended between the listing and the read
            continue
    return total


class Stage:
    """Context manager timing one stage and sampling its peak RSS, the peak PSS of the process tree (forked
    workers included) and CUDA memory."""

    def __init__(self, results: dict, name: str, device: str):
        self.results, self.name, self.device = results, name, device

    def _sample(self):
        k = 0
        while not self._stop.is_set():
            self.peak = max(self.peak, _rss_bytes())
            if k % 10 == 0:  # every 50 ms: reading smaps_rollup of a large tree costs ~ms
                self.tree_peak = max(self.tree_peak, _tree_pss_bytes())
            k += 1
            time.sleep(0.005)

    def __enter__(self):
        gc.collect()
        _release_freed_memory()
        self.start_rss = self.peak = _rss_bytes()
        self.tree_peak = _tree_pss_bytes()
        if self.device.startswith("cuda"):
            torch.cuda.reset_peak_memory_stats()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        if self.device.startswith("cuda"):
            wp.synchronize_device(self.device)
        dt = time.perf_counter() - self.t0
        self._stop.set()
        self._thread.join()
        rec = {"time_s": round(dt, 4), "peak_rss_above_start_mb": round((self.peak - self.start_rss) / 2**20, 1),
               "peak_rss_mb": round(self.peak / 2**20, 1), "peak_tree_pss_mb": round(self.tree_peak / 2**20, 1)}
        if self.device.startswith("cuda"):
            rec["cuda_torch_peak_mb"] = round(torch.cuda.max_memory_allocated() / 2**20, 1)
            rec["cuda_warp_mempool_high_mb"] = round(wp.get_mempool_used_mem_high(self.device) / 2**20, 1)
        self.results[self.name] = rec
        print(f"  {self.name}: {rec}", file=sys.stderr, flush=True)


def load_gaussians(n: int, seed: int = 0, data: Path = DEFAULT_DATA):
    """``n`` Gaussians from the 54k scene (random subset, or copies jittered by one σ beyond 54k);
    a synthetic noisy sphere shell when ``data`` is absent. Returns the arrays and the source's name."""
    rng = np.random.default_rng(seed)
    if data.is_file():
        d = np.load(data)
        means, quats, scales = d["means"], d["quats"], d["scales"]
        source = data.name
    else:  # synthetic fallback: a noisy sphere shell
        source = "synthetic sphere shell"
        m = 54275
        v = rng.normal(size=(m, 3))
        means = (v / np.linalg.norm(v, axis=1, keepdims=True) * rng.uniform(0.95, 1.05, (m, 1))).astype(np.float32)
        quats, scales = rng.normal(size=(m, 4)).astype(np.float32), rng.uniform(0.002, 0.02, (m, 3)).astype(np.float32)
    m = len(means)
    idx = rng.permutation(m)[:n] if n <= m else rng.integers(0, m, n)
    means, quats, scales = means[idx].copy(), quats[idx], scales[idx]
    if n > m:  # copies: jitter by about one σ so that no two points coincide
        means += rng.normal(size=means.shape).astype(np.float32) * scales
    opacities = rng.uniform(0.05, 1.0, n).astype(np.float32)
    return means, quats, scales, opacities, source


def make_field(means, quats, scales, opacities, timer: dict):
    """Stand-in opacity field: ``1 - Π_k (1 - α_k exp(-½ |S⁻¹ Rᵀ (x - μ_k)|²))`` over the KNN nearest Gaussians."""
    tree = cKDTree(means)
    rot_t = quat_to_rotation(torch.as_tensor(quats, dtype=torch.float64)).transpose(1, 2).numpy()
    inv_s = 1.0 / scales.astype(np.float64)

    def field(x):
        t0 = time.perf_counter()
        x = np.asarray(x, np.float64)
        _, nn = tree.query(x, k=KNN, workers=-1)
        local = np.einsum("mkij,mkj->mki", rot_t[nn], x[:, None, :] - means[nn]) * inv_s[nn]
        g = opacities[nn] * np.exp(-0.5 * (local**2).sum(-1))
        out = 1.0 - np.prod(1.0 - np.minimum(g, 0.99), axis=1)
        timer["field_s"] = timer.get("field_s", 0.0) + time.perf_counter() - t0
        timer["field_points"] = timer.get("field_points", 0) + x.shape[0]
        return out.astype(np.float32)

    return field


def machine_info(label: str, device: str) -> dict:
    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu)
    except OSError:
        pass
    info = {"label": label, "platform": platform.platform(), "cpu": cpu, "cpu_count": os.cpu_count(),
            "python": sys.version.split()[0], "numpy": np.__version__, "scipy": scipy.__version__,
            "warp": wp.__version__, "torch": torch.__version__, "device": device}
    if device.startswith("cuda"):
        info["gpu"] = wp.get_device(device).name
    try:
        import CGAL  # noqa: F401

        from importlib.metadata import version

        info["cgal"] = version("cgal")
    except ImportError:
        info["cgal"] = None
    return info


def run_size(n: int, backends: list[str], device: str, binary_steps: int, point_options: dict, data: Path) -> dict:
    means, quats, scales, opacities, source = load_gaussians(n, data=data)
    res: dict = {"n_gaussians": n, "data": source, "point_options": point_options, "stages": {}}
    st = res["stages"]
    with Stage(st, "tetra_points", device):
        points, owner, pscale = tetra_points(means, quats, scales, opacities, **point_options)
    res["n_points"] = int(points.shape[0])
    tets = None
    for backend in backends:
        with Stage(st, f"delaunay_{backend}", device):
            tets_b = delaunay(points, backend)
        res[f"n_tets_{backend}"] = int(tets_b.shape[0])
        tets = tets_b if tets is None else tets
    with Stage(st, "filter_cells", device):
        tets_f = filter_cells(tets, points, owner, pscale)
    res["n_tets_filtered"] = int(tets_f.shape[0])
    timer: dict = {}
    field = make_field(means, quats, scales, opacities, timer)
    with Stage(st, "field_at_points", device):
        values = field(points)
    for steps in (0, binary_steps):
        timer.clear()
        with Stage(st, f"marching_steps{steps}", device):
            (v, f), = marching_tetrahedra(points, tets_f, values, field, binary_steps=steps, device=device)
        st[f"marching_steps{steps}"]["field_time_s"] = round(timer.get("field_s", 0.0), 4)
        st[f"marching_steps{steps}"]["time_without_field_s"] = round(
            st[f"marching_steps{steps}"]["time_s"] - timer.get("field_s", 0.0), 4)
    res["n_vertices"], res["n_faces"] = int(v.shape[0]), int(f.shape[0])
    return res


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--gaussians", type=int, nargs="+", default=[10000])
    ap.add_argument("--backends", nargs="+", default=["scipy"], choices=["scipy", "cgal"])
    ap.add_argument("--device", default=None)
    ap.add_argument("--binary-steps", type=int, default=8)
    ap.add_argument("--opacity-min", type=float, default=None, help="tetra_points option (off by default)")
    ap.add_argument("--corner-min-extent", type=float, default=None, help="tetra_points option (off by default)")
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="npz with means, quats, scales")
    ap.add_argument("--machine", default="unnamed machine")
    ap.add_argument("--out", default="bench_marching.json")
    args = ap.parse_args(argv)
    device = args.device or ("cuda" if wp.get_cuda_device_count() > 0 else "cpu")
    wp.init()
    # Compile the kernels once before timing.
    tiny = np.random.default_rng(0).uniform(size=(16, 3)).astype(np.float32)
    marching_tetrahedra(tiny, delaunay(tiny), tiny[:, 0], lambda x: np.asarray(x)[:, 0], binary_steps=1,
                        device=device)
    out = {"machine": machine_info(args.machine, device), "binary_steps": args.binary_steps, "runs": []}
    for n in args.gaussians:
        opts = {"opacity_min": args.opacity_min, "corner_min_extent": args.corner_min_extent}
        out["runs"].append(run_size(n, args.backends, device, args.binary_steps, opts, args.data))
        print(json.dumps(out["runs"][-1]), flush=True)
        write_json_atomic(args.out, out)


if __name__ == "__main__":
    main()
