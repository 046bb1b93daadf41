"""The renderer benchmark's synthetic scene and camera (``benchmarks/render/bench_render.py``, ``bench_gsplat.py``).

``make_scene(n)``: the activated parameters of ``n`` flat Gaussians (thickness 5 % of the tangent size) on the
surfaces of a 4x4 ground plane, a sphere and a box, with tangent sizes ~0.8x the point spacing (log-normal ±30 %),
plus 5 % larger background Gaussians on a sphere of radius 8; opacities 60 % in U(0.5, 1), 40 % in U(0.02, 0.5);
SH degree 3. ``make_camera(width, height)``: a camera looking at the objects from ~3.8 units, 60° horizontal field
of view. Deterministic for a seed, so the tests and the benchmark render the same Gaussians.
"""

from __future__ import annotations

import math

import torch

from ..core.camera import look_at


def _frames_from_normals(n: torch.Tensor, g: torch.Generator) -> torch.Tensor:
    """Unit quaternions (wxyz) of frames whose third axis is ``n``, randomly spun about it."""
    a = torch.where(n[:, :1].abs() < 0.9, torch.tensor([1.0, 0, 0]), torch.tensor([0, 1.0, 0]))
    t1 = torch.nn.functional.normalize(torch.cross(n, a, dim=1), dim=1)
    t2 = torch.cross(n, t1, dim=1)
    phi = torch.rand(n.shape[0], 1, generator=g) * 2 * math.pi
    t1, t2 = t1 * phi.cos() + t2 * phi.sin(), -t1 * phi.sin() + t2 * phi.cos()
    R = torch.stack([t1, t2, n], dim=2)  # columns
    w = torch.sqrt(torch.clamp(1 + R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2], min=1e-12)) / 2
    q = torch.stack([w, (R[:, 2, 1] - R[:, 1, 2]) / (4 * w), (R[:, 0, 2] - R[:, 2, 0]) / (4 * w), (R[:, 1, 0] - R[:, 0, 1]) / (4 * w)], 1)
    return torch.nn.functional.normalize(q, dim=1)


def make_scene(n: int, seed: int = 0, device="cuda"):
    """Activated parameters of ``n`` Gaussians on synthetic surfaces (see the module docstring)."""
    g = torch.Generator().manual_seed(seed)
    n_bg = n // 20
    n_s = n - n_bg
    areas = torch.tensor([16.0, 4 * math.pi * 0.36, 6 * 0.64])  # plane 4x4, sphere r=0.6, box 0.8^3
    which = torch.multinomial(areas / areas.sum(), n_s, replacement=True, generator=g)
    u = torch.rand(n_s, 3, generator=g)
    pts = torch.zeros(n_s, 3)
    nrm = torch.zeros(n_s, 3)
    m = which == 0  # ground plane z = 0
    pts[m] = torch.stack([u[m, 0] * 4 - 2, u[m, 1] * 4 - 2, torch.zeros(int(m.sum()))], 1)
    nrm[m] = torch.tensor([0.0, 0, 1])
    m = which == 1  # sphere
    d = torch.nn.functional.normalize(torch.randn(int(m.sum()), 3, generator=g), dim=1)
    pts[m] = torch.tensor([-0.3, 0.2, 0.6]) + 0.6 * d
    nrm[m] = d
    m = which == 2  # box [0.4,1.2]x[-1,-0.2]x[0,0.8]
    face = torch.randint(0, 6, (int(m.sum()),), generator=g)
    p = u[m] * 0.8
    axis, side = face // 2, (face % 2).float()
    p[torch.arange(p.shape[0]), axis] = side * 0.8
    nb = torch.zeros_like(p)
    nb[torch.arange(p.shape[0]), axis] = side * 2 - 1
    pts[m] = p + torch.tensor([0.4, -1.0, 0.0])
    nrm[m] = nb
    spacing = math.sqrt(float(areas.sum()) / n_s)
    tang = spacing * torch.exp(0.3 * torch.randn(n_s, 2, generator=g)) * 0.8
    scales = torch.cat([tang, 0.05 * tang.mean(1, keepdim=True)], 1)
    quats = _frames_from_normals(nrm, g)
    # background: far sphere of radius 8, bigger splats
    d = torch.nn.functional.normalize(torch.randn(n_bg, 3, generator=g), dim=1)
    d[:, 2] = d[:, 2].abs()
    bg_pts = 8.0 * d
    bg_spacing = math.sqrt(2 * math.pi * 64 / max(n_bg, 1))
    bg_tang = bg_spacing * torch.exp(0.3 * torch.randn(n_bg, 2, generator=g))
    bg_scales = torch.cat([bg_tang, 0.05 * bg_tang.mean(1, keepdim=True)], 1)
    means = torch.cat([pts, bg_pts])
    scales = torch.cat([scales, bg_scales])
    quats = torch.cat([quats, _frames_from_normals(-d, g)])
    faint = torch.rand(n, generator=g) < 0.4
    opac = torch.where(faint, 0.02 + 0.48 * torch.rand(n, generator=g), 0.5 + 0.5 * torch.rand(n, generator=g))
    sh = 0.05 * torch.randn(n, 16, 3, generator=g)
    sh[:, 0] = (torch.rand(n, 3, generator=g) - 0.5) * 3.0
    return [x.float().contiguous().to(device) for x in (means, quats, scales, opac, sh)]


def make_camera(width, height):
    return look_at((2.6, -2.4, 1.6), (0.1, -0.1, 0.35), up=(0, 0, 1), fx=0.866 * width, width=width, height=height)
