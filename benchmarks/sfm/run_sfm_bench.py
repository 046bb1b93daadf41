"""Measure ``triangulate_known_poses`` on the real scenes in ../shared/data (CPU).

Usage::

    python benchmarks/sfm/run_sfm_bench.py --scene dtu_scan24 --out /tmp/sfm_bench/dtu.json [--matching pose]

Writes one JSON record: the stats of the run plus where the points lie (background vs object):
``outside_unit_sphere`` (DTU: the object is inside the unit sphere after scale_mat normalisation),
``outside_masks`` (points whose projection is outside the object mask in most views that see them;
DTU masks, NeRF alpha), ``outside_focus_box`` (outside the trainer's default random-init box).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from gof_warp.data import DataConfig, load_scene
from gof_warp.data.sfm import SfmConfig, triangulate_known_poses

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def focus_box(cams) -> np.ndarray:
    """Same box as ``trainer.default_init_box`` (recomputed here to keep the benchmark stand-alone)."""
    centres = np.stack([c.center for c in cams])
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in cams:
        P = np.eye(3) - np.outer(c.R[2], c.R[2])
        A += P
        b += P @ c.center
    focus = np.linalg.lstsq(A, b, rcond=None)[0]
    half = 0.5 * float(np.mean(np.linalg.norm(centres - focus, axis=1)))
    return np.concatenate([focus - half, focus + half])


def outside_masks(points, views) -> float | None:
    masked = [v for v in views if v.mask is not None]
    if not masked:
        return None
    inside = np.zeros(len(points))
    seen = np.zeros(len(points))
    for v in masked:
        c = v.camera
        uv, z = c.project(points)
        ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < c.width) & (uv[:, 1] >= 0) & (uv[:, 1] < c.height)
        ij = np.floor(uv[ok]).astype(int)
        seen[ok] += 1
        inside[np.flatnonzero(ok)] += v.mask[ij[:, 1], ij[:, 0]] > 0
    frac_in = np.where(seen > 0, inside / np.maximum(seen, 1), 0)
    return float(np.mean(frac_in < 0.5))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--downscale", type=float, default=1.0)
    ap.add_argument("--config", default="{}", help="JSON dict of SfmConfig fields")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    t = time.perf_counter()
    scene = load_scene(DATA / args.scene, DataConfig(test_every=0, downscale=args.downscale), device="cpu")
    load_s = time.perf_counter() - t
    cfg = SfmConfig(**json.loads(args.config))
    with tempfile.TemporaryDirectory(prefix="sfm_bench_") as cache:  # never cache into ../shared
        r = triangulate_known_poses(scene.train, cfg, cache_dir=Path(cache))
    p = r.points
    box = focus_box(scene.train_cameras)
    rec = {
        "scene": args.scene,
        "format": scene.format,
        "resolution": sorted({f"{v.camera.width}x{v.camera.height}" for v in scene.train}),
        "config": dataclasses.asdict(cfg),
        "load_seconds": round(load_s, 2),
        **r.stats,
        "outside_focus_box": round(float(np.mean(np.any((p < box[:3]) | (p > box[3:]), axis=1))), 4),
        "outside_masks": None if (f := outside_masks(p, scene.train)) is None else round(f, 4),
        "machine": f"2-core CPU dev box, no GPU ({platform.processor() or platform.machine()})",
    }
    if scene.format == "dtu":
        rec["outside_unit_sphere"] = round(float(np.mean(np.linalg.norm(p, axis=1) > 1.0)), 4)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(rec, indent=2) + "\n")
    print(json.dumps(rec, indent=2))


if __name__ == "__main__":
    main()
