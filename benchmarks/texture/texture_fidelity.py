"""How faithful is a textured mesh? PSNR/SSIM against the run's held-out test photos of the mesh rendered by ray
casting with a baked texture (:func:`gof_warp.mesh.texture.textured_render_psnr`) and with vertex colours
(:func:`gof_warp.mesh.colour.mesh_render_psnr`), both from the training photos, at the full mesh (decimated to
``--full-faces`` when larger) and at smaller face budgets; beside them the Gaussians' own render PSNR on the same
views (whole image, and over the pixels the mesh covers). At the full mesh also: the texture without exposure gains,
and the texture from the Gaussians' renders. Writes OUT.json and OUT.png (one test view: photo | Gaussians |
textured mesh | vertex-coloured mesh).

    python benchmarks/texture/texture_fidelity.py RUN OUT.json [--max-faces 50000 20000 5000] [--device cpu] [--no-variants]

RUN: a training run folder with its scene (``RUN/scene`` or the scene it names) and ``RUN/mesh_tetra.ply`` (the
README job: ``python -m gof_warp.train --out RUN && python -m gof_warp.extract RUN --binary-steps 4``).
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
    ap.add_argument("--full-faces", type=int, default=200_000)
    ap.add_argument("--max-faces", type=int, nargs="*", default=[50_000, 20_000, 5_000])
    ap.add_argument("--device", default="auto")
    ap.add_argument("--view", type=int, default=0, help="the test view of the picture")
    ap.add_argument("--no-variants", action="store_true",
                    help="skip the full mesh's texture without exposure gains and from the Gaussians' renders")
    a = ap.parse_args(argv)

    import trimesh
    from PIL import Image

    from gof_warp.viz.pictures import run_views
    from gof_warp.core.devices import resolve_device, warp_device
    from gof_warp.eval.image_metrics import psnr, ssim
    from gof_warp.mesh.colour import colours_from_images, gaussian_images, mesh_render_psnr, render_vertex_colours
    from gof_warp.mesh.decimate import decimate
    from gof_warp.mesh.texture import bake_texture, make_atlas, render_textured, texture_side, textured_render_psnr
    from gof_warp.training.run_folder import load_run

    run = Path(a.run)
    device = resolve_device(a.device)
    wdev = warp_device(device)
    gaussians, _, _, render_config = load_run(run, None, device)
    train_cams, train_photos = run_views(run, "train", device)
    test_cams, test_photos = run_views(run, "test", device)
    background = tuple(render_config.background)
    m = trimesh.load(run / "mesh_tetra.ply", process=False, force="mesh")
    mesh = (np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64))
    result = {"run": str(run), "mesh": str(run / "mesh_tetra.ply"), "mesh_faces": int(len(mesh[1])),
              "device": str(device), "host": platform.node(), "train_views": len(train_cams),
              "test_views": len(test_cams),
              "machine": (f"1x {torch.cuda.get_device_name(device)}" if str(device).startswith("cuda") else
                          "2-core CPU dev box (shared with other jobs, so timings are upper bounds)")}
    metrics_file = run / "metrics.json"
    if metrics_file.is_file():
        trained = json.loads(metrics_file.read_text())
        result["run_training"] = {"iterations": trained.get("iterations"),
                                  "num_gaussians": trained.get("num_gaussians"),
                                  "test_psnr": (trained.get("test") or {}).get("psnr")}

    renders = list(gaussian_images(gaussians, test_cams, render_config))
    x = torch.from_numpy(np.stack(renders)).permute(0, 3, 1, 2)
    y = torch.from_numpy(np.stack(test_photos).astype(np.float32) / 255.0).permute(0, 3, 1, 2)
    result["gaussians_render"] = {"psnr": float(psnr(x, y)), "ssim": float(ssim(x, y))}
    print(json.dumps(result["gaussians_render"]), flush=True)

    def r4(d):
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in d.items()}

    full_budget = a.full_faces if len(mesh[1]) > a.full_faces else None
    budgets = [full_budget] + sorted({n for n in a.max_faces if n < len(mesh[1])}, reverse=True)
    rows = []
    picture = None
    for i, budget in enumerate(budgets):
        v, f = mesh if budget is None else decimate(*mesh, max_faces=budget, measure=False)[:2]
        v = np.asarray(v, np.float64)
        row = {"max_faces": budget, "vertices": int(len(v)), "faces": int(len(f))}
        t = time.perf_counter()
        colours = colours_from_images(v, f, train_cams, train_photos, device=wdev)
        row["vertex_colours"] = {**r4(mesh_render_psnr(v, f, colours, test_cams, test_photos, background=background,
                                                       device=wdev)), "time_s": round(time.perf_counter() - t, 2)}
        t = time.perf_counter()
        atlas = make_atlas(v, f, texture_side(len(f)))
        atlas_s = time.perf_counter() - t
        variants = [("texture", dict(source="photos", exposure=True))]
        if i == 0 and not a.no_variants:
            variants += [("texture_no_exposure", dict(source="photos", exposure=False)),
                         ("texture_from_gaussians", dict(source="gaussians", exposure=False))]
        for name, opts in variants:
            t = time.perf_counter()
            images = (train_photos if opts["source"] == "photos"
                      else gaussian_images(gaussians, train_cams, render_config))
            tex = bake_texture(v, f, train_cams, images, atlas=atlas, exposure=opts["exposure"], device=wdev)
            bake_s = time.perf_counter() - t
            fid = textured_render_psnr(tex, test_cams, test_photos, background=background, device=wdev)
            info = {k: tex.info[k] for k in ("size", "texels", "ring_texels", "unseen_texels", "charts_fill")}
            gains = np.array(tex.info["gains"])
            info["gain_range"] = [round(float(gains.min()), 4), round(float(gains.max()), 4)]
            row[name] = {**r4(fid), **info, "atlas_s": round(atlas_s, 2), "bake_s": round(bake_s, 2)}
            if i == 0 and name == "texture":
                cam = test_cams[a.view]
                rgb_t, hit = render_textured(tex, cam, background=background, device=wdev)
                rgb_v, _ = render_vertex_colours(v, f, colours, cam, background=background, device=wdev)
                picture = [np.asarray(test_photos[a.view], np.float32) / 255.0, renders[a.view], rgb_t, rgb_v]
            print(name, json.dumps(row[name]), flush=True)
        masks = [render_vertex_colours(v, f, colours, c, device=wdev)[1] for c in test_cams]
        mk = torch.from_numpy(np.stack(masks).astype(np.float32))[:, None]
        row["gaussians_render_masked_psnr"] = round(float(psnr(x, y, mask=mk)), 4)
        rows.append(row)
        print(json.dumps({k: row[k] for k in ("max_faces", "faces", "gaussians_render_masked_psnr")}), flush=True)
        result["meshes"] = rows
        out = Path(a.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=2) + "\n")
    g = result["gaussians_render"]["psnr"]
    top = rows[0]["texture"]["psnr"]
    result["bar"] = {"textured_psnr_at_most_200k_faces": top, "gaussians_psnr": round(g, 4),
                     "gap_db": round(g - top, 4), "within_2db": bool(g - top <= 2.0)}
    Path(a.out).write_text(json.dumps(result, indent=2) + "\n")
    if picture is not None:
        strip = np.round(np.concatenate([np.clip(p, 0, 1) for p in picture], 1) * 255).astype(np.uint8)
        zoom = max(1, -(-384 // strip.shape[0]))  # small photos: enlarged, each pixel a block
        strip = np.repeat(np.repeat(strip, zoom, 0), zoom, 1)
        Image.fromarray(strip).save(Path(a.out).with_suffix(".png"))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
