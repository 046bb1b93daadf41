"""Tile culling changes nothing: render a trained model from every camera of its scene with
``RenderConfig(tile_cull=True)`` and ``False`` and report the largest difference of each output (and of the
gradients of a fixed random weighted sum of the outputs), on the device where it runs.

    python benchmarks/render/cull_identity.py MODEL.ply SCENE [--out result.json]

The CPU tests check bitwise identity on small scenes; this checks a real model on the GPU, where the
kernels are compiled differently (fused multiply-adds are off in the binning module for that reason).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from gof_warp.data import load_scene  # noqa: E402
from gof_warp.devices import resolve_device  # noqa: E402
from gof_warp.model import Gaussians  # noqa: E402
from gof_warp.render import RenderConfig, render  # noqa: E402

OUTPUTS = ("rgb", "alpha", "depth", "median_depth", "normal", "distortion")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model")
    ap.add_argument("scene")
    ap.add_argument("--device", default="auto")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    device = resolve_device(a.device)
    g = Gaussians.load_ply(a.model, device=device).requires_grad_(True)
    scene = load_scene(a.scene)
    worst = {k: 0.0 for k in OUTPUTS}
    worst_grad, floor = {}, {}
    for view in scene.train + scene.test:
        results = []
        for cull in (True, False, False):  # the second unculled render: the floor of atomics' summation order
            cfg = RenderConfig(tile_cull=cull, background=tuple(float(c) for c in scene.background))
            for p in g.params.values():
                p.grad = None
            out = render(g, view.camera, config=cfg)
            gen = torch.Generator(device=device).manual_seed(0)
            loss = sum((out[k] * torch.rand(out[k].shape, generator=gen, device=device)).sum() for k in OUTPUTS)
            loss.backward()
            results.append(({k: out[k].detach().clone() for k in OUTPUTS},
                            {n: p.grad.detach().clone() for n, p in g.params.items()}))
        (o1, g1), (o0, g0), (_, g00) = results
        for k in OUTPUTS:
            worst[k] = max(worst[k], float((o1[k] - o0[k]).abs().max()))
        for n in g1:
            if g0[n].numel() == 0:
                continue
            scale = float(g0[n].abs().max()) or 1.0
            worst_grad[n] = max(worst_grad.get(n, 0.0), float((g1[n] - g0[n]).abs().max()) / scale)
            floor[n] = max(floor.get(n, 0.0), float((g00[n] - g0[n]).abs().max()) / scale)
    result = {"model": a.model, "gaussians": len(g), "views": len(scene.train) + len(scene.test),
              "device": torch.cuda.get_device_name(device) if device.startswith("cuda") else "cpu",
              "max_abs_output_difference": worst, "max_relative_gradient_difference": worst_grad,
              "same_without_culling_twice": floor}
    print(json.dumps(result, indent=1))
    if a.out:
        Path(a.out).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
