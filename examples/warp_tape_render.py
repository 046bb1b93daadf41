"""Render a few Gaussians from a pure Warp program (no torch) and differentiate with ``wp.Tape``.

The renderer's backward is hand-written; ``render_gaussians(..., tape=tape)`` registers it on the tape
with ``tape.record_func``, so ``tape.backward(loss)`` runs it after the loss kernel's adjoint.

    python examples/warp_tape_render.py --device cpu
"""

from __future__ import annotations

import argparse

import numpy as np
import warp as wp

from gof_warp.kernels.render_types import make_camera_params, make_raster_settings
from gof_warp.kernels.renderer import render_gaussians


@wp.kernel
def mean_squared_error(rgb: wp.array(dtype=wp.vec3), target: wp.vec3, loss: wp.array(dtype=float)):
    i = wp.tid()
    d = rgb[i] - target
    wp.atomic_add(loss, 0, wp.dot(d, d) / float(rgb.shape[0]))


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda" if wp.is_cuda_available() else "cpu")
    parser.add_argument("--num", type=int, default=8, help="number of Gaussians")
    parser.add_argument("--width", type=int, default=40)
    parser.add_argument("--height", type=int, default=30)
    args = parser.parse_args(argv)
    wp.init()
    rng = np.random.default_rng(0)
    n = args.num
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    sh = np.zeros((n, 1, 3))
    sh[:, 0] = rng.uniform(-1.0, 1.0, size=(n, 3))

    def param(x, dtype):
        return wp.array(np.asarray(x, dtype=np.float32), dtype=dtype, device=args.device, requires_grad=True)

    means = param(rng.normal(scale=0.4, size=(n, 3)), wp.vec3)
    quats = param(quats, wp.vec4)
    scales = param(rng.uniform(0.1, 0.3, size=(n, 3)), wp.vec3)
    opacities = param(rng.uniform(0.3, 0.9, size=n), float)
    sh = param(sh, wp.vec3)
    # camera 3 units in front of the origin, looking along +z (world-to-camera R = I, t = (0, 0, 3))
    cam = make_camera_params(np.eye(3), [0.0, 0.0, 3.0], 40.0, 40.0, args.width / 2, args.height / 2, args.width, args.height)
    settings = make_raster_settings(args.width, args.height)

    tape = wp.Tape()
    loss = wp.zeros(1, dtype=float, device=args.device, requires_grad=True)
    out = render_gaussians(means, quats, scales, opacities, sh, 0, cam, settings, tape=tape)
    with tape:
        wp.launch(mean_squared_error, dim=out.rgb.shape[0], inputs=[out.rgb, wp.vec3(0.5, 0.5, 0.5)], outputs=[loss], device=args.device)
    tape.backward(loss)
    result = {
        "loss": float(loss.numpy()[0]),
        "coverage": float(out.alpha.numpy().mean()),
        "grad_means_norm": float(np.linalg.norm(means.grad.numpy())),
        "grad_opacity_norm": float(np.linalg.norm(opacities.grad.numpy())),
    }
    print(", ".join(f"{k}={v:.4g}" for k, v in result.items()))
    tape.zero()
    return result


if __name__ == "__main__":
    main()
