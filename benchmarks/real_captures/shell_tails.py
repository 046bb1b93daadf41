"""What raises GOF's opacity field in front of `background_full`'s far shell (2-core CPU; session 28):
``shell_tails.py MODEL.ply SCENE [--offset 0.05] [--lines 40]``.

On ``--lines`` random radial lines 0.4–2 m above the ground (``--band``), the point ``--offset`` in front of the shell
(radius ``--radius``) is evaluated in float64 per training view that sees it, as ``kernels.opacity_field`` does
(Gaussians in depth order, each at ``min(t*, t)`` along the view's ray, the filtered scales and opacities; the
Gaussians within 0.5 of the point only, occluders further off left out), and GOF's field is the minimum over those
views. For the view giving the minimum it lists what makes the value, each Gaussian weighted by its ``−log(1 − α)``:
how far behind the point its peak lies, its standard deviation along the ray, its peak alpha on the ray and its scales.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from scipy.spatial import cKDTree

from gof_warp.data import load_scene
from gof_warp.model import Gaussians, quat_to_rotmat

K_MAX2 = 9.0  # the field's 3σ cut-off on the ray's closest approach
ALPHA_MAX, ALPHA_MIN = 0.99, 1.0 / 255.0
GROUND_Z = -0.9


def view_opacity(x, cam, mu, rot, scales, opac, near):
    """``(O, contributors)``: the composited opacity at ``x`` from ``cam`` over the Gaussians ``near`` (indices), and
    per contributing Gaussian ``(alpha, peak behind x [world], sigma along the ray [world], peak alpha, index)``."""
    xv = cam.R @ x + cam.t
    z = xv[2]
    r = xv / z
    mv = mu[near] @ cam.R.T + cam.t
    T, opacity, contrib = 1.0, 0.0, []
    for j in np.argsort(mv[:, 2]):
        k = near[j]
        P = np.diag(1.0 / scales[k]) @ (cam.R @ rot[k]).T
        og, rg = -P @ mv[j], P @ r
        A, B, C = rg @ rg, og @ rg, og @ og
        ts = -B / A
        if ts <= 0.05 or C - B * B / A > K_MAX2:
            continue
        xg = og + min(ts, z) * rg
        a = min(ALPHA_MAX, opac[k] * math.exp(-0.5 * xg @ xg))
        if a < ALPHA_MIN:
            continue
        ray = np.linalg.norm(r)
        contrib.append((a, (ts - z) * ray, ray / math.sqrt(A), opac[k] * math.exp(-0.5 * (C - B * B / A)), k))
        opacity += a * T
        T *= 1.0 - a
    return opacity, contrib


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("scene")
    ap.add_argument("--offset", type=float, default=0.05, help="in front of the shell, world units")
    ap.add_argument("--radius", type=float, default=6.0)
    ap.add_argument("--lines", type=int, default=40)
    ap.add_argument("--band", type=float, nargs=2, default=(0.4, 2.0), help="height above the ground")
    a = ap.parse_args()
    cams = load_scene(a.scene).train_cameras
    g = Gaussians.load_ply(a.model)
    mu = g.means.detach().numpy().astype(np.float64)
    scales = g.scales.detach().numpy().astype(np.float64)
    raw = g.raw_scales.detach().numpy().astype(np.float64)
    rot = quat_to_rotmat(g.quats.detach().double() / g.quats.detach().double().norm(dim=1, keepdim=True)).numpy()
    opac = g.opacities.detach().numpy().astype(np.float64)
    tree = cKDTree(mu)
    rng = np.random.default_rng(0)
    mins, rows = [], []
    while len(mins) < a.lines:
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        if not a.band[0] < a.radius * d[2] - GROUND_Z < a.band[1]:
            continue
        x = (a.radius - a.offset) * d
        near = np.array(tree.query_ball_point(x, 0.5), dtype=int)
        if not len(near):
            continue
        per = [view_opacity(x, cam, mu, rot, scales, opac, near)
               for cam in cams if cam.in_image(x[None], near=0.05)[2][0]]
        if len(per) < 2:
            continue
        best = min(per, key=lambda p: p[0])
        mins.append(best[0])
        rows.extend(best[1])
    mins = np.array(mins)
    print(f"GOF's field {a.offset * 100:.0f} cm in front of the shell, {len(mins)} lines: median {np.median(mins):.3f} "
          f"(p10 {np.percentile(mins, 10):.3f}, p90 {np.percentile(mins, 90):.3f})")
    alpha = np.array([c[0] for c in rows])
    w = np.round(-np.log1p(-alpha) * 1000).astype(int)  # each contributor weighted by -log(1 - alpha)
    ks = np.array([c[4] for c in rows])

    def pct(values):
        return np.round(np.percentile(np.repeat(values, w, axis=0), [10, 50, 90], axis=0), 3)

    print("what makes it in the minimum view (weighted by -log(1 - alpha)), p10 / p50 / p90:")
    print(f"  peak behind the point: {pct(np.array([c[1] for c in rows]) * 100)} cm")
    print(f"  standard deviation along the ray: {pct(np.array([c[2] for c in rows]) * 100)} cm")
    print(f"  peak alpha on the ray: {pct(np.array([c[3] for c in rows]))}")
    sorted_scales = np.sort(np.repeat(raw[ks], w, axis=0), 1)
    print(f"  unfiltered scales, smallest to largest (median): {np.round(np.median(sorted_scales, 0) * 100, 2)} cm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
