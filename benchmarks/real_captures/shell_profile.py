"""The opacity field of a trained model along radial lines through a spherical background shell:
``shell_profile.py MODEL.ply SCENE --radius R [--rays N] [--out OUT.json]``.

Draws ``N`` random directions from the origin whose shell point (at ``R``) lies above the scene's ground, samples the
field (GOF's, minimum over the training views; -1 where no view sees) from ``R - 2`` to ``R + 1`` (``--inner``,
``--outer``, ``--step``, ``--heights``: other spans, steps and bands above the ground), and reports where
the first 0.5 crossing lies against ``R`` (a bias: the level in front of or behind the true shell; a spread: a thick
layer whose opacity builds up over a range of depths) and how often a line crosses 0.5 more than once (layers).
Written for the `background` scene's shell (radius 6) in session 11; the model can be one brought back with
``../extract/pack_model.py``."""

import argparse
import json
from pathlib import Path

import numpy as np

from gof_warp.opacity_field import OpacityFieldConfig, opacity_field
from gof_warp.run_folder import load_run


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model", type=Path)
    ap.add_argument("scene")
    ap.add_argument("--radius", type=float, required=True)
    ap.add_argument("--ground", type=float, default=None, help="ground height (default: the scene.json entry)")
    ap.add_argument("--rays", type=int, default=300)
    ap.add_argument("--inner", type=float, default=2.0, help="sample from radius - INNER ...")
    ap.add_argument("--outer", type=float, default=1.0, help="... to radius + OUTER")
    ap.add_argument("--step", type=float, default=0.05, help="radial step of the samples")
    ap.add_argument("--heights", type=float, nargs=2, default=(0.4, 1e9), metavar=("LO", "HI"),
                    help="shell points this high above the ground only (default: from 0.4 up)")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--device", default="cpu", help="torch/Warp device of the field (default: cpu)")
    a = ap.parse_args()
    ground = a.ground
    if ground is None:
        ground = float(json.loads((Path(a.scene) / "scene.json").read_text())["ground"]["height"])
    g, cams, _, rc = load_run(a.model, a.scene, a.device)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(20 * a.rays, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    height = a.radius * d[:, 2] - ground
    d = d[(height > a.heights[0]) & (height < a.heights[1])][: a.rays]
    rs = np.arange(a.radius - a.inner, a.radius + a.outer + 0.5 * a.step, a.step)
    pts = (d[:, None, :] * rs[None, :, None]).reshape(-1, 3).astype(np.float32)
    f = opacity_field(g, cams, pts, config=OpacityFieldConfig(unseen_value=-1.0), render_config=rc).cpu().numpy()
    f = f.reshape(len(d), -1)
    inside = f >= 0.5
    crossed = inside.any(axis=1)
    first = rs[np.argmax(inside, axis=1)][crossed] - a.radius
    changes = (np.diff(inside.astype(int), axis=1) != 0).sum(axis=1)[crossed]
    # depth over which the field climbs from 0.2 to 0.9 (the layer's thickness as the field sees it)
    climb = [float(rs[np.argmax(row >= 0.9)] - rs[np.argmax(row >= 0.2)]) for row in f[crossed] if (row >= 0.9).any()]
    out = {"model": str(a.model), "radius": a.radius, "rays": int(len(d)), "rays_crossing": int(crossed.sum()),
           "first_crossing_minus_radius_quantiles": dict(zip(["p10", "p25", "p50", "p75", "p90"],
                                                             np.quantile(first, [0.1, 0.25, 0.5, 0.75, 0.9]).round(3).tolist())),
           "rays_with_several_crossings": float((changes > 1).mean()),
           "climb_0.2_to_0.9_quantiles": dict(zip(["p25", "p50", "p75"],
                                                  np.quantile(climb, [0.25, 0.5, 0.75]).round(3).tolist())),
           "median_field_by_offset": {f"{r - a.radius:+.3f}": round(float(v), 3)
                                      for r, v in zip(rs, np.median(f[crossed], axis=0))}}
    print(json.dumps(out, indent=1))
    if a.out:
        a.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
