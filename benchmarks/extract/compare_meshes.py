"""Score one extraction against another of the same model: ``compare_meshes.py TEST.ply REF.ply OUT.json``.

The issue's accuracy bar for a faster extraction path: F-score at τ = 0.1 % of the reference's bounding-box
diagonal ≥ 0.995 between the two meshes (points sampled on both surfaces every 0.03 % of the diagonal,
``gof_warp.geometry_metrics``), also at 0.5 %, with both meshes' statistics (boundary edges: holes).
"""

from __future__ import annotations

import json
import sys

import numpy as np
import trimesh

from gof_warp.geometry_metrics import evaluate_mesh


def main(test: str, ref: str, out: str) -> None:
    m = trimesh.load(ref, process=False)
    diag = float(np.linalg.norm(m.bounds[1] - m.bounds[0]))
    taus = [0.001 * diag, 0.005 * diag]
    r = evaluate_mesh(test, ref, tau=taus, density=0.0003 * diag)  # samples 3x finer than the smaller τ
    r["tau_fraction_of_diagonal"] = [0.001, 0.005]
    r["density_fraction_of_diagonal"] = 0.0003
    r["reference_diagonal"] = diag
    with open(out, "w") as f:
        json.dump(r, f, indent=1)
    print(json.dumps(r["metrics"])[:1500])


if __name__ == "__main__":
    main(*sys.argv[1:4])
