"""Resumable job queue for the real-captures GPU runs, cut to fit 10-minute device calls.

Each call runs ``python3 benchmarks/real_captures/gpu_queue.py --budget 540`` on the (warm) GPU machine: steps
already done (a marker in ``--state``) are skipped, training resumes from its newest checkpoint, a step
that would start with too little time left waits for the next call, and a training step still running
at the budget is stopped (its checkpoints stay). Results land in ``--state/results`` and are packed into
``$OUT/results.tar.gz`` at the end of every call. Several queues (one ``--state`` each) can share one GPU:
``queue_parallel.sh``.

Scenes: ``garden``, ``background``, ``background_detail`` and ``background_full`` (synthetic, exact GT: train with the preset ``train``
picks, extract, score the seen region and a ground-and-objects crop, probe the ground of the field) and ``dtu``, ``can``,
``fox`` (carried in ``.data/`` or parked in ``/tmp/gofdata``: train with the picked preset, extract, pictures). The GPU machine has no pycolmap: with
``--points DIR`` a synthetic scene gets ``DIR/<scene>/points3d.ply`` (points triangulated from the known poses of the
same scene generated on another machine) after it is generated.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

PY = sys.executable
HERE = Path(__file__).resolve().parent


REAL = {"dtu": "dtu_scan24", "can": "colmap_can", "fox": "fox"}
SYNTHETIC_VIEWS = 100  # the ground-and-background protocol (100 views); session 18 lost a run to the preset's 40
STOP_GRACE_S = 45.0  # a step still running this long before the budget is interrupted, so the call ends by then
# the ground-and-objects crop of each synthetic scene (x0 y0 z0 x1 y1 z1): its ground under and around the objects
CROPS = {"garden": (-2.5, -2.5, -0.5, 2.5, 2.5, 1.5), "background": (-2.0, -2.0, -1.1, 2.0, 2.0, 1.0),
         "background_detail": (-2.0, -2.0, -1.1, 2.0, 2.0, 1.0), "background_full": (-2.0, -2.0, -1.1, 2.0, 2.0, 1.0)}


def steps(state: Path, scenes: list[str], resolution: tuple[int, int], iterations: int, views: int | None = None,
          points: Path | None = None, min_views: int = 0, overrides: tuple[str, ...] = (), pack: bool = False):
    """``[(name, command, min_seconds_left, is_training)]`` in order; a scene ``NAME:N`` trains N iterations.

    ``min_views`` K > 1 adds a second extraction with ``--min-views K`` (``RUN/mesh_views<K>.ply``, pictures for
    every scene) and, for the synthetic scenes, its two scores beside the default mesh's. ``pack`` brings every
    scene's trained geometry back (``../extract/pack_model.py``; DTU's always comes back)."""
    out = []
    iters = {s.split(":")[0]: int(s.split(":")[1]) for s in scenes if ":" in s}
    scenes = [s.split(":")[0] for s in scenes]
    for s in scenes:
        run = state / f"run_{s}"
        res = state / "results" / s
        if s in CROPS:
            scene = state / s
            out.append((f"{s}:generate", [PY, "-m", "gof_warp.synthetic", "--preset", s, "--out", str(scene),
                                          "--resolution", str(resolution[0]), str(resolution[1]), "--force"]
                        + (["--views", str(views)] if views else []), 60, False))
            if points is not None:
                out.append((f"{s}:points", ["cp", str(points / s / "points3d.ply"), str(scene)], 10, False))
        else:  # a real scene carried in .data/ or .data2/ (the device call's 64 MiB limit splits them)
            scene = state / s
            src = REAL[s]
            out.append((f"{s}:copy", ["sh", "-c", f"cp -r $(ls -d .data/{src} .data2/{src} /tmp/gofdata/{src} 2>/dev/null "
                                                 f"| head -1) {scene}"], 10, False))
        out.append((f"{s}:train", [PY, "-m", "gof_warp.train", str(scene), "--out", str(run), "--iterations",
                                   str(iters.get(s, iterations)), "checkpoint_every=1000", *overrides, "--resume"], 120,
                    True))
        if s == "dtu" or pack:  # the trained geometry comes back (DTU's for the extraction benchmarks)
            out.append((f"{s}:pack", [PY, str(HERE.parent / "extract" / "pack_model.py"), "pack", str(run),
                                      str(state / "big" / f"{s}_geometry.npz")], 30, False))
        out.append((f"{s}:extract", [PY, "-m", "gof_warp.extract", str(run), "--delaunay-workers", "0"], 240, False))
        meshes = [("", run / "mesh_tetra.ply")]
        if min_views > 1:
            meshes.append((f"_views{min_views}", run / f"mesh_views{min_views}.ply"))
        for tag, mesh in meshes:  # the default mesh scored before the second one is extracted
            if tag:
                out.append((f"{s}:extract{tag}", [PY, "-m", "gof_warp.extract", str(run), "--min-views",
                                                  str(min_views), "--out", str(mesh)], 240, False))
            if s in CROPS:
                evaluate = [PY, "-m", "gof_warp.evaluate", "--mesh", str(mesh), "--gt", str(scene / "gt_mesh.ply"),
                            "--scene", str(scene)]
                out.append((f"{s}:evaluate{tag}", evaluate + ["--json", str(res / f"evaluate_seen{tag}.json")], 120,
                            False))
                out.append((f"{s}:evaluate_crop{tag}", evaluate + ["--crop", *map(str, CROPS[s]), "--json",
                                                                   str(res / f"evaluate_crop{tag}.json")], 120, False))
        if s in CROPS:
            out.append((f"{s}:gt_pictures", [PY, "-m", "gof_warp.pictures", str(run), "--mesh",
                                             str(scene / "gt_mesh.ply")], 60, False))
            out.append((f"{s}:probe", [PY, str(HERE / "probe_run.py"), str(scene), str(run),
                                       str(res / "ground_probe.json")], 60, False))
    return out


def collect(state: Path, scenes: list[str]) -> None:
    for s in scenes:
        run, res = state / f"run_{s}", state / "results" / s
        res.mkdir(parents=True, exist_ok=True)
        for name in ("metrics.json", "config.yaml", "mesh_tetra.json", "train.log", "extract.log",
                     *(p.name for p in run.glob("mesh_views*.json"))):
            if (run / name).is_file():
                shutil.copy(run / name, res / name)
        if (run / "pictures").is_dir():
            for p in (run / "pictures").glob("*.png"):
                shutil.copy(p, res / p.name)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--state", default="/tmp/rc")
    ap.add_argument("--budget", type=float, default=540.0)
    ap.add_argument("--scenes", default="garden,dtu,background")
    ap.add_argument("--resolution", type=int, nargs=2, default=[256, 192])
    ap.add_argument("--iterations", type=int, default=30000)
    ap.add_argument("--views", type=int, default=SYNTHETIC_VIEWS,
                    help="training views of the synthetic scenes (default %(default)s, the real-captures issue's protocol; "
                         "0: the preset's own, 40 for the background scenes)")
    ap.add_argument("--train-override", action="append", default=[], metavar="KEY=VALUE",
                    help="a config override for every training (repeatable), e.g. seed=1")
    ap.add_argument("--pack", action="store_true",
                    help="bring every scene's trained geometry back as <scene>_geometry[.partK].npz (DTU's always)")
    ap.add_argument("--min-views", type=int, default=0,
                    help="also extract with `extract --min-views K` (K > 1) and score that mesh beside the default")
    ap.add_argument("--points", type=Path, default=None,
                    help="folder with <scene>/points3d.ply for the synthetic scenes (the GPU machine has no pycolmap)")
    a = ap.parse_args()
    t_end = time.time() + a.budget
    state = Path(a.state)
    scenes = a.scenes.split(",")
    (state / "done").mkdir(parents=True, exist_ok=True)
    (state / "big").mkdir(parents=True, exist_ok=True)
    names = [s.split(":")[0] for s in scenes]
    for s in names:
        (state / "results" / s).mkdir(parents=True, exist_ok=True)
    for name, cmd, need, training in steps(state, scenes, tuple(a.resolution), a.iterations, a.views,
                                         a.points, a.min_views, tuple(a.train_override), a.pack):
        marker = state / "done" / name.replace(":", "_")
        if marker.exists():
            continue
        left = t_end - time.time()
        if left < need:
            print(f"[queue] {name}: {left:.0f} s left < {need} s: next call", flush=True)
            break
        scene = name.split(":")[0]
        log = state / f"run_{scene}" / f"{name.split(':')[1]}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        t0 = time.time()
        with open(log, "a") as f:
            p = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
            try:
                rc = p.wait(timeout=max(1.0, t_end - STOP_GRACE_S - time.time()))
            except subprocess.TimeoutExpired:
                p.send_signal(signal.SIGINT)  # a training checkpoints its current iteration and stops
                try:
                    p.wait(timeout=STOP_GRACE_S)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
                if p.returncode == 0:  # it finished before the interrupt took effect (130 when it stopped early)
                    marker.write_text("ok\n")
                    print(f"[queue] {name}: rc 0 in {time.time() - t0:.0f} s, at the budget", flush=True)
                else:
                    print(f"[queue] {name}: stopped at the budget after {time.time() - t0:.0f} s (resumes next call)",
                          flush=True)
                break
        print(f"[queue] {name}: rc {rc} in {time.time() - t0:.0f} s", flush=True)
        if rc != 0:  # no marker: the next call tries again
            print(open(log).read()[-3000:], flush=True)
            continue
        marker.write_text("ok\n")
    collect(state, names)
    out = os.environ.get("OUT")
    if out:
        with tarfile.open(Path(out) / "results.tar.gz", "w:gz") as tar:
            tar.add(state / "results", arcname="results")
        for big in (state / "big").glob("*.npz"):  # at most 16 MiB a file and 8 files a call come back
            shutil.copy(big, Path(out) / big.name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
