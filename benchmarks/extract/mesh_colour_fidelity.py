"""How faithful is a vertex-coloured mesh? PSNR/SSIM of the mesh rendered by ray casting
(:func:`gof_warp.mesh.colour.mesh_render_psnr`) against the run's held-out test photos, for vertex colours from the
Gaussians' renders and from the training photos, at the full mesh and decimated face budgets; beside it the
Gaussians' own render PSNR on the same views (whole image, and over the pixels the mesh covers).

    python benchmarks/extract/mesh_colour_fidelity.py RUN OUT.json [--max-faces 50000 20000] [--device cpu]

RUN: a training run folder with its scene (``RUN/scene`` or the scene it names) for the photos. The mesh:
``RUN/mesh_tetra.ply`` when it exists, else extracted with the default settings (``extract_mesh``).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run")
    ap.add_argument("out")
    ap.add_argument("--max-faces", type=int, nargs="*", default=[50_000, 20_000])
    ap.add_argument("--device", default="auto")
    a = ap.parse_args(argv)

    from gof_warp.viz.pictures import run_views
    from gof_warp.core.devices import resolve_device, warp_device
    from gof_warp.eval.image_metrics import psnr, ssim
    from gof_warp.mesh.colour import colours_from_images, gaussian_images, mesh_render_psnr, render_vertex_colours
    from gof_warp.mesh.decimate import decimate
    from gof_warp.mesh.extraction import MeshConfig, extract_mesh
    from gof_warp.training.run_folder import load_run

    run = Path(a.run)
    device = resolve_device(a.device)
    wdev = warp_device(device)
    gaussians, _, _, render_config = load_run(run, None, device)
    train_cams, train_photos = run_views(run, "train", device)
    test_cams, test_photos = run_views(run, "test", device)
    background = tuple(render_config.background)

    mesh_file = run / "mesh_tetra.ply"
    t0 = time.perf_counter()
    if mesh_file.is_file():
        import trimesh

        m = trimesh.load(mesh_file, process=False, force="mesh")
        full = (np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.int64))
        mesh_from = str(mesh_file)
    else:
        (full,) = extract_mesh(gaussians, train_cams, MeshConfig(), render_config=render_config)
        mesh_from = "extract_mesh(MeshConfig())"
    result = {"run": str(run), "mesh": mesh_from, "mesh_s": round(time.perf_counter() - t0, 2),
              "device": str(device), "host": platform.node(), "train_views": len(train_cams),
              "test_views": len(test_cams)}
    metrics_file = run / "metrics.json"
    if metrics_file.is_file():  # the training that made the run
        trained = json.loads(metrics_file.read_text())
        result["run_training"] = {k: trained.get(k) for k in ("iterations", "num_gaussians", "test")}

    # the Gaussians' own render on the test views
    renders = list(gaussian_images(gaussians, test_cams, render_config))
    x = torch.from_numpy(np.stack(renders)).permute(0, 3, 1, 2)
    y = torch.from_numpy(np.stack(test_photos).astype(np.float32) / 255.0).permute(0, 3, 1, 2)
    result["gaussians_render"] = {"psnr": float(psnr(x, y)), "ssim": float(ssim(x, y))}

    budgets = [None] + sorted({n for n in a.max_faces if n < len(full[1])}, reverse=True)
    rows = []
    for budget in budgets:
        v, f = full if budget is None else decimate(*full, max_faces=budget, measure=False)[:2]
        row = {"max_faces": budget, "vertices": int(len(v)), "faces": int(len(f))}
        hit_masks = None
        for source in ("gaussians", "photos"):
            t = time.perf_counter()
            images = gaussian_images(gaussians, train_cams, render_config) if source == "gaussians" else train_photos
            colours = colours_from_images(v, f, train_cams, images, device=wdev)
            colour_s = time.perf_counter() - t
            metrics = mesh_render_psnr(v, f, colours, test_cams, test_photos, background=background, device=wdev)
            row[source] = {**{k: round(val, 4) for k, val in metrics.items() if k != "views"},
                           "colour_s": round(colour_s, 2)}
            if hit_masks is None:
                hit_masks = [render_vertex_colours(v, f, colours, c, device=wdev)[1] for c in test_cams]
        # the Gaussians' render over the same covered pixels, for the masked columns
        m = torch.from_numpy(np.stack(hit_masks).astype(np.float32))[:, None]
        row["gaussians_render_masked_psnr"] = round(float(psnr(x, y, mask=m)), 4)
        rows.append(row)
        print(json.dumps(row), flush=True)
    result["meshes"] = rows
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
