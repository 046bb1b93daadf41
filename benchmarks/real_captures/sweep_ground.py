"""Ablation sweep on a ground-and-background synthetic scene: which training choice makes the ground wavy or
missing? One GPU call: generate the scene, write pseudo-SfM points, train every variant concurrently with
GOF's schedule compressed to ``--iterations``, then probe the ground of each model's opacity field
(:mod:`ground_probe`) and collect test PSNR and the loss-spike report into one JSON.

    python benchmarks/real_captures/sweep_ground.py --out $OUT/sweep --iterations 10000 --resolution 256

Pseudo-SfM points: ``--sfm-points`` points sampled on the GT surfaces that some train camera sees (depth
maps), with 2 mm noise, coloured from a view that sees them — a stand-in for triangulated points with a
known error, so the sweep isolates what training does with a given start.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))

BASE = ["model.init=sfm", "model.background_points=0"]
VARIANTS = {
    "random": ["model.init=random", "model.init_box=[-8,-8,-8,8,8,8]"],
    "sfm_official_bg": ["densify.prune_screen_size=false", "loss.normal_form=gof", "model.background_points=20000"],
    "sfm": [],
    "sfm_noscreen": ["densify.prune_screen_size=false"],
    "sfm_gofnormal": ["loss.normal_form=gof"],
    "sfm_official": ["densify.prune_screen_size=false", "loss.normal_form=gof"],
    "sfm_official_noreg": ["densify.prune_screen_size=false", "loss.normal_form=gof", "loss.lambda_distortion=0",
                           "loss.lambda_normal=0"],
}


def flatten(d: dict, prefix: str = "") -> list[str]:
    out = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        out += flatten(v, key + ".") if isinstance(v, dict) else [f"{key}={json.dumps(v)}"]
    return out


def pseudo_sfm(scene_dir: Path, n: int, seed: int = 0) -> None:
    """Write ``points3d.ply``: ``n`` visible GT-surface points with 2 mm noise, coloured from the photos."""
    import trimesh

    from ground_probe import unoccluded_views

    from gof_warp.data import DataConfig, load_scene

    rng = np.random.default_rng(seed)
    gt = trimesh.load(scene_dir / "gt_mesh.ply", process=False)
    pts, _ = trimesh.sample.sample_surface(gt, 20 * n, seed=seed)
    scene = load_scene(scene_dir, DataConfig())
    seen = np.zeros(len(pts), int)
    colour = np.zeros((len(pts), 3))
    for v, idx, ij in unoccluded_views(scene_dir, scene, pts):
        colour[idx] = v.image[ij[:, 1], ij[:, 0]]
        seen[idx] += 1
    cand = np.where(seen >= 2)[0]
    pick = rng.choice(cand, size=min(n, len(cand)), replace=False)
    p = pts[pick] + rng.normal(0.0, 0.002, (len(pick), 3))
    trimesh.PointCloud(p, colors=np.concatenate([colour[pick], np.full((len(pick), 1), 255)], 1).astype(np.uint8)).export(
        scene_dir / "points3d.ply")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--preset", default="garden")
    ap.add_argument("--resolution", type=int, nargs=2, default=[256, 192])
    ap.add_argument("--views", type=int, default=100)
    ap.add_argument("--iterations", type=int, default=10000)
    ap.add_argument("--sfm-points", type=int, default=1500)
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--spacing", type=float, default=0.025, help="ground probe column spacing (m)")
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--time-limit", type=float, default=100.0, help="seconds of training per variant")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    from gof_warp.bench import gof_schedule
    from gof_warp.synthetic import make_scene

    t0 = time.time()
    scene_dir = out / "scene"
    if not (scene_dir / "transforms_train.json").is_file():
        make_scene(a.preset, scene_dir, views=a.views, resolution=tuple(a.resolution), force=True)
        pseudo_sfm(scene_dir, a.sfm_points)
    print(f"scene ready {time.time() - t0:.0f} s", flush=True)
    sched = flatten(gof_schedule(a.iterations))
    names = a.variants.split(",")
    # warm Warp's kernel cache once (concurrent first compiles would race)
    subprocess.run([sys.executable, "-m", "gof_warp.train", str(scene_dir), "--out", str(out / "_warm"), "--config",
                    "unbounded", "--iterations", "20", "--quiet", "--device", a.device, *BASE, "checkpoint_every=0"], check=True)
    print(f"warm {time.time() - t0:.0f} s", flush=True)
    for n in names:  # one at a time: processes sharing a GPU time-slice and crawl
        cmd = [sys.executable, "-m", "gof_warp.train", str(scene_dir), "--out", str(out / n), "--config", "unbounded",
               "--device", a.device, *sched, *BASE, *VARIANTS[n]]
        with open(out / f"{n}.log", "w") as log:
            p = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
            try:
                p.wait(timeout=a.time_limit)
            except subprocess.TimeoutExpired:
                p.kill()
                print(f"{n}: killed at the time limit", flush=True)
        print(f"{n} trained {time.time() - t0:.0f} s", flush=True)
    from ground_probe import probe, seen_ground_columns, summarise

    from gof_warp.extract import load_run

    ground_z = float(json.loads((scene_dir / "scene.json").read_text())["ground"]["height"])
    xy, _ = seen_ground_columns(scene_dir, ground_z=ground_z, half=2.4, spacing=a.spacing)
    table = {}
    for n in names:
        run = out / n
        row = {"variant": n, "overrides": VARIANTS[n]}
        if (run / "metrics.json").is_file():
            m = json.loads((run / "metrics.json").read_text())
            row.update(test_psnr=m["test"].get("psnr"), gaussians=m["num_gaussians"], train_s=m["train_time_s"],
                       loss_spikes=m.get("loss_spikes"), init=m.get("init"))
            g, cams, _, rc = load_run(run, None, a.device)
            h = probe(g, cams, xy, ground_z, render_config=rc)
            row["ground"] = summarise(xy, h)
            np.save(out / f"{n}_ground_h.npy", h.astype(np.float32))
        table[n] = row
        print(json.dumps(row), flush=True)
    (out / "sweep.json").write_text(json.dumps({"iterations": a.iterations, "resolution": a.resolution,
                                                "views": a.views, "preset": a.preset, "rows": table}, indent=1))
    np.save(out / "ground_xy.npy", xy.astype(np.float32))
    print(f"done {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
