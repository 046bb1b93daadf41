"""Extract the surface of your own Warp field with our marching tetrahedra + bisection (no torch).

The field is a ``@wp.func``: a solid gyroid clipped by a ball, ``f(x) = min(gyroid(k x), k (r - |x|))``,
inside where ``f >= 0``. Its parameters travel in a ``wp.struct``. The tetrahedra come from a regular
grid, each cube split into the 6 Kuhn (Freudenthal) tetrahedra that share its main diagonal, so
neighbouring cubes match face to face and a closed level set gives a watertight mesh.

``marching_tetrahedra(points, tets, None, gyroid_field, field_params=params)`` evaluates the field at the
grid points and, in each bisection step, at the midpoints of all crossing edges, with one kernel made from
the ``wp.func`` (``gof_warp.kernels.make_field_kernel``): nothing goes back to the host between steps.

    python examples/warp_marching_gyroid.py --device cpu --resolution 40 --out /tmp/gyroid
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import numpy as np
import warp as wp

from gof_warp.mesh.marching import marching_tetrahedra


@wp.struct
class GyroidParams:
    frequency: float  # k, radians per world unit
    radius: float  # of the clipping ball, world units


@wp.func
def gyroid_field(x: wp.vec3, p: GyroidParams) -> float:
    """``min(gyroid(k x), k (r - |x|))``: positive inside the gyroid's solid phase within the ball."""
    q = p.frequency * x
    g = wp.sin(q[0]) * wp.cos(q[1]) + wp.sin(q[1]) * wp.cos(q[2]) + wp.sin(q[2]) * wp.cos(q[0])
    return wp.min(g, p.frequency * (p.radius - wp.length(x)))


def gyroid_field_np(x: np.ndarray, frequency: float, radius: float) -> np.ndarray:
    """The same field in float64 numpy (the reference the test checks vertices against)."""
    q = frequency * np.asarray(x, np.float64)
    s, c = np.sin(q), np.cos(q)
    g = s[:, 0] * c[:, 1] + s[:, 1] * c[:, 2] + s[:, 2] * c[:, 0]
    return np.minimum(g, frequency * (radius - np.linalg.norm(x, axis=1)))


def kuhn_grid(lower: float, upper: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n³`` grid points ``[n³, 3] float32`` in ``[lower, upper]³`` and ``6 (n-1)³`` tetrahedra ``[T, 4] int32``.

    Each cube (corner ``c``) gives the tetrahedra ``c, c + e_a, c + e_a + e_b, c + 1`` for the 6 orders
    ``(a, b, ·)`` of the axes; all cubes are split alike, so shared faces are split alike.
    """
    axis = np.linspace(lower, upper, n, dtype=np.float64)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3).astype(np.float32)
    corner = np.stack(np.meshgrid(*[np.arange(n - 1)] * 3, indexing="ij"), -1).reshape(-1, 3)

    def index(ijk):
        return (ijk[:, 0] * n + ijk[:, 1]) * n + ijk[:, 2]

    eye = np.eye(3, dtype=np.int64)
    tets = []
    for a, b, c in itertools.permutations(range(3)):
        path = [corner, corner + eye[a], corner + eye[a] + eye[b], corner + eye[a] + eye[b] + eye[c]]
        tets.append(np.stack([index(p) for p in path], 1))
    return points, np.concatenate(tets).astype(np.int32)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="Warp device (default: Warp's current device)")
    parser.add_argument("--resolution", type=int, default=40, help="grid points per axis")
    parser.add_argument("--frequency", type=float, default=2.0 * np.pi / 1.2, help="gyroid k (one period = 1.2)")
    parser.add_argument("--radius", type=float, default=1.0, help="clipping ball radius")
    parser.add_argument("--steps", type=int, default=8, help="bisection steps per crossing edge")
    parser.add_argument("--out", type=Path, default=None, help="folder for mesh.npz (vertices, faces)")
    args = parser.parse_args(argv)
    wp.init()
    device = args.device or str(wp.get_device())

    params = GyroidParams()
    params.frequency, params.radius = float(args.frequency), float(args.radius)
    half = 1.1 * args.radius  # the grid encloses the ball: the level set is closed
    points, tets = kuhn_grid(-half, half, args.resolution)
    start = time.perf_counter()
    (vertices, faces), = marching_tetrahedra(points, tets, None, gyroid_field, field_params=params, levels=[0.0],
                                             binary_steps=args.steps, device=device)
    seconds = time.perf_counter() - start

    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    residual = np.abs(gyroid_field_np(vertices, args.frequency, args.radius))
    result = {
        "tetrahedra": int(tets.shape[0]),
        "vertices": int(vertices.shape[0]),
        "faces": int(faces.shape[0]),
        "watertight": bool(faces.shape[0] > 0 and np.all(uses == 2)),
        "max_abs_field": float(residual.max()) if residual.size else 0.0,
        "seconds": seconds,
    }
    print(", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in result.items()))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        np.savez(args.out / "mesh.npz", vertices=vertices, faces=faces, frequency=args.frequency,
                 radius=args.radius, spacing=2 * half / (args.resolution - 1))
    return result


if __name__ == "__main__":
    main()
