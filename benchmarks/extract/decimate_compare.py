"""Decimate an extracted mesh to a face budget and score it against the full mesh (issue: faces ≤ 0.5× official).

    python benchmarks/extract/decimate_compare.py MESH.ply MAX_FACES OUT.json

Runs :func:`gof_warp.decimate.decimate` (as ``extract --max-faces`` does, without the error measurement), then
``compare_meshes.py``'s scoring of the decimated mesh against the input: F-score at 0.1 % and 0.5 % of the
diagonal (the extraction issue's bar between two meshes of one model is F@0.1 % ≥ 0.995). Writes one JSON
object: the decimation's info (time, faces before and after, closedness) and the comparison.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from compare_meshes import main as compare  # noqa: E402
from gof_warp.decimate import decimate  # noqa: E402


def main(mesh: str, max_faces: int, out: str) -> None:
    m = trimesh.load(mesh, process=False)
    t0 = time.perf_counter()
    v, f, info = decimate(np.asarray(m.vertices), np.asarray(m.faces), max_faces=max_faces, measure=False)
    info["wall_s"] = time.perf_counter() - t0
    small = str(Path(out).with_suffix(".ply"))
    trimesh.Trimesh(v, f, process=False).export(small)
    cmp_json = str(Path(out).with_suffix(".compare.json"))
    compare(small, mesh, cmp_json)
    result = {"mesh": mesh, "max_faces": max_faces, "decimation": info, "compare": json.loads(Path(cmp_json).read_text())}
    Path(out).write_text(json.dumps(result, indent=1, default=float))
    print(json.dumps(info, default=float))


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3])
