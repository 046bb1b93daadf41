"""One forward + backward of the renderer on ``bench_render.py``'s scene (a driver for Nsight Compute).

    ncu --kernel-name regex:screen_bounds ... python benchmarks/render/one_step.py [N] [WxH]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_render import OUTPUT_KEYS, SIZES, _loss_weights, make_camera, make_scene  # noqa: E402

import torch  # noqa: E402
import warp as wp  # noqa: E402

from gof_warp.render import RenderConfig, rasterize  # noqa: E402

if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    W, H = SIZES[sys.argv[2] if len(sys.argv) > 2 else "1920x1080"]
    wp.init()
    camera, params = make_camera(W, H), make_scene(n)
    leaves = [p.clone().requires_grad_(True) for p in params]
    weights = _loss_weights(rasterize(*params, camera, config=RenderConfig()))
    out = rasterize(*leaves, camera, config=RenderConfig(), check_values=False)
    sum((out[k] * weights[k]).sum() for k in OUTPUT_KEYS).backward()
    torch.cuda.synchronize()
