"""Which way the multi-view term pushes a trained model's far shell (2-core CPU):
``multiview_push.py MODEL.ply SCENE [--per-step 8] [--every 10]``.

`background_full`'s shell is the sphere r = 6 about the origin. With `loss.multiview` on, training moved it in front
of its true radius (session 27: the median 2.3 cm further in front with 8 neighbours a step), although the term's
minimum on the exact geometry is at the true depth (``multiview_gt.py``). This looks at the step that training takes
from a trained model: the gradient of the term (weight 1, every ``--every``-th training view as the reference,
``--per-step`` of its neighbours, their occlusion depths rendered by the model) on the Gaussians' centres, and the
descent direction's radial component for the Gaussians on the shell (centre 5.5 < r < 6.5, above the ground's
neighbourhood, opacity > 0.5), by height above the ground. Three ways: the term through the rendered median depth and
normal, as training has it; through the depth alone (normal detached); and, as a yardstick, the L1 colour loss
against the photo. Negative radial = towards the cameras (in front of the shell).
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from gof_warp.data import load_scene
from gof_warp.model import Gaussians
from gof_warp.multiview import MultiViewConfig, MultiViewTerm
from gof_warp.render import render

SHELL_RADIUS = 6.0
GROUND_Z = -0.9
BANDS = ((0.0, 0.4), (0.4, 2.0), (2.0, 10.0))


def term_on_model(model: str, scene_dir: str, per_step: int, refs: list[int]):
    """``(cameras, photos, model, term)``: a scene's training cameras and photos, the model of ``model``, and the
    multi-view term over them (weight 1, ``per_step`` neighbours a step, acting from iteration 0) holding, as the
    occlusion depths it reads, the model's own median depths for the views ``refs`` and their neighbours (as in
    training)."""
    scene = load_scene(scene_dir)
    cams = scene.train_cameras
    images = [torch.from_numpy(v.image).float() / 255.0 for v in scene.train]
    g = Gaussians.load_ply(model)
    term = MultiViewTerm(MultiViewConfig(weight=1.0, neighbours_per_step=per_step, from_iter=0), cams, images, seed=0)
    with torch.no_grad():
        for m in sorted(set(refs) | {m for r in refs for m in term.neighbours[r]}):
            term.remember(m, render(g, cams[m])["median_depth"])
    return cams, images, g, term


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("scene")
    ap.add_argument("--per-step", type=int, default=8)
    ap.add_argument("--every", type=int, default=10)
    a = ap.parse_args()
    cams = load_scene(a.scene).train_cameras
    refs = list(range(0, len(cams), a.every))
    cams, images, g, term = term_on_model(a.model, a.scene, a.per_step, refs)
    x = g.means.detach().numpy().astype(np.float64)
    r = np.linalg.norm(x, axis=1)
    shell = (r > SHELL_RADIUS - 0.5) & (r < SHELL_RADIUS + 0.5) & (x[:, 2] > GROUND_Z + 0.1)
    shell &= g.opacities.detach().numpy() > 0.5
    height = x[:, 2] - GROUND_Z
    radial_dir = x / np.maximum(r, 1e-12)[:, None]
    print(f"{int(shell.sum())} opaque shell Gaussians; their centres' radius - {SHELL_RADIUS}: median "
          f"{np.median(r[shell] - SHELL_RADIUS) * 100:.1f} cm; reference views {refs}, {a.per_step} neighbours a step")
    g.requires_grad_(True)
    for variant in ("term: depth and normal", "term: depth only", "L1 colour (yardstick)"):
        for p in g.params.values():
            p.grad = None
        used = 0
        for v in refs:
            out = render(g, cams[v])
            if variant.startswith("L1"):
                loss = (out["rgb"] - images[v]).abs().mean()
            else:
                if variant == "term: depth only":
                    out = {**out, "normal": out["normal"].detach()}
                result = term(out, v, 10_000)
                if result is None:
                    continue
                loss, n = result
                used += int(n)
            loss.backward()
        step = -g.params["means"].grad.numpy().astype(np.float64)  # the descent direction
        radial = (step * radial_dir).sum(1)
        norm = np.linalg.norm(step, axis=1)
        line = [f"{variant}" + (f" ({used} patches)" if used else "")]
        for lo, hi in BANDS:
            sel = shell & (height >= lo) & (height < hi) & (norm > 0)
            if sel.sum() == 0:
                continue
            share_in = float((norm[sel] * (radial[sel] < 0)).sum() / norm[sel].sum())
            line.append(f"  {lo}-{hi} m above the ground: {int(sel.sum())} moved, sum of radial steps "
                        f"{radial[sel].sum():+.3e}, radial / |step| {radial[sel].sum() / norm[sel].sum():+.3f}, "
                        f"inward share (by |step|) {share_in:.2f}")
        print("\n".join(line), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
