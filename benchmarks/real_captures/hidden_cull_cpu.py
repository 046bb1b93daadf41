"""Leave out, at extraction, the Gaussians hidden behind the rendered surface (2-core CPU; session 28):
``hidden_cull_cpu.py MODEL.ply SCENE OUT_PREFIX --margins 0.01 0.02``.

For each margin, :func:`gof_warp.hidden.behind_surface`'s Gaussians over the scene's training views (one render a view
for all margins: :func:`~gof_warp.hidden.surface_depth_ratio`), their count, and the model without them as
``OUT_PREFIX<margin>.ply`` (mesh it with ``python -m gof_warp.extract PLY --scene SCENE``).
"""

from __future__ import annotations

import argparse

from gof_warp.data import load_scene
from gof_warp.hidden import behind_by, surface_depth_ratio
from gof_warp.model import Gaussians


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("scene")
    ap.add_argument("out_prefix")
    ap.add_argument("--margins", type=float, nargs="+", default=[0.01])
    a = ap.parse_args()
    cams = load_scene(a.scene).train_cameras
    g = Gaussians.load_ply(a.model)
    least = surface_depth_ratio(g, cams)
    for m in a.margins:
        hidden = behind_by(least, m)
        g.subset(~hidden).save_ply(f"{a.out_prefix}{m}.ply")
        print(f"margin {m}: {int(hidden.sum())} of {len(g)} Gaussians behind the rendered surface in every view that "
              f"sees where they are -> {a.out_prefix}{m}.ply")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
