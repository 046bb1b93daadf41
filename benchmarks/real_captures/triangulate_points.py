"""Triangulate a scene's points from its known poses here and write them as ``points3d.ply`` for the GPU machine.

The GPU machine has no pycolmap, so the triangulation that `train` would run there (``model.init = auto``) runs on
this machine and its points travel with the scene (the Blender and instant-ngp loaders read a ``points3d.ply``
beside the cameras). Same points as `train` gets: ``gof_warp.init_points.initial_point_cloud(scene, "sfm")``.

    python benchmarks/real_captures/triangulate_points.py SCENE OUT/points3d.ply
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from gof_warp.data import load_scene
from gof_warp.init_points import initial_point_cloud
from gof_warp.ply import write_ply_vertices


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("out")
    a = ap.parse_args()
    t0 = time.perf_counter()
    scene = load_scene(a.scene)
    points, colours, info = initial_point_cloud(scene, "sfm", random_points=0)
    rgb = np.asarray(colours if colours is not None else np.full((len(points), 3), 128))
    if rgb.dtype != np.uint8:
        rgb = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)
    write_ply_vertices(a.out, {"x": points[:, 0].astype(np.float32), "y": points[:, 1].astype(np.float32),
                               "z": points[:, 2].astype(np.float32), "red": rgb[:, 0], "green": rgb[:, 1],
                               "blue": rgb[:, 2]})
    print(f"{len(points)} points ({info.get('source')}) in {time.perf_counter() - t0:.1f} s -> {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
