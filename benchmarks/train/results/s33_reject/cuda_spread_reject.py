import sys, torch, numpy as np
sys.path.insert(0, "tests")
import test_pixel_conic as T
from gof_warp.kernels import renderer
from reference_render import make_camera, random_scene
from gof_warp.render import RenderConfig, rasterize
device = "cuda"
cam = make_camera(width=97, height=71, fx=90.0, fy=80.0)
scene = random_scene(cam, 300, 2, seed=11, n_behind=3, n_near=8, spread=1.5)
flat = torch.rand(300, generator=torch.Generator().manual_seed(0)) < 0.5
scene["scales"][flat, 2] *= 0.02
names = ("means", "quats", "scales", "opacities", "sh")
for ts in (16, 8):
    cfg = RenderConfig(tile_size=ts, background=(0.2, 0.5, 1.0))
    def run():
        leaves = [scene[k].float().to(device).clone().requires_grad_(True) for k in names]
        out = rasterize(*leaves, cam, config=cfg)
        w = torch.Generator().manual_seed(1)
        loss = sum((out[k] * torch.randn(out[k].shape, generator=w).to(device)).sum() for k in sorted(out) if out[k].is_floating_point())
        loss.backward()
        return {f"grad_{k}": x.grad.cpu() for k, x in zip(names, leaves)}
    orig = renderer.pixel_conics
    A = [run() for _ in range(4)]
    renderer.pixel_conics = T._no_reject
    B = [run() for _ in range(4)]
    renderer.pixel_conics = orig
    for key in A[0]:
        within_a = max(float((A[0][key] - a[key]).abs().max()) for a in A[1:])
        within_b = max(float((B[0][key] - b[key]).abs().max()) for b in B[1:])
        across = max(float((a[key] - b[key]).abs().max()) for a in A for b in B)
        print(ts, key, "max", round(float(A[0][key].abs().max()), 3), "with-with", within_a, "without-without", within_b, "across", across)
