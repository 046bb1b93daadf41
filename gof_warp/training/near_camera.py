"""Gaussians right in front of a training camera: what the loss-spike report records.

A Gaussian whose centre sits a short depth in front of a camera covers much of that camera's image. Views
are visited one at a time, so such a Gaussian can be fitted by the other views (for which it is part of a
far surface or a floater) and, at the next visit of the camera it sits in front of, suddenly dominate that
view's photometric loss and distortion term: a one-iteration loss spike.

* :func:`centre_depths` — camera-space depth of every centre and whether it projects into the image.
* :func:`near_camera_census` — for one camera, the Gaussians whose centres lie in the image at depth
  ``(0, within]``: how many, how many of them opaque enough to render, and the nearest few of those (depth,
  opacity, largest scale). The trainer attaches it to
  each per-view loss spike in ``metrics.json`` (``loss_spikes.view_spikes``), so a spike says whether something
  sat right in front of that camera when it happened.
* :func:`near_ray_census` — what that camera's rays actually meet near it: on a coarse grid of pixel rays, the
  renderer's own ray–Gaussian test (``t*`` in ``(near, within]``, ``α = min(α_max, o·exp(−d²/2)) ≥ α_min``) for
  every Gaussian that could reach that depth, centre in the image or not. A large flat Gaussian whose centre lies
  beside the image can cover much of it; the centre census above cannot see it.
* :func:`near_camera_bounds` / :func:`in_front_of_cameras` — per camera, a depth no surface it sees lies in front
  of (a fraction of its nearest initial point), and the Gaussians that some camera's rays meet nearer than that
  (the ray census's test): what ``DensifyConfig.near_camera_fraction`` removes after densification.
* :func:`views_seeing` — how many cameras hold each centre in their image beyond their near plane. In a random start
  the space right in front of a camera is in no other training view's image (a held-out view between them looks
  through it): what ``ModelConfig.random_min_views`` keeps Gaussians out of.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..core.camera import Camera
from ..core.model import quat_to_rotmat


def centre_depths(means: torch.Tensor, camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """``(depth [N], in_image [N] bool)`` of centres ``means [N, 3]``: camera-space ``z`` and whether the centre is
    in front of the camera (``z > 0``) and projects inside the image (``0 <= u < width``, ``0 <= v < height``)."""
    _, _, z, inside = camera.in_image_tensor(means)
    return z, inside


def near_camera_census(means: torch.Tensor, opacities: torch.Tensor, scales: torch.Tensor, camera: Camera, *,
                       within: float, min_opacity: float = 0.0, top: int = 5) -> dict:
    """The Gaussians whose centres project into ``camera``'s image at depth ``(0, within]``.

    Args:
        means: ``[N, 3]``; opacities: ``[N]`` (activated); scales: ``[N, 3]`` (activated).
        within: depth limit, world units.
        min_opacity: only Gaussians at least this opaque are listed and counted as ``visible`` (the renderer's
            ``alpha_min``: below it a Gaussian adds nothing to any pixel).
        top: how many of the nearest visible ones to list.

    Returns:
        plain data: ``{"within", "count", "visible", "nearest": [{"depth", "opacity", "max_scale"}, ...]}``, nearest
        first; ``count`` includes the Gaussians too transparent to render.
    """
    with torch.no_grad():
        z, inside = centre_depths(means.detach(), camera)
        near = inside & (z <= within)
        idx = torch.nonzero(near & (opacities.detach() >= min_opacity)).flatten()
        order = idx[torch.argsort(z[idx])][:top]
        nearest = [{"depth": round(float(z[i]), 4), "opacity": round(float(opacities[i]), 4),
                    "max_scale": round(float(scales[i].max()), 4)} for i in order.tolist()]
    return {"within": float(within), "count": int(near.sum()), "visible": int(idx.numel()), "nearest": nearest}


_PROJECT_CHUNK = 65536  # Gaussians projected into every camera at once by in_front_of_cameras


def _alpha_reach(alpha_min: float, alpha_max: float) -> float:
    """``k``: wherever ``α = min(alpha_max, o·exp(−d²/2)) ≥ alpha_min`` can hold (``o ≤ 1``), ``d ≤ k``, so the
    ray's peak ``t*`` lies within ``k·σ_max`` of the centre."""
    return math.sqrt(2.0 * math.log(max(alpha_max, 1e-12) / alpha_min)) if alpha_min > 0 else math.inf


