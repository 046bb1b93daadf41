"""Summary of a random-start comparison (``run_cpu.sh`` / ``run_gpu.sh``): per run, test PSNR (mean, worst view,
per view), Gaussians, training time, what the start pruned, and **floater cover**: per test view, the fraction of
pixels where the model renders an opaque surface (alpha ≥ 0.5) at less than ``COVER_FRACTION`` of the scene's true
depth there (the synthetic scenes' exact depth maps, ``SCENE/test/depth/*.npy``) — something between the camera and
the scene. Writes ``OUT/summary.json`` and ``OUT/test_views.png``: per test view, photo and each run's render, and
under them each run's median depth (brighter is nearer; one scale per view, from the true depth).

    python benchmarks/random_init/summarise.py OUT RUN [RUN ...]     (RUN: folder names under OUT)
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np
import torch

COVER_FRACTION = 0.5  # a pixel is covered by a floater when its rendered depth is below this fraction of the true one
COVERED = 0.01  # a test view counts as covered when floaters cover more than this fraction of it


def _true_depth(run: Path, name: str) -> np.ndarray | None:
    """The exact depth map of test view ``name`` (``test_r_000`` → ``SCENE/test/depth/r_000.npy``)."""
    from gof_warp.training.run_folder import read_run_config, scene_candidates

    cams = json.loads((run / "cameras.json").read_text())
    for base in scene_candidates(run, cams, read_run_config(run) or {}, None):
        f = Path(base) / "test" / "depth" / (name.removeprefix("test_") + ".npy")
        if f.is_file():
            return np.load(f).astype(np.float64)
    return None


def _renders(run: Path, device: str):
    """Per test view: ``(name, photo [H,W,3] uint8, render [H,W,3] float, median depth [H,W], alpha [H,W])``."""
    from gof_warp.rendering.render import render
    from gof_warp.training.run_folder import load_run
    from gof_warp.viz.pictures import run_views

    gaussians, _, _, config = load_run(run, None, device)
    cams, photos = run_views(run, "test", device)
    out = []
    with torch.no_grad():
        for cam, photo in zip(cams, photos):
            r = render(gaussians, cam, config=config)
            out.append((cam.name, np.asarray(photo), r["rgb"].clamp(0, 1).cpu().numpy(),
                        r["median_depth"].reshape(cam.height, cam.width).cpu().numpy().astype(np.float64),
                        r["alpha"].reshape(cam.height, cam.width).cpu().numpy().astype(np.float64)))
    return out


def floater_cover(depth: np.ndarray, alpha: np.ndarray, true_depth: np.ndarray) -> float:
    """Fraction of pixels with ``alpha ≥ 0.5`` and ``0 < depth < COVER_FRACTION × true depth``."""
    ok = np.isfinite(true_depth) & (true_depth > 0)
    near = (alpha >= 0.5) & (depth > 0) & (depth < COVER_FRACTION * np.where(ok, true_depth, np.inf))
    return float(near.mean())


def main(out: Path, names: list[str]) -> int:
    device = "cuda" if torch.cuda.is_available() else "cpu"
    rows, views = {}, {}
    for name in names:
        run = out / name
        m = json.loads((run / "metrics.json").read_text())
        per = [round(v["psnr"], 2) for v in m["test"]["per_image"]]
        renders = _renders(run, device)
        cover = []
        for view, photo, rgb, depth, alpha in renders:
            true = _true_depth(run, view)
            cover.append(None if true is None else round(floater_cover(depth, alpha, true), 4))
            views.setdefault(view, {"photo": photo, "true": true})[name] = (rgb, depth)
        known = [c for c in cover if c is not None]
        init = m.get("init", {})
        rows[name] = {"test_psnr": round(m["test"]["psnr"], 2), "worst_view_psnr": min(per), "per_view_psnr": per,
                      "floater_cover_per_view": cover,
                      "views_covered": None if not known else sum(c > COVERED for c in known),
                      "num_gaussians": m["num_gaussians"], "train_time_s": round(m["train_time_s"], 1),
                      "init": {k: init.get(k) for k in ("source", "points", "random_min_views")},
                      "unseen_pruned": m.get("unseen_pruned"), "device": m.get("device"),
                      "iterations": m.get("iterations")}
    machine = (f"1x {torch.cuda.get_device_name(0)}" if torch.cuda.is_available()
               else f"{os.cpu_count()}-core CPU ({platform.node()})")
    summary = {"machine": machine, "date": datetime.date.today().isoformat(),
               "floater_cover": f"per test view, the fraction of pixels rendered opaque (alpha >= 0.5) nearer than "
                                f"{COVER_FRACTION} x the exact depth; a view is covered above {COVERED}",
               "runs": rows}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))
    _picture(views, names, out / "test_views.png")
    return 0


def _picture(views: dict, names: list[str], path: Path) -> None:
    """Per test view two rows: photo | each run's render, then (blank) | each run's median depth."""
    from PIL import Image

    tiles = []
    for view, d in views.items():
        photo = d["photo"].astype(np.float64) / 255.0
        h, w = photo.shape[:2]
        true = d["true"]
        lo, hi = (np.nanpercentile(true, 1), np.nanpercentile(true, 99)) if true is not None else (0.0, 1.0)
        top = [photo] + [d[n][0] for n in names if n in d]
        bottom = [np.zeros_like(photo)]
        for n in names:
            if n in d:
                depth = d[n][1]
                g = np.clip((hi - depth) / max(hi - lo, 1e-9), 0, 1)  # brighter is nearer
                g = np.where(depth > 0, g, 0.0)
                bottom.append(np.repeat(g[..., None], 3, axis=2))
        tiles.append(np.concatenate([np.concatenate(top, 1), np.concatenate(bottom, 1)], 0))
    grid = np.concatenate(tiles, 0)
    img = Image.fromarray((np.clip(grid, 0, 1) * 255).astype(np.uint8))
    img.quantize(256).save(path, optimize=True)


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]), sys.argv[2:]))
