"""Load a scene folder (any supported format) and print what it holds.

    python examples/load_scene.py [SCENE] [--downscale 2]

With no SCENE, a tiny synthetic scene is generated into a temporary folder first.
"""

import argparse
import tempfile

from gof_warp.data import DataConfig, load_scene
from gof_warp.synthetic import make_scene


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", help="scene folder (COLMAP, Blender, instant-ngp or DTU)")
    ap.add_argument("--downscale", type=float, default=1.0)
    ap.add_argument("--device", default=None, help="Warp device for undistortion/generation (cpu, cuda)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = args.scene or make_scene("default", f"{tmp}/scene", views=6, resolution=(48, 48), device=args.device)
        scene = load_scene(path, DataConfig(downscale=args.downscale), device=args.device)
        for key, value in scene.summary().items():
            print(f"{key:>16}: {value}")
        view = scene.train[0]
        print(f"first view {view.name!r}: {view.camera}")
        if scene.points is not None:
            uv, z = view.camera.project(scene.points)
            inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < view.camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < view.camera.height)
            print(f"{int(inside.sum())} of {len(scene.points)} initial points project into it")


if __name__ == "__main__":
    main()
