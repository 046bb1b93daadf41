"""``python -m gof_warp.inspect SCENE``: what gof_warp makes of a scene folder.

Prints the detected format, camera model(s) (and whether they were undistorted), view counts,
resolution(s), focal lengths, extent, masks, initial points, image memory, the training preset that
``train --config auto`` picks with its reason (:mod:`gof_warp.training.presets`) and the readers' warnings.
Loads (decodes) every image, so it also proves that the scene is readable. Exit status 0 on success,
2 with ``error: <message>`` on stderr (no traceback) when the scene cannot be read.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from .common import HelpFormatter, configure_output, downscale_arg, run_command

_PINHOLE = ("PINHOLE", "SIMPLE_PINHOLE")


def describe(scene) -> dict:
    """:meth:`Scene.summary` plus camera details (focal range, undistortion)."""
    info = scene.summary()
    cams = [v.camera for v in scene.all_views]
    fx = np.array([c.fx for c in cams])
    fy = np.array([c.fy for c in cams])
    info["undistorted"] = any(m not in _PINHOLE for m in info["camera_models"])
    info["focal_px"] = [round(float(fx.min()), 2), round(float(fx.max()), 2), round(float(fy.min()), 2), round(float(fy.max()), 2)]
    info["camera_centre_distance_from_origin"] = [
        round(float(d), 4) for d in (lambda d: (d.min(), d.max()))(np.linalg.norm([c.center for c in cams], axis=1))
    ]
    return info


def format_text(info: dict) -> str:
    models = ", ".join(info["camera_models"]) or "?"
    if info["undistorted"]:
        models += " (undistorted to PINHOLE)"
    fx0, fx1, fy0, fy1 = info["focal_px"]
    d0, d1 = info["camera_centre_distance_from_origin"]
    lines = [
        f"scene:          {info['source']}",
        f"format:         {info['format']}",
        f"camera model:   {models}",
        f"views:          {info['train_views'] + info['test_views']} ({info['train_views']} train, {info['test_views']} test)",
        f"resolution:     {', '.join(info['resolutions'])}",
        f"focal (px):     fx {fx0:g}..{fx1:g}, fy {fy0:g}..{fy1:g}",
        f"extent:         {info['extent']:g} (camera centres {d0:g}..{d1:g} from the origin)",
        f"masks:          {info['masks']}",
        f"initial points: {info['initial_points']}",
        f"background:     {tuple(info['background'])}",
        f"image memory:   {info['image_memory_mb']} MB",
        f"train preset:   {info['preset']} ({info['preset_reason']})",
    ]
    warnings = info["warnings"]
    lines.append(f"warnings:       {len(warnings)}")
    lines += [f"  - {w}" for w in warnings]
    return "\n".join(lines)


DESCRIPTION = """\
What gof_warp makes of a scene folder: format, camera models (and whether they were undistorted),
view counts, resolutions, focal lengths, extent, masks, initial points, image memory, the training
preset that "train --config auto" picks with its reason, and the readers' warnings. Every image is
decoded, so a clean run also proves the scene readable. Exit code 0 on success, 2 with
"error: <message>" on stderr when the scene cannot be read."""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gof_warp.inspect", description=DESCRIPTION,
                                     formatter_class=HelpFormatter)
    parser.add_argument("scene", help="scene folder (COLMAP, Blender, instant-ngp or NeuS/DTU)")
    parser.add_argument("--downscale", type=downscale_arg, default=1, metavar="N",
                        help="divide the resolution by the integer N >= 1 (default: 1, full size)")
    parser.add_argument("--test-every", type=int, default=8, help="every N-th view is a test view (0: none)")
    parser.add_argument("--memory-budget", type=float, default=8.0, help="decoded-image budget in GB")
    parser.add_argument("--undistort", choices=("valid", "same"), default="valid", help="pinhole camera after undistortion: valid (only pixels with data) or same (the original field of view)")
    parser.add_argument("--device", default=None, help="Warp device for undistortion (default: cuda if available, else cpu)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON instead of text")
    args = parser.parse_args(argv)
    configure_output(quiet=True)  # the CLI's stdout is the summary, not Warp's banner
    from ..data import DataConfig, load_scene

    def body():
        config = DataConfig(
            downscale=args.downscale,
            test_every=args.test_every,
            image_memory_budget_gb=args.memory_budget,
            undistort=args.undistort,
        )
        from ..training.presets import choose_preset

        info = describe(load_scene(args.scene, config, device=args.device))
        choice = choose_preset(args.scene)
        info["preset"], info["preset_reason"] = choice.preset, choice.reason
        print(json.dumps(info, indent=2) if args.json else format_text(info))

    return run_command(body)


if __name__ == "__main__":
    sys.exit(main())
