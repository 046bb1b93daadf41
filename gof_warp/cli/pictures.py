"""``python -m gof_warp.pictures RUN``: the pictures of a run on demand (photo | render | depth | normal | mesh, the
mesh in its colours or texture when it has them)."""

from __future__ import annotations

import argparse
import sys

from ..viz import pictures as _pictures
from ..core.devices import resolve_device
from .common import HelpFormatter, configure_output, run_command


DESCRIPTION = """\
Pictures of a run, to see what training and extraction produced: one PNG with a row per view and
the columns photo | Gaussian render | median depth | rendered normal | mesh (in its colours or
texture when it has them, else shaded), written to RUN/pictures/views.png (no mesh) or
RUN/pictures/mesh_<stem>.png."""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m gof_warp.pictures", description=DESCRIPTION,
                                 formatter_class=HelpFormatter)
    ap.add_argument("run", help="training output folder (or a Gaussian PLY with --scene)")
    ap.add_argument("--mesh", default=None, help="mesh for the last column, PLY, OBJ or GLB: drawn in its vertex colours "
                                              "or texture when it has them, else shaded (default: none, no mesh column)")
    ap.add_argument("--views", type=int, default=3, help="number of views (rows); test views first")
    ap.add_argument("--out", default=None, help="output folder (default: RUN/pictures)")
    ap.add_argument("--scene", default=None, help="scene folder for cameras and photos (default: found from the run)")
    ap.add_argument("--device", default="auto", help="cpu, cuda or auto")
    ap.add_argument("--quiet", action="store_true", help="no log lines (errors and warnings still shown)")
    a = ap.parse_args(argv)
    configure_output(a.quiet)

    def body():
        for p in _pictures.write_run_pictures(a.run, mesh_path=a.mesh, views=a.views, out_dir=a.out,
                                              device=resolve_device(a.device), scene=a.scene):
            print(f"wrote {p}")

    return run_command(body)


if __name__ == "__main__":
    sys.exit(main())
