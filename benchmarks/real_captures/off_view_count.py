"""How many training cameras see the false surface, against how many see the GT: ``off_view_count.py SCENE OFF.npz [DENSITY]``.

``OFF.npz``: ``seen_offsurface.py --samples-out`` (the predicted samples farther than tau from the seen GT). Each off
sample and each sample of the seen shell GT is counted in every training camera where it is in front, inside the
image and not behind the GT depth there by more than 0.1 (occlusion by the GT, as region scoring's depth maps). Prints
the off area by view count per nearest GT part, and by height above the ground. Session 18: on `background_detail`
most of the false shell surface is seen by one camera, where nothing places its depth. The scene may be generated at
a low resolution (the poses are the same at any size)."""
import sys
from pathlib import Path

import numpy as np
import trimesh

from gof_warp.region_metrics import _box_diag, _soup, observe, observed_by, read_scene, sample_soup, split_triangles

BINS = [0, 1, 2, 3, 4, 6, 10, 20, 1000]


def scene_parts(sc: Path):
    """``(cameras, scene.json, part names, GT triangles split as region scoring splits them [T, 3, 3], part [T])``."""
    cams, scene = read_scene(sc)
    gt = trimesh.load(sc / "gt_mesh.ply", process=False)
    gv, gf = np.asarray(gt.vertices, float), np.asarray(gt.faces)
    names = [p["name"] for p in scene["parts"]]
    fp = np.repeat(np.arange(len(names)), [p["faces"] for p in scene["parts"]])
    split = [split_triangles(gv[gf[fp == k]], 0.01 * _box_diag(gv)) for k in range(len(names))]
    return cams, scene, names, np.concatenate(split), np.concatenate([np.full(len(s), k) for k, s in enumerate(split)])


def main() -> int:
    sc = Path(sys.argv[1])
    off = np.load(sys.argv[2])
    cams, scene, names, tri, lab = scene_parts(sc)
    obs = observe(*_soup(tri), cams)

    def count(P, margin=0.1):
        return sum(observed_by(cam, D, P, margin).astype(int) for cam, D in zip(obs.cameras, obs.depth))

    sh = names.index("shell")
    g = sample_soup(tri[obs.seen & (lab == sh)], 0.05, 1)
    ng = count(g)
    P, part = off["points"].astype(float), off["part"]
    no = count(P)
    area = float(sys.argv[3]) ** 2 if len(sys.argv) > 3 else 0.02679 ** 2  # sample spacing (seen_offsurface.py's)
    print(f"view-count bins {BINS[:-1]}..")
    print("seen shell GT, share by views:", np.round(np.histogram(ng, BINS)[0] / len(ng), 3))
    for k in np.unique(part):
        print(f"off area near {names[k]} (m2) by views:", np.round(np.histogram(no[part == k], BINS)[0] * area, 1))
    hz = (scene.get("ground") or {"height": 0.0})["height"]
    for lo, hi in ((-9, 0), (0, 1), (1, 2), (2, 9)):
        m = (part == sh) & (P[:, 2] - hz >= lo) & (P[:, 2] - hz < hi)
        mg = (g[:, 2] - hz >= lo) & (g[:, 2] - hz < hi)
        print(f"height above ground [{lo}, {hi}): off shell {m.sum() * area:.1f} m2 (seen by 1 view: "
              f"{(m & (no == 1)).sum() * area:.1f}); shell GT seen by 1 view: {(ng[mg] == 1).mean() if mg.any() else 0:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
