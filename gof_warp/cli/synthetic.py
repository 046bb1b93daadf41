"""``python -m gof_warp.synthetic``: render a synthetic scene with exact ground truth.

Examples::

    python -m gof_warp.synthetic --list
    python -m gof_warp.synthetic --out scenes/default                      # small, CPU-friendly
    python -m gof_warp.synthetic --preset thin --out scenes/thin --resolution 800 800 --device cuda
"""

from __future__ import annotations

import argparse
import sys

from .common import HelpFormatter, configure_output, run_command
from ..core.errors import GofError


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m gof_warp.synthetic",
        description="Render a synthetic scene (Blender format, exact depth and normal maps, gt_mesh.ply)\n"
                    "with Warp mesh ray casting.",
        epilog="""\
examples:
  python -m gof_warp.synthetic --list
  python -m gof_warp.synthetic --out scenes/default     (small, CPU-friendly)
  python -m gof_warp.synthetic --preset thin --out scenes/thin --resolution 800 800 --device cuda""",
        formatter_class=HelpFormatter,
    )
    ap.add_argument("--preset", default="default", help="scene preset (see --list; default: %(default)s)")
    ap.add_argument("--out", help="output folder (no default: required unless --list; it must not exist or be empty, unless --force)")
    ap.add_argument("--views", type=int, default=None, help="number of training views (default: the preset's)")
    ap.add_argument("--resolution", type=int, nargs=2, metavar=("W", "H"), default=None,
                    help="image size (default: the preset's small CPU size; benchmarks use 800 800)")
    ap.add_argument("--seed", type=int, default=0, help="camera rig rotation and noise texture (default: 0)")
    ap.add_argument("--supersample", type=int, default=None, help="samples per pixel axis for colour and alpha (default: the preset's)")
    ap.add_argument("--mesh", default=None, help="textured OBJ (or a folder with one) for --preset spot (default: none)")
    ap.add_argument("--device", default=None, help="Warp device, e.g. cpu or cuda:0 (default: cuda if available)")
    ap.add_argument("--force", action="store_true", help="replace a non-empty output folder that is a synthetic scene "
                                                          "written by this command (any other is refused)")
    ap.add_argument("--list", action="store_true", help="list the presets and what each stresses, then exit")
    ap.add_argument("-q", "--quiet", action="store_true", help="only print errors")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure_output(args.quiet)

    def body():
        from ..synthetic import get_preset, list_presets, make_scene

        if args.list:
            for name in list_presets():
                print(f"{name:12s} {get_preset(name).intent}")
            return 0
        if not args.out:
            raise GofError("--out is required (the folder to write the scene into)")
        out = make_scene(args.preset, args.out, views=args.views, resolution=args.resolution, seed=args.seed,
                         device=args.device, force=args.force, mesh_path=args.mesh, supersample=args.supersample)
        if not args.quiet:
            print(out)

    return run_command(body)


if __name__ == "__main__":
    sys.exit(main())
