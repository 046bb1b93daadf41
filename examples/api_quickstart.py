"""Train, extract and score a GOF mesh from Python: the README's API example, runnable.

    python examples/api_quickstart.py [--out DIR] [--iterations 200] [--views 10] [--size 48] [--device cpu]
        [--eval-density D]

With the tiny defaults it runs on a CPU in a minute or two (longer the first time Warp compiles its kernels):
a small synthetic scene with an exact ground-truth mesh is generated, trained, meshed by marching tetrahedra
on the opacity field and scored. For your own data, pass a scene folder to
``gof_warp.load_scene`` instead and train with a real preset (``python -m gof_warp.train`` does that).
Prints the test PSNR, the mesh size and its accuracy against the ground truth; ``main`` returns them.
"""

import argparse
import math
import tempfile
from pathlib import Path

import torch
import trimesh

import gof_warp
from gof_warp.rendering.render import render  # the function: once loaded, the module gof_warp.rendering.render shadows gof_warp.rendering.render
from gof_warp.training.trainer import TrainConfig, Trainer


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None, help="folder for the scene and the run (default: a temporary one)")
    ap.add_argument("--iterations", type=int, default=200)
    ap.add_argument("--views", type=int, default=10, help="training views of the synthetic scene")
    ap.add_argument("--size", type=int, default=48, help="image width and height in pixels")
    ap.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    ap.add_argument("--eval-density", type=float, default=None,
                    help="scoring: surface sample spacing (default: ~300k samples on the ground truth)")
    a = ap.parse_args(argv)
    device = a.device or ("cuda" if torch.cuda.is_available() else "cpu")
    with tempfile.TemporaryDirectory() as tmp:
        return quickstart(Path(a.out or tmp), a.iterations, a.views, a.size, device, a.eval_density)


def quickstart(folder: Path, iterations: int, views: int, size: int, device: str, eval_density=None) -> dict:
    # --- the README's example, from here (the README writes its defaults as numbers) ---
    scene_dir = gof_warp.make_scene("default", folder / "scene", views=views, resolution=(size, size),
                                    device=device, force=True)  # or your own folder: COLMAP, Blender, DTU ...
    scene = gof_warp.load_scene(scene_dir)
    config = TrainConfig(iterations=iterations, checkpoint_every=0)  # every setting: docs/config.md
    # a random start in the box the objects lie in, few points, Lambertian colour (as the `quick` preset)
    config.model.init, config.model.init_box, config.model.sh_degree = "random", (-1, -1, -1, 1, 1, 1), 1
    config.model.random_init_points = 2000
    # GOF's schedule, shortened to this run: densify from 50 every 50 up to 80 %, regularisers from half-way
    config.densify.start_iter, config.densify.interval, config.densify.stop_iter = 50, 50, iterations * 4 // 5
    config.densify.filter_3d_until_iter, config.loss.regularization_from_iter = iterations * 4 // 5, iterations // 2
    metrics = Trainer(scene, config, folder / "run", device).run()  # writes run/point_cloud.ply, run/metrics.json

    gaussians = gof_warp.Gaussians.load_ply(folder / "run" / "point_cloud.ply", device=device)  # 3DGS layout
    image = render(gaussians, scene.test[0].camera)["rgb"]  # [H, W, 3], differentiable (torch autograd)
    (verts, faces), = gof_warp.extract_mesh(gaussians, scene.train_cameras)  # one mesh per level (0.5)
    report = gof_warp.evaluate_mesh(trimesh.Trimesh(verts, faces, process=False), scene_dir / "gt_mesh.ply",
                                    density=eval_density)  # None: ~300k samples on the ground truth
    # --- to here ---

    scores = report["metrics"]
    result = {"test_psnr": metrics["test"]["psnr"], "gaussians": len(gaussians), "image_shape": tuple(image.shape),
              "faces": int(len(faces)), "chamfer": scores["chamfer"], "tau": scores["tau"][0],
              "fscore": scores["fscore"][0]}
    if not all(v is not None and math.isfinite(v) for v in (result["test_psnr"], result["chamfer"], result["fscore"])):
        raise SystemExit(f"a score is not finite: {result}")
    print(f"trained {iterations} iterations in {metrics['train_time_s']:.1f} s: {result['gaussians']} Gaussians, "
          f"test PSNR {result['test_psnr']:.2f} dB")
    print(f"mesh: {result['faces']} faces; against the exact mesh: Chamfer {result['chamfer']:.4f}, "
          f"F-score {result['fscore']:.3f} at tau {result['tau']:.4f}")
    return result


if __name__ == "__main__":
    main()
