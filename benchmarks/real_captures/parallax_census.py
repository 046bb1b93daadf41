"""How much parallax the training cameras give the false surface, against the seen GT: would a mask on it help?

``parallax_census.py SCENE OFF.npz [SPACING]``: ``OFF.npz`` from ``seen_offsurface.py --samples-out`` (predicted
samples farther than tau from the seen GT). For every off sample, and for samples of the seen GT, the cameras that
observe it (in front, inside the image, not behind the GT depth there by more than 0.1: region scoring's test) give
its largest triangulation angle: the largest angle between two of their rays to it. A point whose rays all nearly
coincide has no parallax, so no photometric fit can place its depth (one camera: angle 0). Prints the area of each by
angle, and for masks "leave out what has less than A degrees" the false area removed against the true area lost.
The scene may be generated at a low resolution (the poses are the same at any size). Session 19, issue 18.
"""

import sys
from pathlib import Path

import numpy as np

from gof_warp.region_metrics import _soup, observe, observed_by, sample_soup

from off_view_count import scene_parts

BINS_DEG = [0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 181.0]
MASKS_DEG = [1.0, 2.0, 3.0, 5.0, 8.0]


def max_triangulation_angle(points: np.ndarray, centres: np.ndarray, seen: np.ndarray, chunk: int = 512) -> np.ndarray:
    """``[N]`` degrees: the largest angle between two rays from ``centres [C, 3]`` that see ``points [N, 3]``
    (``seen [N, C]`` bool); 0 where fewer than two cameras see the point."""
    out = np.zeros(len(points))
    for s in range(0, len(points), chunk):
        d = centres[None] - points[s:s + chunk, None]  # [n, C, 3]
        d /= np.linalg.norm(d, axis=2, keepdims=True)
        cos = np.einsum("nci,ndi->ncd", d, d)
        both = seen[s:s + chunk, :, None] & seen[s:s + chunk, None, :]
        cos = np.where(both, cos, 1.0).min(axis=(1, 2))
        out[s:s + chunk] = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return out


def main() -> int:
    sc = Path(sys.argv[1])
    off = np.load(sys.argv[2])
    spacing = float(sys.argv[3]) if len(sys.argv) > 3 else 0.02679  # seen_offsurface.py's sample spacing
    cams, _, names, tri, lab = scene_parts(sc)
    obs = observe(*_soup(tri), cams)
    centres = np.stack([c.center for c in obs.cameras])

    def angles(P):
        seen = np.stack([observed_by(cam, D, P, 0.1) for cam, D in zip(obs.cameras, obs.depth)], 1)
        return max_triangulation_angle(P, centres, seen), seen.sum(1)

    gt_points = sample_soup(tri[obs.seen], spacing, 1)
    a_gt, n_gt = angles(gt_points)
    a_off, n_off = angles(off["points"].astype(float))
    area = spacing**2
    print(f"samples: seen GT {len(gt_points)} ({len(gt_points) * area:.1f} m2), off {len(a_off)} ({len(a_off) * area:.1f} m2)")
    print("largest triangulation angle bins (deg):", BINS_DEG[:-1])
    print("  seen GT area (m2): ", np.round(np.histogram(a_gt, BINS_DEG)[0] * area, 1))
    print("  false area (m2):   ", np.round(np.histogram(a_off, BINS_DEG)[0] * area, 1))
    for k in np.unique(off["part"]):
        m = off["part"] == k
        print(f"  false area near {names[k]} (m2):", np.round(np.histogram(a_off[m], BINS_DEG)[0] * area, 1))
    print("mask 'leave out less than A degrees': false area removed / seen GT area lost (m2)")
    for a in MASKS_DEG:
        print(f"  A = {a:4.1f}: {(a_off < a).sum() * area:6.1f} of {len(a_off) * area:.1f} / "
              f"{(a_gt < a).sum() * area:6.1f} of {len(a_gt) * area:.1f}")
    for v in (1, 2, 3):
        print(f"views <= {v}: false {(n_off <= v).sum() * area:.1f} m2, seen GT {(n_gt <= v).sum() * area:.1f} m2")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
