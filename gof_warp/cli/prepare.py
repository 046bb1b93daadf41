"""``python -m gof_warp.prepare PHOTOS --out SCENE``: camera poses for a folder of plain photos (pycolmap SfM, CPU).

Examples::

    python -m gof_warp.prepare photos/ --out scenes/mug
    python -m gof_warp.prepare frames/ --out scenes/walk --matcher sequential --max-size 1200
"""

from __future__ import annotations

import argparse
import sys

from .common import HelpFormatter, configure_output, run_command


def build_parser() -> argparse.ArgumentParser:
    from ..data.prepare import CAMERA_MODELS, MATCHERS, PrepareConfig

    d = PrepareConfig()
    ap = argparse.ArgumentParser(
        prog="python -m gof_warp.prepare",
        description="Recover camera poses for a folder of plain photos with structure from motion (pycolmap:\n"
                    "SIFT features, matching, incremental mapping; CPU) and write an undistorted (PINHOLE) COLMAP\n"
                    "scene that `train` reads: SCENE/images/, SCENE/sparse/0/ and the report SCENE/prepare.json.",
        epilog="""\
examples:
  python -m gof_warp.prepare photos/ --out scenes/mug
  python -m gof_warp.prepare frames/ --out scenes/walk --matcher sequential --max-size 1200
  python -m gof_warp.train scenes/mug""",
        formatter_class=HelpFormatter,
    )
    ap.add_argument("photos", help="folder holding the photos (.jpg, .png, ...; at least 3, overlapping)")
    ap.add_argument("--out", required=True, help="scene folder to write (no default: required; it must not exist "
                                                 "or be empty, unless --overwrite)")
    ap.add_argument("--matcher", choices=MATCHERS, default=d.matcher,
                    help="which photo pairs to match: exhaustive (every pair: unordered photos), sequential "
                         "(neighbours in name order: video frames), auto (exhaustive up to 150 photos, else sequential)")
    ap.add_argument("--max-size", type=int, default=d.max_size, metavar="PX",
                    help="downscale photos whose longer side exceeds PX before SfM (the scene's images have this "
                         "size; 0 keeps the full size)")
    ap.add_argument("--camera-model", choices=CAMERA_MODELS, default=d.camera_model,
                    help="lens model estimated by SfM (the scene is written undistorted)")
    ap.add_argument("--single-camera", action=argparse.BooleanOptionalAction, default=d.single_camera,
                    help="one camera (intrinsics) shared by all photos, e.g. one phone at a fixed zoom; "
                         "--no-single-camera estimates one per photo")
    ap.add_argument("--max-features", type=int, default=d.max_features, help="SIFT features per photo")
    ap.add_argument("--threads", type=int, default=d.num_threads, help="CPU threads (-1: all)")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace an output folder that an earlier prepare wrote (one holding prepare.json; "
                         "any other non-empty folder is refused)")
    ap.add_argument("-q", "--quiet", action="store_true", help="only print errors")
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    configure_output(args.quiet)

    def body():
        from ..core.progress import Stages
        from ..data.prepare import PrepareConfig, prepare_scene

        config = PrepareConfig(matcher=args.matcher, max_size=args.max_size, camera_model=args.camera_model,
                               single_camera=args.single_camera, max_features=args.max_features,
                               num_threads=args.threads, overwrite=args.overwrite)
        r = prepare_scene(args.photos, args.out, config, Stages(quiet=args.quiet))
        if not args.quiet:
            print(f"registered {r['registered']}/{r['images']} photos, {r['points']} 3D points, "
                  f"mean reprojection error {r['mean_reprojection_error_px']:.3f} px, {r['seconds']['total']:.1f} s")
            if r["unregistered"]:
                print("not registered: " + ", ".join(f"{k} ({v})" for k, v in r["unregistered"].items()))
            print(f"scene: {args.out}  (report: prepare.json; next: python -m gof_warp.train {args.out})")

    return run_command(body, "no scene written")


if __name__ == "__main__":
    sys.exit(main())
