"""Do the texture's exposure gains help when the photos' exposures differ? The training photos of a run are scaled
by a random gain per view and channel (uniform in ``[1 - J, 1 + J]``, seed 0), then a texture is baked with and
without gain compensation and rendered against the (unscaled) held-out test photos; beside them the texture from the
unscaled photos. The mesh: ``RUN/mesh_tetra.ply`` decimated to ``--max-faces``.

    python benchmarks/texture/exposure_study.py RUN OUT.json [--max-faces 20000] [--jitter 0.3] [--device cpu]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run")
    ap.add_argument("out")
    ap.add_argument("--max-faces", type=int, default=20_000)
    ap.add_argument("--jitter", type=float, default=0.3)
    ap.add_argument("--device", default="auto")
    a = ap.parse_args(argv)

    import trimesh

    from gof_warp.viz.pictures import run_views
    from gof_warp.core.devices import resolve_device, warp_device
    from gof_warp.mesh.decimate import decimate
    from gof_warp.mesh.texture import bake_texture, make_atlas, texture_side, textured_render_psnr
    from gof_warp.training.run_folder import load_run

    run = Path(a.run)
    device = resolve_device(a.device)
    wdev = warp_device(device)
    _, _, _, render_config = load_run(run, None, device)
    train_cams, train_photos = run_views(run, "train", device)
    test_cams, test_photos = run_views(run, "test", device)
    background = tuple(render_config.background)
    m = trimesh.load(run / "mesh_tetra.ply", process=False, force="mesh")
    v, f = decimate(np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64), max_faces=a.max_faces,
                    measure=False)[:2]
    rng = np.random.default_rng(0)
    true_gain = rng.uniform(1 - a.jitter, 1 + a.jitter, (len(train_cams), 3))
    scaled = [np.clip(p.astype(np.float32) / 255.0 * g, 0, 1) for p, g in zip(train_photos, true_gain)]
    atlas = make_atlas(v, f, texture_side(len(f)))
    result = {"run": str(run), "faces": int(len(f)), "jitter": a.jitter, "device": str(device),
              "machine": "2-core CPU dev box (shared with other jobs, so timings are upper bounds)"}
    for name, photos, exposure in (("unscaled_photos", train_photos, True), ("scaled_with_gains", scaled, True),
                                   ("scaled_without_gains", scaled, False)):
        t = time.perf_counter()
        tex = bake_texture(v, f, train_cams, photos, atlas=atlas, exposure=exposure, device=wdev)
        fid = textured_render_psnr(tex, test_cams, test_photos, background=background, device=wdev)
        row = {k: round(x, 4) for k, x in fid.items() if k != "views"}
        row["bake_s"] = round(time.perf_counter() - t, 2)
        if name == "scaled_with_gains":  # solved gains against the applied ones (up to one common scale)
            g = np.array(tex.info["gains"])
            ratio = g / true_gain
            ratio /= np.median(ratio, axis=0)
            row["gain_error"] = {"median_abs": round(float(np.median(np.abs(ratio - 1))), 4),
                                 "max_abs": round(float(np.abs(ratio - 1).max()), 4)}
        result[name] = row
        print(name, json.dumps(row), flush=True)
    Path(a.out).write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
