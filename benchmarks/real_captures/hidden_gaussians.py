"""How much each Gaussian of a trained model shows in the training views, and which ones no view shows (2-core CPU):
``hidden_gaussians.py MODEL.ply SCENE --out WEIGHTS.npz [--every K]``.

A Gaussian's blending weight w_i = α_i T_i summed over a view's pixels is what that view sees of it. Gaussians behind
an opaque surface get w ≈ 0 in every view, so no loss moves them, yet GOF's opacity field counts their front tails at
every point before their peaks (session 27: the far shell's 0.5 level 5 cm in front of its renders). The per-view sums
come from one backward pass a view (``gof_warp.hidden.blend_weights``: with every DC colour at 0, colour 0.5, unclamped,
the gradient of the rendered red channel's sum with respect to Gaussian i's DC red coefficient is SH_C0 · Σ_pixels w_i).

Writes, per Gaussian, the sum over the views (pixels' worth of weight) and the largest single-view sum, and prints how
many Gaussians fall under a few thresholds and where they lie against the scene's shell (``--radius``, default 6).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from gof_warp.data import load_scene
from gof_warp.hidden import blend_weights
from gof_warp.model import Gaussians


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("scene")
    ap.add_argument("--out", required=True)
    ap.add_argument("--every", type=int, default=1, help="every K-th training view")
    ap.add_argument("--radius", type=float, default=6.0)
    a = ap.parse_args()
    cams = load_scene(a.scene).train_cameras[:: a.every]
    g = Gaussians.load_ply(a.model)
    total = np.zeros(len(g))
    largest = np.zeros(len(g))
    t0 = time.time()
    for k, cam in enumerate(cams):
        w = blend_weights(g, cam).double().numpy()
        total += w
        np.maximum(largest, w, out=largest)
        if k == 0:
            print(f"first view in {time.time() - t0:.1f} s", flush=True)
    np.savez_compressed(a.out, total=total, largest=largest, views=len(cams))
    x = g.means.detach().numpy().astype(np.float64)
    r = np.linalg.norm(x, axis=1)
    op = g.opacities.detach().numpy()
    print(f"{len(g)} Gaussians, {len(cams)} views, {time.time() - t0:.0f} s")
    for thr in (0.01, 0.1, 1.0):
        low = largest < thr
        print(f"largest single-view weight < {thr} px: {int(low.sum())} ({low.mean() * 100:.1f} %); of them opaque "
              f"(> 0.5) {int((low & (op > 0.5)).sum())}; within 0.3 of r = {a.radius}: {int((low & (abs(r - a.radius) < 0.3)).sum())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
