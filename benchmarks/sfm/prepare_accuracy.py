"""Accuracy and wall time of ``gof-warp prepare`` on real photos against reference poses.

    python benchmarks/sfm/prepare_accuracy.py PHOTOS REFERENCE OUT.json [--scene DIR] [prepare options]

REFERENCE is an instant-ngp/nerfstudio ``transforms.json`` (OpenGL camera-to-world, converted here to the
OpenCV/COLMAP convention) or a COLMAP model folder (``sparse/0``). Photos are matched to reference frames by
file name. Reported after a similarity alignment (Umeyama) of the camera centres: registered fraction, median
and max rotation error (degrees), median and max position error (% of the camera spread: RMS distance of the
reference centres from their centroid), SfM wall time.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gof_warp.data.prepare import PrepareConfig, pose_errors, prepare_scene, read_scene_poses

GL_TO_CV = np.diag([1.0, -1.0, -1.0])


def reference_poses(ref: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{file name: (world-to-camera R in the OpenCV convention, camera centre)}``."""
    if ref.suffix == ".json":
        meta = json.loads(ref.read_text())
        poses = {}
        for f in meta["frames"]:
            c2w = np.asarray(f["transform_matrix"], np.float64)[:3]
            R_c2w = c2w[:, :3] @ GL_TO_CV  # OpenGL axes (x right, y up, z back) → OpenCV (x right, y down, z forward)
            poses[Path(f["file_path"]).name] = (R_c2w.T, c2w[:, 3].copy())
        return poses
    return read_scene_poses(ref.parent.parent if ref.name.isdigit() and ref.parent.name == "sparse" else ref)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("photos")
    ap.add_argument("reference")
    ap.add_argument("out_json")
    ap.add_argument("--scene", help="where to write the prepared scene (default: a temporary folder)")
    ap.add_argument("--matcher", default="auto")
    ap.add_argument("--max-size", type=int, default=1600)
    ap.add_argument("--camera-model", default="SIMPLE_RADIAL")
    a = ap.parse_args(argv)
    ref = reference_poses(Path(a.reference))
    cfg = PrepareConfig(matcher=a.matcher, max_size=a.max_size, camera_model=a.camera_model)
    with tempfile.TemporaryDirectory() as tmp:
        scene = Path(a.scene) if a.scene else Path(tmp) / "scene"
        t0 = time.perf_counter()
        report = prepare_scene(a.photos, scene, cfg)
        wall = time.perf_counter() - t0
        est = read_scene_poses(scene)
    common = sorted(set(est) & set(ref))
    err = pose_errors([est[k][0] for k in common], [est[k][1] for k in common],
                      [ref[k][0] for k in common], [ref[k][1] for k in common])
    result = {
        "photos": str(Path(a.photos).resolve()),
        "reference": str(Path(a.reference).resolve()),
        "images": report["images"],
        "registered": report["registered"],
        "registered_fraction": report["registered_fraction"],
        "compared": len(common),
        "median_rotation_deg": round(err["median_rotation_deg"], 4),
        "max_rotation_deg": round(err["max_rotation_deg"], 4),
        "median_position_pct_of_spread": round(err["median_position_pct"], 4),
        "max_position_pct_of_spread": round(err["max_position_pct"], 4),
        "points": report["points"],
        "mean_reprojection_error_px": report["mean_reprojection_error_px"],
        "wall_seconds": round(wall, 1),
        "stage_seconds": report["seconds"],
        "camera": report["cameras_estimated"],
        "unregistered": report["unregistered"],
        "config": report["config"],
    }
    Path(a.out_json).write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k not in ("camera", "config", "stage_seconds")}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
