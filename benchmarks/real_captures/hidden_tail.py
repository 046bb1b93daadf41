"""Which of a trained model's hidden Gaussians reach through the surface in front of them (2-core CPU):
``hidden_tail.py MODEL.ply SCENE [--visible VF.npz] [--radius 6.05]``.

``gof_warp.hidden.surface_measures`` gives, per Gaussian, the least ratio of its centre's depth to the rendered median
depth at its pixel (behind the surface when above 1 + margin in every view that sees where it is) and its tail: its
opacity at the rendered surface along the ray through its centre, the largest over those views (what GOF's field
counts of it in front of the surface). Prints, for the Gaussians behind by more than 1 %, how many reach through at a
few thresholds (``densify.hidden_min_tail``), split by where they lie in ``background_full``: under the ground, at the
shell's radius, by the objects, in the concave corner where ground meets shell, and the round ones beyond the shell
(session 28's culprits: centre beyond ``--radius``, smallest scale above 5 cm). ``--visible`` adds the visibility test
at 0.2 from a saved ``visible_fraction`` (``vf`` in an npz).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from gof_warp.data import load_scene
from gof_warp.hidden import behind_by, surface_measures
from gof_warp.model import Gaussians


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("scene")
    ap.add_argument("--visible", default=None, help="npz with 'vf': gof_warp.hidden.visible_fraction of this model")
    ap.add_argument("--radius", type=float, default=6.05, help="the round Gaussians beyond this radius are counted")
    a = ap.parse_args()
    cams = load_scene(a.scene).train_cameras
    g = Gaussians.load_ply(a.model)
    t0 = time.time()
    ratio, tail = surface_measures(g, cams)
    hidden = behind_by(ratio, 0.01).numpy()
    tail = tail.numpy()
    print(f"{len(g)} Gaussians, {len(cams)} views, {time.time() - t0:.0f} s; behind the surface by > 1 %: {hidden.sum()}")
    x = g.means.detach().numpy()
    r, z = np.linalg.norm(x, axis=1), x[:, 2]
    smallest = g.scales.detach().numpy().min(1)
    parts = {"under the ground (z < -0.7)": z < -0.7, "at the shell (r > 5.8)": r > 5.8,
             "by the objects (r < 3, z > -0.7)": (r < 3) & (z > -0.7),
             "ground-shell corner (r > 5.6, z < -0.7)": (r > 5.6) & (z < -0.7),
             f"round, beyond r = {a.radius}": (r > a.radius) & (smallest > 0.05)}
    q = [5, 25, 50, 75, 95]
    for name, m in parts.items():
        sel = hidden & m
        pct = np.percentile(tail[sel], q).round(3).tolist() if sel.any() else []
        print(f"{name}: behind {sel.sum()}, tail p{q} {pct}")
    vf = np.load(a.visible)["vf"] if a.visible else None
    for eps in (0.01, 0.05, 0.1, 0.2):
        sel = hidden & (tail > eps)
        line = f"min_tail {eps}: {sel.sum()} reach through; " + ", ".join(
            f"{name.split(' (')[0]} {int((sel & m).sum())}" for name, m in parts.items())
        if vf is not None:
            line += f"; with the visibility test 0.2: {int((sel & (vf < 0.2)).sum())}"
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
