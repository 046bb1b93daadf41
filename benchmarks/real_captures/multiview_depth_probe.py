"""Where a trained model's rendered median depth lies on `background_full`'s shell, and which way the multi-view
term moves it there (2-core CPU): ``multiview_depth_probe.py MODEL.ply SCENE``.

For training views 0, 20, 40, 60 and 80: the pixels whose exact surface (the scene's ray caster) is the shell (r = 6,
above the ground), the model's rendered median depth against the exact depth there, and the sign of the term's
descent step on the median depth (weight 1, all 8 neighbours, their occlusion depths rendered by the model), by how
far the rendered depth is off. Written in session 27 with ``multiview_push.py``.
"""
import sys

import numpy as np

from gof_warp.render import render
from gof_warp.synthetic.presets import get_preset
from gof_warp.synthetic.render import RayCaster
from multiview_push import term_on_model  # same folder

REFS = [0, 20, 40, 60, 80]
SHELL_RADIUS = 6.0


def shell_pixels(caster, cam) -> tuple[np.ndarray, np.ndarray]:
    """``(exact z-depth [H, W], mask of the pixels whose exact surface is the shell above the ground)``."""
    gt = caster.render(cam, supersample=1)
    h, w = gt.depth.shape
    vv, uu = np.mgrid[0:h, 0:w]
    rays = np.stack([(uu + 0.5 - cam.cx) / cam.fx, (vv + 0.5 - cam.cy) / cam.fy, np.ones((h, w))], -1)
    world = (rays * gt.depth[..., None] - np.asarray(cam.t)) @ np.asarray(cam.R)
    radius = np.linalg.norm(world, axis=-1)
    return gt.depth, (np.abs(radius - SHELL_RADIUS) < 0.05) & (world[..., 2] > -0.8)


def main() -> int:
    cams, _, g, term = term_on_model(sys.argv[1], sys.argv[2], 8, REFS)
    caster = RayCaster(get_preset("background_full").build(None), device="cpu")
    g.requires_grad_(True)
    rel_all, sign_all = [], []
    for v in REFS:
        exact, shell = shell_pixels(caster, cams[v])
        out = render(g, cams[v])
        d = out["median_depth"]
        d.retain_grad()
        loss, _ = term(out, v, 10_000)
        loss.backward()
        rel = (d.detach().numpy() - exact) / exact
        grad = d.grad.numpy()
        m = shell & (grad != 0)
        rel_all.append(rel[m])
        sign_all.append(np.sign(-grad[m]))
        print(f"view {v}: shell px {int(shell.sum())}, with term gradient {int(m.sum())}; rendered median depth vs the "
              f"exact one on shell px: median {np.median(rel[shell]) * 100:+.2f} %, "
              f"at term px {np.median(rel[m]) * 100:+.2f} %; "
              f"descent moves the depth back (+) at {np.mean(-grad[m] > 0):.2f} of them", flush=True)
    rel, sign = np.concatenate(rel_all), np.concatenate(sign_all)
    for lo, hi in ((-1, -0.02), (-0.02, -0.005), (-0.005, 0.005), (0.005, 0.02), (0.02, 1)):
        sel = (rel >= lo) & (rel < hi)
        back = np.mean(sign[sel] > 0) if sel.any() else float("nan")
        print(f"relative depth error in [{lo:+.3f}, {hi:+.3f}): {int(sel.sum())} px, "
              f"descent moves the depth back at {back:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
