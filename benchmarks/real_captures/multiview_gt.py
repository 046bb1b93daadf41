"""The multi-view term on `background_full`'s exact geometry (2-core CPU): is its minimum at the true depth?

GT colour, median depth (the ray caster's z-depth) and camera-space normals of the training views at 200x200 (100
views, the preset's rig); the term (``MultiViewConfig`` defaults) with every depth scaled by k, over each view's
neighbours. Prints (1) per reference view and neighbour the loss and the patches used at k = 1, 0.98, 0.95, over the
whole image and its top eighth of rows (the lowest cameras' top band of the shell); (2) the patch-weighted sum of the
loss over every 7th view and its neighbours, by part (shell below z = 0.1, shell above z = 1.1, ground), for k from
0.985 to 1.015 (``--ks`` other factors, e.g. finer ones near 1). ``python multiview_gt.py [MODEL.ply] [--ks K,K,...]``

With ``MODEL.ply`` (a trained model, e.g. ``../extract/pack_model.py unpack`` of a packed run), (2) is printed twice:
with the neighbours' exact depths in the occlusion test, as above, and with the median depths that model renders for
them (what the term reads in training, where the neighbours' renders are only as right as the model), to see whether
the term's landscape on the exact surface moves when the occlusion test reads a trained model's depths; and a third
time with the model's rendered normals in place of the exact ones at the reference view (each patch's plane tilted as
in training), the occlusion test against the exact depths.
"""

import argparse


import numpy as np
import torch

from gof_warp.multiview import MultiViewConfig, grey, multiview_loss, neighbour_views, sample_centres
from gof_warp.synthetic.presets import get_preset
from gof_warp.synthetic.render import RayCaster

ap = argparse.ArgumentParser()
ap.add_argument("model", nargs="?")
ap.add_argument("--ks", default="0.985,0.99,0.995,1.0,1.005,1.01,1.015")
ap.add_argument("--skip-pairs", action="store_true", help="leave out (1), the per-pair table")
args = ap.parse_args()
W = 200
preset = get_preset("background_full")
train, _ = preset.rig.cameras(W, W, n_train=100)
caster = RayCaster(preset.build(None), device="cpu")
cfg = MultiViewConfig(weight=0.15)
neighbours = neighbour_views(train, cfg.neighbours, cfg.max_angle_deg)
cache = {}


def view(i):
    """``(rgb, depth, camera-space normal, alpha, world points [H, W, 3])`` of training view ``i``."""
    if i not in cache:
        cam = train[i]
        r = caster.render(cam, supersample=2)
        n_cam = (r.normal @ np.asarray(cam.R).T).astype(np.float32)
        v, u = np.mgrid[0:W, 0:W]
        rays = np.stack([(u + 0.5 - cam.cx) / cam.fx, (v + 0.5 - cam.cy) / cam.fy, np.ones((W, W))], -1)
        world = (rays * r.depth[..., None] - np.asarray(cam.t)) @ np.asarray(cam.R)
        cache[i] = (torch.tensor(r.rgba[..., :3]), torch.tensor(r.depth), torch.tensor(n_cam),
                    torch.tensor(r.rgba[..., 3]), world)
    return cache[i]


model_depth = {}


def rendered(m):
    """``(median depth, camera-space normal)`` the model given renders for training view ``m`` (cached)."""
    if m not in model_depth:
        from gof_warp.model import Gaussians
        from gof_warp.render import render

        if "model" not in model_depth:
            model_depth["model"] = Gaussians.load_ply(args.model)
        with torch.no_grad():
            out = render(model_depth["model"], train[m])
        model_depth[m] = (out["median_depth"], out["normal"])
    return model_depth[m]


def loss(i, m, centres, k, occluders="exact"):
    rgb, d, n, a, _ = view(i)
    rgb2, d2, _, _, _ = view(m)
    nbr_depth = rendered(m)[0] if occluders == "model" else d2
    if occluders == "model normals":
        n = rendered(i)[1]
    value, used = multiview_loss(d * k, n, a, grey(rgb), grey(rgb2), train[i], train[m], centres, cfg,
                                 nbr_depth=nbr_depth)
    return float(value), int(used)


centres_all = sample_centres(W, W, 4096, 7, torch.Generator().manual_seed(0))
elevation = np.degrees(np.arcsin((np.stack([c.center for c in train])[:, 2] + 0.35) / 4))
if not args.skip_pairs:
    print("(1) k = 1 / 0.98 / 0.95: loss (patches), whole image | top eighth of the rows")
for i in [] if args.skip_pairs else list(np.argsort(elevation)[:2]) + [50]:
    top = centres_all[centres_all[:, 1] < W // 8]
    for m in neighbours[i]:
        cells = [f"{loss(i, m, centres_all, k)[0]:.3f} ({loss(i, m, centres_all, k)[1]}) | "
                 f"{loss(i, m, top, k)[0]:.3f} ({loss(i, m, top, k)[1]})" for k in (1.0, 0.98, 0.95)]
        print(f"view {i} (elevation {elevation[i]:.1f}) -> {m} ({elevation[m]:.1f}): " + "; ".join(cells), flush=True)

ks = tuple(float(k) for k in args.ks.split(","))
for occluders in ("exact",) + (("model", "model normals") if args.model else ()):
    total = {part: np.zeros(len(ks)) for part in ("shell below z = 0.1", "shell above z = 1.1", "ground")}
    used_at = {part: np.zeros(len(ks), int) for part in total}
    for i in range(0, 100, 7):
        world = view(i)[4]
        centres = sample_centres(W, W, 3000, 7, torch.Generator().manual_seed(i))
        c = centres.numpy()
        z, radius = world[c[:, 1], c[:, 0], 2], np.linalg.norm(world[c[:, 1], c[:, 0]], axis=-1)
        parts = {"shell below z = 0.1": (radius > 5.9) & (z < 0.1) & (z > -0.5),
                 "shell above z = 1.1": (radius > 5.9) & (z > 1.1), "ground": np.abs(z + 0.9) < 0.01}
        for m in neighbours[i]:
            for part, mask in parts.items():
                if mask.sum() < 20:
                    continue
                chosen = centres[torch.tensor(mask)]
                for j, k in enumerate(ks):
                    value, used = loss(i, m, chosen, k, occluders)
                    total[part][j] += value * used
                    used_at[part][j] += used
    what = ("the reference's rendered normals, occlusion test against the exact depths" if occluders == "model normals"
            else f"occlusion test against the {occluders} depths")
    print(f"(2) patch-weighted loss by part, depth scaled by k; {what} (patches used in brackets)")
    for part, v in total.items():
        print(f"{part}: " + "  ".join(f"{k}: {x:.1f} ({u})" for k, x, u in zip(ks, v, used_at[part])), flush=True)
