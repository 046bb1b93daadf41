"""Carry a trained model's geometry off the GPU machine and back (files from a device call: 16 MiB each).

``pack RUN_OR_PLY OUT.npz``: keeps what extraction reads — means (float32), opacity logits, log-scales,
quaternions, 3D filter and the DC colour (float16) — and drops the higher SH bands. A 546k-Gaussian DTU model
packs to ~15 MB. ``unpack IN.npz OUT.ply`` writes a 3DGS PLY (SH degree 0) that ``python -m gof_warp.extract
OUT.ply --scene SCENE`` meshes. float16 moves log-scales by <= 5e-4 (relative scale 0.05 %) and quaternions by
<= 5e-4: the same scene for timing and memory, not bit-identical meshes.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from gof_warp.ply import read_ply_vertices, write_ply_vertices

HALF = ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "f_dc_0", "f_dc_1", "f_dc_2",
        "filter_3D"]


def pack(src: Path, dst: Path) -> None:
    ply = src / "point_cloud.ply" if src.is_dir() else src
    cols = read_ply_vertices(ply)
    out = {"xyz": np.stack([cols[c] for c in "xyz"], 1).astype(np.float32)}
    out.update({c: cols[c].astype(np.float16) for c in HALF if c in cols})
    np.savez_compressed(dst, **out)


def unpack(src: Path, dst: Path) -> None:
    z = np.load(src)
    xyz = z["xyz"]
    cols = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}
    cols.update({c: z[c].astype(np.float32) for c in HALF if c in z.files})
    write_ply_vertices(dst, cols)


if __name__ == "__main__":
    verb, a, b = sys.argv[1:4]
    {"pack": pack, "unpack": unpack}[verb](Path(a), Path(b))