def _near_candidates(z: torch.Tensor, reach: torch.Tensor, opacities: torch.Tensor, near: float, within,
                     alpha_min: float) -> torch.Tensor:
    """Bool mask of the Gaussians whose rays' peaks can lie at depth ``(near, within]`` with ``α ≥ alpha_min``:
    centre depth ``z > near`` (the renderer culls the rest), ``z − reach ≤ within`` (``reach = k·σ_max``,
    :func:`_alpha_reach`) and opacity ``≥ alpha_min``. Shapes broadcast: ``z`` ``[N]`` or ``[C, N]``, ``reach`` and
    ``opacities`` ``[N]``, ``within`` a float or ``[C, 1]``."""
    return (z > near) & (z - reach <= within) & (opacities >= alpha_min)


def _ray_grid(k: torch.Tensor, rays_across: int, dtype) -> torch.Tensor:
    """``[P, 3]`` camera-space rays (z = 1) through the centres of a ``rays_across × round(rays_across·H/W)`` grid
    of image cells; ``k = (fx, fy, cx, cy, width, height)`` (a row of :func:`stack_cameras`)."""
    fx, fy, cx, cy, w, h = k.tolist()
    nx = max(1, int(rays_across))
    ny = max(1, round(nx * h / w))
    px = (torch.arange(nx, device=k.device, dtype=dtype) + 0.5) * (w / nx)
    py = (torch.arange(ny, device=k.device, dtype=dtype) + 0.5) * (h / ny)
    yy, xx = torch.meshgrid(py, px, indexing="ij")
    return torch.stack([(xx - cx) / fx, (yy - cy) / fy, torch.ones_like(xx)], -1).reshape(-1, 3)


def _ray_hits(mu: torch.Tensor, R_v: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
              rays: torch.Tensor, near: float, within: float, alpha_min: float, alpha_max: float):
    """The renderer's ray–Gaussian test for ``n`` Gaussians (camera-space centres ``mu [n,3]``, rotations ``R_v
    [n,3,3]`` into camera space, ``scales [n,3]``, ``opacities [n]``) and ``rays [P,3]``: ``(hit [P,n] bool,
    α [P,n] (0 where no hit), t* [P,n])``; a hit is ``near < t* ≤ within`` and ``α ≥ alpha_min``."""
    inv_s = 1.0 / scales
    o_g = -torch.einsum("nji,nj->ni", R_v, mu) * inv_s  # S⁻¹ R_vᵀ (0 − μ)
    r_g = torch.einsum("nji,pj->pni", R_v, rays) * inv_s  # [P, n, 3]
    A = (r_g * r_g).sum(-1)
    B = (r_g * o_g).sum(-1)
    C = (o_g * o_g).sum(-1)
    t_star = -B / A
    alpha = torch.clamp(opacities * torch.exp(-0.5 * (C - B * B / A).clamp_min(0)), max=alpha_max)
    hit = (t_star > near) & (t_star <= within) & (alpha >= alpha_min)
    return hit, torch.where(hit, alpha, torch.zeros_like(alpha)), t_star


def _to_camera(means: torch.Tensor, quats: torch.Tensor, R: torch.Tensor, t: torch.Tensor):
    """Camera-space centres ``[n,3]`` and rotations ``[n,3,3]`` of Gaussians for the pose ``(R [3,3], t [3])``."""
    mu = means @ R.T + t
    return mu, R @ quat_to_rotmat(torch.nn.functional.normalize(quats, dim=1))


