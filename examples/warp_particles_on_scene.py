"""Particles dropped onto a reconstructed scene, colliding with its baked GOF opacity volume in a Warp kernel.

The scene is solid where the opacity volume (``python -m gof_warp.extract RUN --volume``) reaches 0.5. Each
step is semi-implicit Euler under gravity; a particle whose new position is solid is projected back onto the
0.5 level set along the volume's gradient (a few Newton steps) and its velocity loses the normal component
(restitution) and part of the tangential one (friction). Particles do not collide with each other. Needs only
Warp, numpy and Pillow (no torch, no gof_warp):

    python examples/warp_particles_on_scene.py --nvdb RUN/opacity_volume.nvdb --up 0,0,1 --out OUT

Writes ``OUT/particles_on_scene.png`` (a vertical slice of the opacity, particles in red) and
``OUT/particles_on_scene.npz`` (``positions``, ``velocities``, ``fell`` = left the volume's box). Without
``--nvdb`` it uses the stand-in volume of ``warp_query_volume.py`` (a ground plane and a sphere).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

LEVEL = 0.5  # opacity >= LEVEL is solid
NEWTON_STEPS = 4  # projections back onto the level set per contact


@wp.func
def sample_world(volume: wp.uint64, x: wp.vec3) -> float:
    return wp.volume_sample_f(volume, wp.volume_world_to_index(volume, x), wp.Volume.LINEAR)


@wp.func
def gradient_world(volume: wp.uint64, x: wp.vec3) -> wp.vec3:
    """∂opacity/∂x in world units (index-space gradient through the inverse index-to-world map)."""
    g = wp.vec3()
    wp.volume_sample_grad_f(volume, wp.volume_world_to_index(volume, x), wp.Volume.LINEAR, g)
    return wp.vec3(wp.dot(g, wp.volume_world_to_index_dir(volume, wp.vec3(1.0, 0.0, 0.0))),
                   wp.dot(g, wp.volume_world_to_index_dir(volume, wp.vec3(0.0, 1.0, 0.0))),
                   wp.dot(g, wp.volume_world_to_index_dir(volume, wp.vec3(0.0, 0.0, 1.0))))


@wp.kernel
def step_particles(volume: wp.uint64, gravity: wp.vec3, dt: float, level: float, restitution: float,
                   friction: float, lo: wp.vec3, hi: wp.vec3,
                   x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), fell: wp.array(dtype=wp.int32)):
    """One semi-implicit Euler step with collisions against {opacity >= level}; updates x, v in place."""
    t = wp.tid()
    if fell[t] != 0:
        return
    vel = v[t] + gravity * dt
    p = x[t] + vel * dt
    f = sample_world(volume, p)
    if f >= level:
        n = -wp.normalize(gravity)  # fallback normal where the gradient vanishes: against gravity
        for _ in range(NEWTON_STEPS):
            g = gradient_world(volume, p)
            gg = wp.dot(g, g)
            if gg > 1e-12:
                n = -g / wp.sqrt(gg)  # outward: opacity decreases outwards
                p = p - g * ((f - level) / gg) + n * 1e-4  # Newton step onto the level set, just outside
            else:
                p = x[t]
            f = sample_world(volume, p)
            if f < level:
                break
        if f >= level:
            p = x[t]  # could not get out: stay at the last free position
        vn = wp.dot(vel, n)
        if vn < 0.0:
            vt = vel - vn * n
            vel = vt * (1.0 - friction) - restitution * vn * n
    if p[0] < lo[0] or p[1] < lo[1] or p[2] < lo[2] or p[0] > hi[0] or p[1] > hi[1] or p[2] > hi[2]:
        fell[t] = 1
    x[t] = p
    v[t] = vel


@wp.kernel
def sample_points(volume: wp.uint64, points: wp.array(dtype=wp.vec3), out: wp.array(dtype=float)):
    t = wp.tid()
    out[t] = sample_world(volume, points[t])


def _query_example():
    """The sibling example (stand-in volume, bounds) loaded by path: examples are not a package."""
    path = Path(__file__).with_name("warp_query_volume.py")
    spec = importlib.util.spec_from_file_location("warp_query_volume", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _basis(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to ``up`` (the picture's horizontal axis and the slice's normal)."""
    a = np.eye(3)[np.argmin(np.abs(up))]
    e1 = np.cross(up, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(up, e1)


def picture(vol, device, x: np.ndarray, centre, up, e1, half: float, path: Path, size: int = 400):
    """A vertical slice through ``centre`` (spanned by e1 and up) shaded by opacity (dark: solid), particles drawn."""
    from PIL import Image, ImageDraw

    s = np.linspace(-half, half, size)
    a, b = np.meshgrid(s, s[::-1], indexing="xy")  # image row 0 at the top (+up)
    pts = centre + a[..., None] * e1 + b[..., None] * up
    out = wp.zeros(size * size, dtype=float, device=device)
    wp.launch(sample_points, dim=size * size, device=device,
              inputs=[vol.id, wp.array(pts.reshape(-1, 3).astype(np.float32), dtype=wp.vec3, device=device)],
              outputs=[out])
    o = out.numpy().reshape(size, size)
    grey = (235 - 150 * np.clip(o, 0, 1)).astype(np.uint8)
    grey[np.abs(o - LEVEL) < 0.04] = 40  # the 0.5 level set
    img = Image.fromarray(np.stack([grey] * 3, -1))
    draw = ImageDraw.Draw(img)
    rel = x - centre
    u = (rel @ e1 + half) / (2 * half) * (size - 1)
    w = (half - rel @ up) / (2 * half) * (size - 1)
    near = np.abs(rel @ np.cross(up, e1)) < 0.1 * half  # particles near the slice: red; the rest: pink, behind
    for sel, r, colour in ((~near, 1.0, (240, 170, 170)), (near, 2.0, (220, 30, 30))):
        for pu, pw in zip(u[sel], w[sel]):
            draw.ellipse([pu - r, pw - r, pu + r, pw + r], fill=colour)
    img.save(path)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda" if wp.is_cuda_available() else "cpu")
    parser.add_argument("--nvdb", default=None, help="a baked opacity volume (.nvdb); default: a stand-in")
    parser.add_argument("--up", default="0,0,1", help="the scene's up direction (gravity points against it)")
    parser.add_argument("--particles", type=int, default=2000)
    parser.add_argument("--steps", type=int, default=800)
    parser.add_argument("--dt", type=float, default=None, help="time step (s); default: 1/4 voxel per step at "
                        "the speed of a fall through the box")
    parser.add_argument("--restitution", type=float, default=0.2)
    parser.add_argument("--friction", type=float, default=0.3, help="tangential speed lost per contact step")
    parser.add_argument("--drop", type=float, default=0.5, help="drop area: this fraction of the box, centred")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default=".", help="folder of the picture and the .npz")
    args = parser.parse_args(argv)
    wp.init()
    qx = _query_example()
    if args.nvdb:
        with open(args.nvdb, "rb") as f:
            vol = wp.Volume.load_from_nvdb(f, device=args.device)
    else:
        vol = qx.stand_in_volume(args.device)
    lo, hi = qx.world_bounds(vol)
    up = np.array([float(c) for c in args.up.split(",")])
    up /= np.linalg.norm(up)
    e1, e2 = _basis(up)
    centre = 0.5 * (lo + hi)
    corners = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)]) * (hi - lo) + lo
    height = float(((corners - centre) @ up).max())  # box half-height along up
    half = float(np.abs((corners - centre) @ e1).max())
    rng = np.random.default_rng(args.seed)
    r1, r2 = (args.drop * float(np.abs((corners - centre) @ e).max()) * rng.uniform(-1, 1, size=args.particles)
              for e in (e1, e2))
    start = centre + r1[:, None] * e1 + r2[:, None] * e2 + (0.9 * height) * up
    g = 9.81
    h = float(min(vol.get_voxel_size()))
    dt = args.dt or 0.25 * h / np.sqrt(2 * g * 2 * height)
    x = wp.array(start.astype(np.float32), dtype=wp.vec3, device=args.device)
    v = wp.zeros(args.particles, dtype=wp.vec3, device=args.device)
    fell = wp.zeros(args.particles, dtype=wp.int32, device=args.device)
    inputs = [vol.id, wp.vec3(*(-g * up)), float(dt), LEVEL, args.restitution, args.friction,
              wp.vec3(*lo), wp.vec3(*hi)]
    wp.launch(step_particles, dim=args.particles, device=args.device, inputs=inputs, outputs=[x, v, fell])
    wp.synchronize_device(args.device)
    t0 = time.perf_counter()
    for _ in range(args.steps - 1):
        wp.launch(step_particles, dim=args.particles, device=args.device, inputs=inputs, outputs=[x, v, fell])
    wp.synchronize_device(args.device)
    seconds = time.perf_counter() - t0
    pos, vel, gone = x.numpy().astype(np.float64), v.numpy(), fell.numpy().astype(bool)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    np.savez(out / "particles_on_scene.npz", positions=pos, velocities=vel, fell=gone, up=up, dt=dt)
    picture(vol, args.device, pos, centre, up, e1, half, out / "particles_on_scene.png")
    speed = np.linalg.norm(vel[~gone], axis=1) if (~gone).any() else np.zeros(1)
    result = {"particles": args.particles, "steps": args.steps, "dt": dt, "simulated_s": dt * args.steps,
              "fell": int(gone.sum()), "median_speed": float(np.median(speed)),
              "particle_steps_per_second": args.particles * (args.steps - 1) / seconds}
    print(f"{args.particles} particles, {args.steps} steps of {1e3 * dt:.3f} ms ({result['simulated_s']:.2f} s "
          f"simulated): {result['fell']} left the box, median speed {result['median_speed']:.3f} at the end")
    print(f"throughput: {result['particle_steps_per_second']:.4g} particle-steps/s on {args.device}")
    print(f"wrote {out / 'particles_on_scene.png'} and {out / 'particles_on_scene.npz'}")
    print(f"torch imported: {'torch' in sys.modules}")
    return result


if __name__ == "__main__":
    main()
