"""Fit Gaussians to a few images with our renderer on ``wp.Tape`` and ``warp.optim.Adam`` (no torch).

Target images: ``--target`` random Gaussians rendered from ``--views`` cameras on a ring. The fit starts
from ``--num`` other random Gaussians (grey, half opaque) and minimises the mean squared colour error.

What runs on the tape, per iteration:

1. ``activate`` (a plain kernel, automatic adjoint): raw parameters → ``exp`` scales, ``sigmoid``
   opacities, unit quaternions, degree-0 SH (``sh [N, 1] vec3``).
2. ``render_gaussians(..., tape=tape)`` per view: our forward, and its **hand-written** backward recorded
   with ``tape.record_func`` (Warp's automatic adjoint is wrong through the compositing loop, which
   carries state from Gaussian to Gaussian).
3. ``squared_error`` (automatic adjoint) adds each view's MSE into one loss.

``tape.backward(loss)`` then runs 3 → 2 → 1 and ``warp.optim.Adam`` steps the raw parameters (one
optimiser per learning rate; Adam takes ``float32``/``vec3`` arrays, so quaternions are a flat
``float32 [4N]`` array).

    python examples/warp_fit_gaussians.py --device cpu --iterations 150
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
import warp as wp
from warp.optim import Adam

from gof_warp.core.camera import look_at
from gof_warp.kernels import make_camera_params, make_raster_settings, render_forward, render_gaussians

SH_C0 = 0.28209479177387814  # degree-0 SH constant: colour = SH_C0 · sh + 0.5


@wp.kernel
def activate(raw_means: wp.array(dtype=wp.vec3), raw_quats: wp.array(dtype=float), raw_scales: wp.array(dtype=wp.vec3),
             raw_opacities: wp.array(dtype=float), raw_sh: wp.array(dtype=wp.vec3),
             means: wp.array(dtype=wp.vec3), quats: wp.array(dtype=wp.vec4), scales: wp.array(dtype=wp.vec3),
             opacities: wp.array(dtype=float), sh: wp.array2d(dtype=wp.vec3)):
    """Raw → renderer parameters: ``exp`` scales, ``sigmoid`` opacities, normalised wxyz quaternions."""
    i = wp.tid()
    means[i] = raw_means[i]
    q = wp.vec4(raw_quats[4 * i], raw_quats[4 * i + 1], raw_quats[4 * i + 2], raw_quats[4 * i + 3])
    quats[i] = q / wp.sqrt(wp.dot(q, q) + 1.0e-12)
    s = raw_scales[i]
    scales[i] = wp.vec3(wp.exp(s[0]), wp.exp(s[1]), wp.exp(s[2]))
    opacities[i] = 1.0 / (1.0 + wp.exp(-raw_opacities[i]))
    sh[i, 0] = raw_sh[i]


@wp.kernel
def squared_error(rgb: wp.array(dtype=wp.vec3), target: wp.array(dtype=wp.vec3), scale: float, loss: wp.array(dtype=float)):
    """``loss[0] += scale · |rgb[p] − target[p]|²`` summed over pixels ``p`` (``[H*W]``)."""
    p = wp.tid()
    d = rgb[p] - target[p]
    wp.atomic_add(loss, 0, scale * wp.dot(d, d))


def random_gaussians(rng, n: int, extent: float, scale: tuple[float, float]) -> dict:
    """Raw parameters (numpy) of ``n`` random Gaussians in ``[-extent, extent]³``."""
    return {
        "means": rng.uniform(-extent, extent, (n, 3)),
        "quats": rng.normal(size=(n, 4)),
        "scales": np.log(rng.uniform(*scale, (n, 3))),
        "opacities": rng.uniform(0.5, 3.0, n),  # sigmoid → 0.62 … 0.95
        "sh": (rng.uniform(0.05, 0.95, (n, 3)) - 0.5) / SH_C0,
    }


class Model:
    """Raw parameters as ``wp.array``s (with gradients) and the activated arrays the renderer reads."""

    def __init__(self, raw: dict, device: str):
        def arr(x, dtype):
            return wp.array(np.asarray(x, np.float32), dtype=dtype, device=device, requires_grad=True)

        self.n = raw["means"].shape[0]
        self.device = device
        self.raw = {"means": arr(raw["means"], wp.vec3), "quats": arr(raw["quats"].ravel(), float),
                    "scales": arr(raw["scales"], wp.vec3), "opacities": arr(raw["opacities"], float),
                    "sh": arr(raw["sh"], wp.vec3)}

    def activated(self, tape: wp.Tape | None = None) -> tuple:
        """``(means, quats, scales, opacities, sh)`` for the renderer, recorded on ``tape`` when given."""
        n, dev = self.n, self.device
        out = [wp.empty(n, dtype=wp.vec3, device=dev, requires_grad=True), wp.empty(n, dtype=wp.vec4, device=dev, requires_grad=True),
               wp.empty(n, dtype=wp.vec3, device=dev, requires_grad=True), wp.empty(n, dtype=float, device=dev, requires_grad=True),
               wp.empty((n, 1), dtype=wp.vec3, device=dev, requires_grad=True)]
        launch = dict(kernel=activate, dim=n, inputs=list(self.raw.values()), outputs=out, device=dev)
        if tape is None:
            wp.launch(**launch)
        else:
            with tape:
                wp.launch(**launch)
        return tuple(out)


def ring_cameras(views: int, size: int, distance: float = 3.0) -> list:
    """``views`` cameras on a tilted ring around the origin, ``size × size`` pixels, 50° field of view."""
    focal = 0.5 * size / math.tan(math.radians(25.0))
    cams = []
    for k in range(views):
        a = 2 * math.pi * k / views
        eye = distance * np.array([math.cos(a), math.sin(a), 0.4])
        c = look_at(eye, [0.0, 0.0, 0.0], fx=focal, width=size, height=size)
        cams.append(make_camera_params(c.R, c.t, c.fx, c.fy, c.cx, c.cy, c.width, c.height))
    return cams


def fit(args) -> dict:
    device = args.device
    rng = np.random.default_rng(args.seed)
    cams = ring_cameras(args.views, args.size)
    settings = make_raster_settings(args.size, args.size)
    target_model = Model(random_gaussians(rng, args.target, 0.6, (0.08, 0.25)), device)
    target_params = target_model.activated()
    targets = [render_forward(*target_params, 0, cam, settings)[0].rgb for cam in cams]

    init = random_gaussians(rng, args.num, 0.7, (0.05, 0.12))
    init["opacities"][:] = 0.0  # sigmoid(0) = 0.5
    init["sh"][:] = 0.0  # grey
    model = Model(init, device)
    lrs = {"means": 0.01, "quats": 0.01, "scales": 0.02, "opacities": 0.05, "sh": 0.1}
    optimisers = {k: Adam([model.raw[k]], lr=lr) for k, lr in lrs.items()}
    pixels = args.size * args.size
    scale = 1.0 / (3.0 * pixels * len(cams))  # mean over views, pixels and channels

    losses = []
    start = time.perf_counter()
    for it in range(args.iterations):
        tape = wp.Tape()
        params = model.activated(tape)
        loss = wp.zeros(1, dtype=float, device=device, requires_grad=True)
        for cam, target in zip(cams, targets):
            out = render_gaussians(*params, 0, cam, settings, tape=tape)
            with tape:
                wp.launch(squared_error, dim=pixels, inputs=[out.rgb, target, scale], outputs=[loss], device=device)
        tape.backward(loss)
        for k, opt in optimisers.items():
            opt.step([model.raw[k].grad])
        tape.zero()  # zeroes the raw parameters' gradients too (inputs of the recorded activate launch)
        losses.append(float(loss.numpy()[0]))
        if it % max(1, args.iterations // 5) == 0 or it == args.iterations - 1:
            print(f"iteration {it:4d}: mse {losses[-1]:.5f}  psnr {-10 * math.log10(losses[-1]):.2f} dB")
    seconds = time.perf_counter() - start
    return {"mse_first": losses[0], "mse_last": losses[-1], "psnr_first": -10 * math.log10(losses[0]),
            "psnr_last": -10 * math.log10(losses[-1]), "iterations": args.iterations, "seconds": seconds}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's current device)")
    parser.add_argument("--num", type=int, default=120, help="Gaussians fitted")
    parser.add_argument("--target", type=int, default=60, help="Gaussians of the target images")
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--size", type=int, default=64, help="image width and height in pixels")
    parser.add_argument("--iterations", type=int, default=150)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    wp.init()
    args.device = args.device or str(wp.get_device())
    result = fit(args)
    print(", ".join(f"{k}={v:.4g}" for k, v in result.items()))
    return result


if __name__ == "__main__":
    main()