def near_ray_census(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                    camera: Camera, *, within: float, near: float = 0.2, alpha_min: float = 1.0 / 255.0,
                    alpha_max: float = 0.99, rays_across: int = 64, top: int = 5, chunk: int = 4096) -> dict:
    """The Gaussians ``camera``'s rays meet at depth ``(near, within]``, by the renderer's test, on a ray grid.

    Rays go through the centres of a ``rays_across × round(rays_across·H/W)`` grid of image cells. For each ray
    and Gaussian (centre depth ``> near``, as the renderer culls): ``t* = −B/A`` (the depth where the ray meets
    the Gaussian's peak), ``d² = C − B²/A``, ``α = min(alpha_max, o·exp(−d²/2))``; the pair counts when
    ``near < t* ≤ within`` and ``α ≥ alpha_min``. Order and transmittance are ignored: ``near_alpha`` of a ray
    is ``1 − Π(1 − α)`` over its near pairs, an upper bound on what they hide.

    Args:
        means: ``[N, 3]``; quats: ``[N, 4]`` wxyz (normalised here); scales: ``[N, 3]``, opacities: ``[N]``
            (activated, 3D filter included: what the renderer draws).
        within: depth limit, world units.
        rays_across: rays per image row.

    Returns:
        plain data: ``{"within", "rays", "covered" (fraction of rays with a near pair), "near_alpha" (mean over
        rays), "contributors": [...]}``; the contributors are the ``top`` Gaussians with the largest summed
        ``α`` over the rays, each ``{"depth" (centre), "in_image" (centre), "t_mean" (mean t* over its rays),
        "opacity", "max_scale", "coverage" (fraction of rays), "mean_alpha"}``.
    """
    with torch.no_grad():
        dt = means.dtype
        cam = stack_cameras([camera], means.device, dt)
        means, quats, scales, opacities = means.detach(), quats.detach().to(dt), scales.detach(), opacities.detach()
        mu = means @ cam["R"][0].T + cam["t"][0]
        s_max = scales.max(dim=1).values
        reach = _alpha_reach(alpha_min, alpha_max)
        idx = torch.nonzero(_near_candidates(mu[:, 2], reach * s_max, opacities, near, within, alpha_min)).flatten()
        rays = _ray_grid(cam["k"][0], rays_across, dt)
        log_clear = torch.zeros(rays.shape[0], device=means.device, dtype=dt)
        hit_any = torch.zeros(rays.shape[0], device=means.device, dtype=torch.bool)
        count, a_sum, t_sum = (torch.zeros(idx.numel(), device=means.device, dtype=dt) for _ in range(3))
        for lo in range(0, idx.numel(), chunk):
            sel = idx[lo:lo + chunk]
            mu_s, R_v = _to_camera(means[sel], quats[sel], cam["R"][0], cam["t"][0])
            hit, alpha, t_star = _ray_hits(mu_s, R_v, scales[sel], opacities[sel], rays, near, within, alpha_min,
                                           alpha_max)
            log_clear += torch.log1p(-alpha).sum(1)
            hit_any |= hit.any(1)
            count[lo:lo + chunk] = hit.sum(0).to(dt)
            a_sum[lo:lo + chunk] = alpha.sum(0)
            t_sum[lo:lo + chunk] = torch.where(hit, t_star, torch.zeros_like(t_star)).sum(0)
        n_rays = rays.shape[0]
        order = torch.argsort(a_sum, descending=True)[:top]
        order = order[count[order] > 0]
        _, inside = centre_depths(means[idx[order]], camera)  # only the listed ones
        contributors = []
        for rank, j in enumerate(order.tolist()):
            i = int(idx[j])
            contributors.append({"depth": round(float(mu[i, 2]), 4), "in_image": bool(inside[rank]),
                                 "t_mean": round(float(t_sum[j] / count[j]), 4),
                                 "opacity": round(float(opacities[i]), 4), "max_scale": round(float(s_max[i]), 4),
                                 "coverage": round(float(count[j]) / n_rays, 4),
                                 "mean_alpha": round(float(a_sum[j] / count[j]), 4)})
        return {"within": float(within), "rays": n_rays, "covered": round(float(hit_any.float().mean()), 4),
                "near_alpha": round(float((1.0 - torch.exp(log_clear)).mean()), 5), "contributors": contributors}


def near_camera_bounds(points: torch.Tensor, cameras: list[Camera], fraction: float) -> torch.Tensor:
    """``[C]``: ``fraction`` × the depth of the nearest of ``points [P, 3]`` (the initial/SfM points) that lands in
    each camera's image; ``0`` for a camera whose image holds none of them (nothing is removed in front of it)."""
    with torch.no_grad():
        bounds = []
        for cam in cameras:
            z, inside = centre_depths(points, cam)
            bounds.append(fraction * z[inside].min() if bool(inside.any()) else z.new_zeros(()))
        return torch.stack(bounds) if bounds else points.new_zeros(0)


def stack_cameras(cameras: list[Camera], device=None, dtype=torch.float32) -> dict[str, torch.Tensor]:
    """The cameras' poses and intrinsics as tensors on ``device``, built once for :func:`in_front_of_cameras`:
    ``R [C,3,3]``, ``t [C,3]``, ``k [C,6]`` = ``(fx, fy, cx, cy, width, height)``."""
    return {"R": torch.tensor(np.stack([c.R for c in cameras]), device=device, dtype=dtype),
            "t": torch.tensor(np.stack([c.t for c in cameras]), device=device, dtype=dtype),
            "k": torch.tensor([[c.fx, c.fy, c.cx, c.cy, c.width, c.height] for c in cameras], device=device,
                              dtype=dtype)}


