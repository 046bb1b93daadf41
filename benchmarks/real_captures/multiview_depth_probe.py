"""Where a trained model's rendered median depth lies on `background_full`'s shell, and which way the multi-view
term moves it there (2-core CPU): ``multiview_depth_probe.py MODEL.ply SCENE``.

For training views 0, 20, 40, 60 and 80: the pixels whose exact surface (the scene's ray caster) is the shell (r = 6,
above the ground), the model's rendered median depth against the exact depth there, and the sign of the term's
descent step on the median depth (weight 1, all 8 neighbours, their occlusion depths rendered by the model), by how
far the rendered depth is off. Written in session 27 with ``multiview_push.py``.
"""
import sys

import numpy as np, torch
from gof_warp.data import load_scene
from gof_warp.model import Gaussians
from gof_warp.multiview import MultiViewConfig, MultiViewTerm
from gof_warp.render import render
from gof_warp.synthetic.presets import get_preset
from gof_warp.synthetic.render import RayCaster
scene = load_scene(sys.argv[2]); cams = scene.train_cameras
images = [torch.from_numpy(v.image).float() / 255.0 for v in scene.train]
g = Gaussians.load_ply(sys.argv[1])
caster = RayCaster(get_preset("background_full").build(None), device="cpu")
term = MultiViewTerm(MultiViewConfig(weight=1.0, neighbours_per_step=8, from_iter=0), cams, images, seed=0)
refs = [0, 20, 40, 60, 80]
with torch.no_grad():
    for m in sorted(set(refs) | {m for r in refs for m in term.neighbours[r]}):
        term.remember(m, render(g, cams[m])["median_depth"])
g.requires_grad_(True)
rel_all, sgn_all = [], []
for v in refs:
    cam = cams[v]
    gt = caster.render(cam, supersample=1)
    H, W = gt.depth.shape
    vv, uu = np.mgrid[0:H, 0:W]
    rays = np.stack([(uu + 0.5 - cam.cx) / cam.fx, (vv + 0.5 - cam.cy) / cam.fy, np.ones((H, W))], -1)
    world = (rays * gt.depth[..., None] - np.asarray(cam.t)) @ np.asarray(cam.R)
    rad = np.linalg.norm(world, axis=-1)
    shell = (np.abs(rad - 6.0) < 0.05) & (world[..., 2] > -0.8)
    out = render(g, cam)
    d = out["median_depth"]; d.retain_grad()
    loss, used = term(out, v, 10_000)
    loss.backward()
    D = d.detach().numpy(); G = d.grad.numpy()
    rel = (D - gt.depth) / gt.depth
    m = shell & (G != 0)
    rel_all.append(rel[m]); sgn_all.append(np.sign(-G[m]))
    print(f"view {v}: shell px {int(shell.sum())}, with term gradient {int(m.sum())}; rendered median depth vs the "
          f"exact one on shell px: median {np.median(rel[shell]) * 100:+.2f} %, "
          f"at term px {np.median(rel[m]) * 100:+.2f} %; "
          f"descent moves the depth back (+) at {np.mean(-G[m] > 0):.2f} of them", flush=True)
rel = np.concatenate(rel_all); s = np.concatenate(sgn_all)
for lo, hi in ((-1, -0.02), (-0.02, -0.005), (-0.005, 0.005), (0.005, 0.02), (0.02, 1)):
    sel = (rel >= lo) & (rel < hi)
    back = np.mean(s[sel] > 0) if sel.any() else float("nan")
    print(f"relative depth error in [{lo:+.3f}, {hi:+.3f}): {int(sel.sum())} px, "
          f"descent moves the depth back at {back:.2f}")
