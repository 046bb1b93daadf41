"""Gaussians hidden behind the surface the renders show: what ``DensifyConfig.hidden_prune_iters`` removes.

The renderer composites each Gaussian at its peak ``t*`` along the ray, so a Gaussian whose centre lies behind an
opaque surface adds (almost) nothing to any photo and no loss moves it away. GOF's opacity field counts every
Gaussian before its peak too, by its tail ``α G(t)`` (``kernels.opacity_field``): a large Gaussian behind a surface
reaches through it and raises the field in front of it. On the synthetic ``background_full`` scene ~2,900 round
Gaussians of 12–19 cm that training left 5–100 cm behind the far shell put the field at 0.41 five centimetres in
front of the shell (0.04 without them): the mesh stood ~5 cm in front of the photographed surface. Removed during
training, the renders go on without them (the ground's rim there was complete in both runs); left out of a finished
model at extraction instead, they open surfaces behind the half-transparent layer they backed.

* :func:`surface_depth_ratio` — each centre's depth over the rendered median depth at its pixel, the least over the
  training views whose image holds it where the render shows a surface.
* :func:`behind_surface` — the Gaussians whose centres lie behind the rendered median depth by more than
  ``margin`` × that depth in every such view (that ratio above ``1 + margin``).
* :func:`surface_measures` — that ratio and how much of each Gaussian reaches in front of the surface (its tail).
* :func:`hidden_gaussians` — what the prune removes: behind the surface, and (optionally) showing little and
  reaching through it.
* :func:`visible_fraction` — how much of each Gaussian the photos show: its blending weight summed over a view's
  pixels (:func:`blend_weights`) over what it would show with nothing in front of it (:func:`unoccluded_weight`), the
  largest over the views. A Gaussian behind the median depth but under a half-transparent layer (a glossy floor's
  texture, fur, a reflection) still shows; one behind an opaque surface does not. Why this matters: pruned on depth
  alone, colmap_can loses its floor's tile lines and 2.9 dB, fox 1.5 dB.

Shapes: ``means [N, 3]``; returns ``[N]`` bool. The test reads the centre's pixel only: a Gaussian whose centre is
hidden but whose body shows beside an edge is kept only if some view's median depth at its centre is within the
margin (in practice a view that sees it from the side).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from types import SimpleNamespace

import torch

from ..core.camera import Camera
from ..core.model import SH_C0, quat_to_rotmat
from ..rendering.render import RenderConfig, render


@torch.no_grad()
def surface_depth_ratio(gaussians, cameras: Sequence[Camera], *, config: RenderConfig | None = None) -> torch.Tensor:
    """``[N]`` float: the least ``z / D`` of each Gaussian's centre over the views that see where it is (``+inf``
    where none does); above 1 the centre lies behind the rendered surface in every such view.

    For each camera, the model's median depth ``D`` (:func:`gof_warp.rendering.render.render`) is read at the pixel of each
    centre that projects into the image (camera depth ``z > 0``, pixel ``(⌊u⌋, ⌊v⌋)``). The view *sees where it is*
    when ``D > 0`` there (a surface is rendered). One render per camera, whatever margin is applied afterwards.

    Args:
        gaussians: a model (:class:`gof_warp.core.model.Gaussians`), on any device.
        cameras: the views to test (the training views).
        config: the renderer's settings (the trainer's).
    """
    return surface_measures(gaussians, cameras, config=config, tail=False)[0]


@torch.no_grad()
def surface_measures(gaussians, cameras: Sequence[Camera], *, config: RenderConfig | None = None, tail: bool = True
                     ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """``(ratio [N], tail [N] or None)`` from one render per camera: :func:`surface_depth_ratio`'s ratio and, with
    ``tail``, how far each Gaussian reaches in front of the rendered surface: the largest, over the views that see
    where it is, of its opacity at that view's surface on the ray through its centre,
    ``o · exp(−½ (Δ / σ_t)²)`` with ``Δ = t_c (1 − D / z)`` the distance along the ray from the surface to the centre
    (``t_c`` the centre's distance from the camera) and ``σ_t = (dᵀ Σ⁻¹ d)^(−½)`` the Gaussian's spread along the
    ray's direction ``d``; ``o`` where the centre is in front (``Δ ≤ 0``); 0 where no view sees where it is. That is
    what GOF's field counts of it at the surface (``kernels.opacity_field``): a large Gaussian behind a surface reaches
    through it, a thin layer under it does not."""
    if len(cameras) == 0:
        raise ValueError("behind_surface: no cameras")
    means = gaussians.means.detach()
    least = torch.full((means.shape[0],), math.inf, device=means.device)
    reach = torch.zeros(means.shape[0], device=means.device) if tail else None
    if tail:
        rot = quat_to_rotmat(gaussians.rotations.detach())
        inv_cov = rot @ torch.diag_embed(gaussians.scales.detach().pow(-2)) @ rot.transpose(1, 2)  # [N, 3, 3]
        opacity = gaussians.opacities.detach().reshape(-1)
    for cam in cameras:
        depth = render(gaussians, cam, config=config)["median_depth"]
        u, v, z, inside = cam.in_image_tensor(means)
        col = torch.where(inside, u, 0.0).floor().long().clamp_(0, cam.width - 1)
        row = torch.where(inside, v, 0.0).floor().long().clamp_(0, cam.height - 1)
        d = depth[row, col]
        sees = inside & (d > 0)
        ratio = z / torch.where(sees, d, 1.0)
        least = torch.minimum(least, torch.where(sees, ratio, math.inf))
        if tail:
            ray = means - means.new_tensor(cam.center)
            t_c = ray.norm(dim=1).clamp_min(1e-12)
            direction = ray / t_c[:, None]
            sigma_t = torch.einsum("ni,nij,nj->n", direction, inv_cov, direction).rsqrt()
            delta = t_c * (1.0 - 1.0 / torch.where(sees, ratio, 1.0))
            at_surface = torch.where(delta > 0, opacity * torch.exp(-0.5 * (delta / sigma_t) ** 2), opacity)
            reach = torch.maximum(reach, torch.where(sees, at_surface, torch.zeros_like(at_surface)))
    return least, reach


def behind_surface(gaussians, cameras: Sequence[Camera], *, margin: float, config: RenderConfig | None = None
                   ) -> torch.Tensor:
    """``[N]`` bool: Gaussian ``i`` lies behind the surface in every view that sees where it is, by more than
    ``margin`` × the surface's depth there (``z > (1 + margin) · D`` in each; at least one such view). See
    :func:`surface_depth_ratio` for the test per view.

    Args:
        margin: relative depth margin, ``> 0`` (0.01: 1 % of the surface's depth).
        the others: as in :func:`surface_depth_ratio`.
    """
    return behind_by(surface_depth_ratio(gaussians, cameras, config=config), margin)


def behind_by(ratio: torch.Tensor, margin: float) -> torch.Tensor:
    """``[N]`` bool from :func:`surface_depth_ratio`'s ``ratio``: seen, and behind by more than ``margin`` (``> 0``)
    in every view that sees where it is (:func:`behind_surface` without rendering again, e.g. for several margins)."""
    if not margin > 0:
        raise ValueError(f"behind_surface: margin must be > 0, got {margin}")
    return torch.isfinite(ratio) & (ratio > 1.0 + margin)


def hidden_gaussians(gaussians, cameras: Sequence[Camera], *, margin: float, max_visible: float | None,
                     min_tail: float | None = None, config: RenderConfig | None = None) -> torch.Tensor:
    """``[N]`` bool: :func:`behind_surface` (``margin``) and, unless ``max_visible`` is None, a
    :func:`visible_fraction` under ``max_visible`` (in ``(0, 1]``): hidden by depth and shown little in every view;
    unless ``min_tail`` is None, also reaching in front of the surface by more than ``min_tail`` (in ``[0, 1)``:
    :func:`surface_measures`' tail), so that only what raises GOF's field in front of a surface goes. The fraction is
    computed only when some Gaussian is left."""
    if max_visible is not None and not 0.0 < max_visible <= 1.0:
        raise ValueError(f"hidden_gaussians: max_visible must be in (0, 1] or None, got {max_visible}")
    if min_tail is not None and not 0.0 <= min_tail < 1.0:
        raise ValueError(f"hidden_gaussians: min_tail must be in [0, 1) or None, got {min_tail}")
    ratio, reach = surface_measures(gaussians, cameras, config=config, tail=min_tail is not None)
    hidden = behind_by(ratio, margin)
    if reach is not None:
        hidden &= reach > min_tail
    if max_visible is None or not bool(hidden.any()):
        return hidden
    return hidden & (visible_fraction(gaussians, cameras, config=config) < max_visible)


def blend_weights(gaussians, camera: Camera, *, config: RenderConfig | None = None) -> torch.Tensor:
    """``[N]`` float: each Gaussian's blending weight ``w_i = α_i T_i`` summed over the pixels of ``camera`` (pixels'
    worth; 0 for a Gaussian the view does not show).

    One render and one backward pass: with every colour at 0.5 (DC coefficient 0, higher bands 0, so nothing is
    clamped) the rendered red channel is ``Σ_i w_i (SH_C0 · dc_i + 0.5)`` per pixel, and the gradient of its sum with
    respect to ``dc_i`` is ``SH_C0 · Σ_pixels w_i``. The model itself is not touched.
    """
    dc = torch.zeros_like(gaussians.sh_dc.detach(), requires_grad=True)
    probe = SimpleNamespace(means=gaussians.means.detach(), rotations=gaussians.rotations.detach(),
                            scales=gaussians.scales.detach(), opacities=gaussians.opacities.detach(),
                            active_sh_degree=0, sh_dc=dc, sh_rest=torch.zeros_like(gaussians.sh_rest.detach()))
    with torch.enable_grad():
        render(probe, camera, config=config)["rgb"][..., 0].sum().backward()
    return dc.grad.reshape(dc.shape[0], -1)[:, 0] / SH_C0


@torch.no_grad()
def unoccluded_weight(gaussians, camera: Camera) -> torch.Tensor:
    """``[N]`` float: what :func:`blend_weights` would give with nothing in front of each Gaussian and the whole of it
    in the image, ``o_i · 2π √det Σ'_i`` (pixels), with ``Σ'_i`` its covariance projected to the image (the Jacobian
    of the pinhole at its centre); 0 where the centre is not in front of the camera."""
    means = gaussians.means.detach()
    pc = camera.to_camera_tensor(means)
    z = pc[:, 2]
    zs = torch.where(z > 0, z, torch.ones_like(z))
    R = means.new_tensor(camera.R)
    J = means.new_zeros(means.shape[0], 2, 3)
    J[:, 0, 0] = camera.fx / zs
    J[:, 0, 2] = -camera.fx * pc[:, 0] / zs**2
    J[:, 1, 1] = camera.fy / zs
    J[:, 1, 2] = -camera.fy * pc[:, 1] / zs**2
    M = J @ R @ quat_to_rotmat(gaussians.rotations.detach()) * gaussians.scales.detach()[:, None, :]  # [N, 2, 3]
    det = torch.linalg.det(M @ M.transpose(1, 2)).clamp_min(0.0)
    return torch.where(z > 0, gaussians.opacities.detach().reshape(-1) * 2 * math.pi * det.sqrt(),
                       torch.zeros_like(z))


def visible_fraction(gaussians, cameras: Sequence[Camera], *, config: RenderConfig | None = None) -> torch.Tensor:
    """``[N]`` float: the largest, over the views whose image holds a Gaussian's centre, of :func:`blend_weights` over
    :func:`unoccluded_weight`: about the transmittance in front of it in its best view (1 in the open, ~0 behind an
    opaque surface; 0 where no view holds its centre). Footprints cut by the image's edge or smaller than a pixel
    read low; the renderer's cut-offs (α < 1/255) make it read a little under 1 in the open.

    One render and one backward pass per camera."""
    if len(cameras) == 0:
        raise ValueError("visible_fraction: no cameras")
    means = gaussians.means.detach()
    best = torch.zeros(means.shape[0], device=means.device)
    for cam in cameras:
        inside = cam.in_image_tensor(means)[3]
        full = unoccluded_weight(gaussians, cam)
        frac = blend_weights(gaussians, cam, config=config) / full.clamp_min(1e-12)
        best = torch.maximum(best, torch.where(inside & (full > 0), frac, torch.zeros_like(frac)))
    return best