def views_seeing(means: torch.Tensor, cameras: dict[str, torch.Tensor], near: torch.Tensor,
                 chunk: int = _PROJECT_CHUNK) -> torch.Tensor:
    """``[N]`` int64: for each centre of ``means [N, 3]``, the number of ``cameras`` (:func:`stack_cameras`) that hold
    it in their image beyond their near plane: camera-space ``z > near[c]`` and pixel ``0 <= u < width``,
    ``0 <= v < height`` (``u = fx·x/z + cx``; :meth:`Camera.in_image`'s test). ``near [C]``: each camera's clip depth.
    Memory: ``C × chunk`` projections at a time."""
    with torch.no_grad():
        dt = cameras["R"].dtype
        means = means.detach().to(dt)
        k = cameras["k"]
        fx, fy, cx, cy, w, h = (k[:, i:i + 1] for i in range(6))
        nr = near.to(device=means.device, dtype=dt)[:, None]
        out = torch.zeros(means.shape[0], dtype=torch.int64, device=means.device)
        for lo in range(0, means.shape[0], chunk):
            pc = torch.einsum("cij,nj->cni", cameras["R"], means[lo:lo + chunk]) + cameras["t"][:, None, :]
            z = pc[..., 2]
            zs = torch.where(z > 0, z, torch.ones_like(z))
            u = fx * pc[..., 0] / zs + cx
            v = fy * pc[..., 1] / zs + cy
            seen = (z > nr) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
            out[lo:lo + chunk] = seen.sum(0)
        return out


def in_front_of_cameras(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
                        cameras: dict[str, torch.Tensor], bounds: torch.Tensor, *, near: float = 0.2,
                        alpha_min: float = 1.0 / 255.0, alpha_max: float = 0.99, rays_across: int = 64,
                        chunk: int = 4096) -> torch.Tensor:
    """``[N]`` bool: the Gaussians that some camera's rays meet nearer than that camera's bound, by the renderer's
    own test (:func:`near_ray_census`'s: ``near < t* ≤ bounds[c]``, ``α ≥ alpha_min``) on a ``rays_across``-wide
    grid. A Gaussian whose centre lies beside the image but which covers part of it counts. (Adding the Gaussians
    whose centre lies in the image nearer than the bound, behind the near plane included, measured worse on
    colmap_can.)

    ``cameras``: :func:`stack_cameras`; ``bounds [C]`` (:func:`near_camera_bounds`; ``≤ near``: nothing in front
    of that camera). Candidates for all cameras come from one batched projection; only cameras with candidates
    run the ray test."""
    with torch.no_grad():
        dt = cameras["R"].dtype
        means, quats = means.detach().to(dt), quats.detach().to(dt)
        scales, opacities = scales.detach().to(dt), opacities.detach().to(dt)
        out = torch.zeros(means.shape[0], dtype=torch.bool, device=means.device)
        b = bounds.to(device=means.device, dtype=dt)
        reach = _alpha_reach(alpha_min, alpha_max) * scales.max(dim=1).values
        pairs = []
        for lo in range(0, means.shape[0], _PROJECT_CHUNK):
            hi = lo + _PROJECT_CHUNK
            z = torch.einsum("cj,nj->cn", cameras["R"][:, 2], means[lo:hi]) + cameras["t"][:, 2:3]
            cand = _near_candidates(z, reach[lo:hi], opacities[lo:hi], near, b[:, None], alpha_min)
            cand &= b[:, None] > near
            c, i = torch.nonzero(cand, as_tuple=True)
            pairs.append((c, i + lo))
        if not pairs:
            return out
        cam_of = torch.cat([p[0] for p in pairs])
        gauss = torch.cat([p[1] for p in pairs])
        for c in torch.unique(cam_of).tolist():
            idx = gauss[cam_of == c]
            rays = _ray_grid(cameras["k"][c], rays_across, dt)
            for lo in range(0, idx.numel(), chunk):
                sel = idx[lo:lo + chunk]
                mu, R_v = _to_camera(means[sel], quats[sel], cameras["R"][c], cameras["t"][c])
                hit, _, _ = _ray_hits(mu, R_v, scales[sel], opacities[sel], rays, near, float(b[c]), alpha_min,
                                      alpha_max)
                out[sel] |= hit.any(0)
        return out
