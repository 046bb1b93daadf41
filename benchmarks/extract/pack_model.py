"""Carry a trained model's geometry off the GPU machine and back (files from a device call: 16 MiB each).

``pack RUN_OR_PLY OUT.npz``: keeps what extraction reads — means (float32), opacity logits, log-scales,
quaternions, 3D filter and the DC colour (float16) — and drops the higher SH bands, in files of at most
``PART_ROWS`` Gaussians (``OUT.npz`` alone, else ``OUT.part0.npz``, ``OUT.part1.npz`` …: a 546k-Gaussian DTU model
packs to ~15 MB, and a device call returns files of at most 16 MiB). ``unpack IN.npz OUT.ply`` (one file, or
the first part: the others are found beside it) writes a 3DGS PLY (SH degree 0) that ``python -m gof_warp.extract
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


PART_ROWS = 400_000  # ~11 MB compressed per part (28 B a Gaussian before compression)


def pack(src: Path, dst: Path) -> list[Path]:
    """Write the packed geometry of ``src`` (a run folder or a PLY) to ``dst`` or its parts; returns the files."""
    ply = src / "point_cloud.ply" if src.is_dir() else src
    cols = read_ply_vertices(ply)
    out = {"xyz": np.stack([cols[c] for c in "xyz"], 1).astype(np.float32)}
    out.update({c: cols[c].astype(np.float16) for c in HALF if c in cols})
    n = len(out["xyz"])
    if n <= PART_ROWS:
        np.savez_compressed(dst, **out)
        return [dst]
    files = []
    for k, start in enumerate(range(0, n, PART_ROWS)):
        files.append(dst.with_name(f"{dst.stem}.part{k}.npz"))
        np.savez_compressed(files[-1], **{c: v[start:start + PART_ROWS] for c, v in out.items()})
    return files


def _load(src: Path) -> dict:
    """One packed file, or every part beside ``src`` when ``src`` is a part (``NAME.partK.npz``), joined in order."""
    stem = src.name.split(".part")[0] if ".part" in src.name else None
    if stem is None:
        return dict(np.load(src))
    parts = sorted(src.parent.glob(f"{stem}.part*.npz"), key=lambda p: int(p.name.split(".part")[1].split(".")[0]))
    loaded = [np.load(p) for p in parts]
    return {c: np.concatenate([z[c] for z in loaded]) for c in loaded[0].files}


def unpack(src: Path, dst: Path) -> None:
    z = _load(src)
    xyz = z["xyz"]
    cols = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}
    cols.update({c: z[c].astype(np.float32) for c in HALF if c in z})
    write_ply_vertices(dst, cols)


if __name__ == "__main__":
    verb, a, b = sys.argv[1:4]
    {"pack": pack, "unpack": unpack}[verb](Path(a), Path(b))
