"""cProfile of the marching stage (``gof_warp.extraction._march``) with the octree grid whole and in pieces, on the
same model and grid, in one process (what makes pieces slower than the whole grid: ``README.md``, session 20).

    python benchmarks/extract/profile_pieces.py RUN --cell-factor 0.1 --out $OUT/profile_pieces.txt
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import sys
import time
from pathlib import Path

import torch


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--cell-factor", type=float, default=0.1)
    ap.add_argument("--piece-tets", type=int, nargs="+", default=[2**31 - 1, 1 << 24])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--device", default="cuda")
    a = ap.parse_args(argv)
    from gof_warp import extraction
    from gof_warp.run_folder import load_run
    from gof_warp.extraction import MeshConfig, StageTimer, extract_mesh
    from gof_warp.octree_tets import OctreeConfig
    from gof_warp.tetra import TetraConfig

    gaussians, cameras, _, render_config = load_run(a.run, None, a.device)

    def sync():
        if a.device.startswith("cuda"):
            torch.cuda.synchronize()

    report = io.StringIO()
    march = extraction._march
    for piece_tets in a.piece_tets:
        prof = cProfile.Profile()

        def profiled(*args, **kwargs):
            sync()
            prof.enable()
            try:
                out = march(*args, **kwargs)
                sync()
            finally:
                prof.disable()
            return out

        extraction._march = profiled
        cfg = MeshConfig(tetra=TetraConfig(octree=OctreeConfig(cell_factor=a.cell_factor, piece_tets=piece_tets)))
        timer = StageTimer(a.device)
        t0 = time.perf_counter()
        (v, f), = extract_mesh(gaussians, cameras, cfg, render_config=render_config, timer=timer)
        report.write(f"\n===== piece_tets {piece_tets}: {time.perf_counter() - t0:.2f} s, {len(f)} faces, stages "
                     f"{ {k: s['time_s'] for k, s in timer.stages.items() if 'time_s' in s} }, "
                     f"pieces {timer.stages['counts']['pieces']}\n")
        for key in ("tottime", "cumulative"):
            pstats.Stats(prof, stream=report).sort_stats(key).print_stats(22)
    extraction._march = march
    a.out.write_text(report.getvalue())
    print(report.getvalue()[:6000])
    return 0


if __name__ == "__main__":
    sys.exit(main())
