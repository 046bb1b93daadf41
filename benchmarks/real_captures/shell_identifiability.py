"""How much do the photos of the synthetic `background` scene say about where its far shell is?

The shell (an inward sphere of radius 6 with a procedural texture: smooth in ``background``, fine in
``background_detail``) is moved radially by ``delta`` *with its texture*: the moved sphere has radius ``6 - delta``
and its noise and checker are sampled at the point's radial projection onto the true shell (scales × 6 / (6 − delta)),
so each surface point keeps its colour and only its depth changes. The training cameras are rendered with the true
and the moved shell, and the photos compared: PSNR over all pixels and over the shell's pixels. Where moving the shell by the scoring tolerance
changes the photos less than the trained model's own error (its train PSNR), photometric training cannot
place the shell within that tolerance, whatever the method.

    python benchmarks/real_captures/shell_identifiability.py --out results/DIR/shell_identifiability.json \
        [--preset background|background_detail] [--resolution 400 400] [--views 100] [--every 5] \
        [--deltas 0.05 0.09 0.15 0.3]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from gof_warp.io_utils import write_json_atomic
from gof_warp.synthetic import meshes as M
from gof_warp.synthetic.presets import get_preset
from gof_warp.synthetic.render import RayCaster

SHELL_RADIUS = 6.0


def moved_shell(parts: list[M.SyntheticMesh], delta: float) -> list[M.SyntheticMesh]:
    """``parts`` with the part named ``shell`` scaled about the origin to radius ``6 - delta``, texture kept."""
    out = []
    for p in parts:
        if p.name != "shell":
            out.append(p)
            continue
        k = (SHELL_RADIUS - delta) / SHELL_RADIUS
        material = dataclasses.replace(p.material, noise_scale=p.material.noise_scale / k,
                                       checker_scale=p.material.checker_scale / k)
        out.append(p.transformed(scale=k).with_material(material))
    return out


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return float("inf") if mse == 0 else -10.0 * np.log10(mse)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--preset", default="background", choices=("background", "background_detail"))
    ap.add_argument("--resolution", type=int, nargs=2, default=(400, 400))
    ap.add_argument("--views", type=int, default=100, help="the rig's training views (the scene's)")
    ap.add_argument("--every", type=int, default=5, help="compare every N-th training view")
    ap.add_argument("--deltas", type=float, nargs="+", default=(0.05, 0.09, 0.15, 0.3))
    ap.add_argument("--device", default=None)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    preset = get_preset(args.preset)
    parts = preset.build(None)
    shell_index = [i for i, p in enumerate(parts) if p.name == "shell"]
    if len(shell_index) != 1:
        raise SystemExit("the background preset has no single part named 'shell'")
    train, _ = preset.rig.cameras(*args.resolution, args.views, 0)
    views = train[:: args.every]
    ref_caster = RayCaster(parts, preset.lighting, seed=0, device=args.device)
    refs = [ref_caster.render(c, preset.supersample) for c in views]
    shell_faces = np.flatnonzero(ref_caster.face_part == shell_index[0])
    shell_px = [np.isin(r.face, shell_faces) for r in refs]
    rows = []
    for delta in args.deltas:
        caster = RayCaster(moved_shell(parts, delta), preset.lighting, seed=0, device=args.device)
        all_p, shell_p, shell_fraction = [], [], []
        for cam, ref, px in zip(views, refs, shell_px):
            got = caster.render(cam, preset.supersample)
            all_p.append(psnr(got.rgba[..., :3], ref.rgba[..., :3]))
            if px.any():
                shell_p.append(psnr(got.rgba[..., :3][px], ref.rgba[..., :3][px]))
            shell_fraction.append(float(px.mean()))
        rows.append({"delta": delta, "psnr_all_median": float(np.median(all_p)), "psnr_all_min": float(np.min(all_p)),
                     "psnr_shell_median": float(np.median(shell_p)), "psnr_shell_min": float(np.min(shell_p)),
                     "shell_pixel_fraction_mean": float(np.mean(shell_fraction))})
        print(json.dumps(rows[-1]))
    write_json_atomic(Path(args.out), {
        "what": "PSNR of the training photos with the shell moved radially inward by delta (texture kept) against "
                "the true photos; a model whose own train PSNR is below these numbers cannot tell the two shells "
                "apart from the photos",
        "preset": args.preset, "resolution": list(args.resolution), "views_compared": len(views), "supersample": preset.supersample,
        "rows": rows, "seconds": round(time.perf_counter() - t0, 1)})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
