"""How many pixels the octree's asked-for cells span (2-core CPU): ``cell_pixels.py MODEL.ply SCENE [--factor 0.5]``.

Each Gaussian asks for cells no larger than ``factor × 2r`` (``r = 3 max(s)``, :mod:`gof_warp.octree_tets`). Divided by
its pixel footprint in the finest training view that holds its centre (depth over focal length), that is the cell in
pixels. Prints the percentiles and the fraction a cap of K pixels would refine: whether such a cap tells a scene of few
large Gaussians from one of many small ones (session 29, ``README.md``).
"""

from __future__ import annotations

import argparse

import numpy as np

from gof_warp.model import Gaussians
from gof_warp.region_metrics import read_scene


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("scene", help="a Blender-layout scene folder (the training cameras)")
    ap.add_argument("--factor", type=float, default=0.5)
    a = ap.parse_args()
    g = Gaussians.load_ply(a.model)
    cams, _ = read_scene(a.scene)
    mu = g.means.detach().double().numpy()
    cell = a.factor * 2 * 3 * g.scales.detach().double().numpy().max(1)
    footprint = np.full(len(mu), np.inf)
    for cam in cams:
        _, z, inside = cam.in_image(mu)
        footprint = np.minimum(footprint, np.where(inside, z / cam.fx, np.inf))
    seen = np.isfinite(footprint)
    px = cell[seen] / footprint[seen]
    print(f"{a.model}: {len(mu)} Gaussians, {int(seen.sum())} in some view; cell in pixels p10 / median / p90: "
          + " / ".join(f"{v:.2f}" for v in np.percentile(px, [10, 50, 90])))
    for k in (2, 4, 8):
        print(f"  a cap of {k} pixels refines {np.mean(px > k) * 100:.1f} % of them")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
