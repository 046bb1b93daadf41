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
"""

from __future__ import annotations

import torch

from .camera import Camera


def centre_depths(means: torch.Tensor, camera: Camera) -> tuple[torch.Tensor, torch.Tensor]:
    """``(depth [N], in_image [N] bool)`` of centres ``means [N, 3]``: camera-space ``z`` and whether the centre is
    in front of the camera (``z > 0``) and projects inside the image (``0 <= u < width``, ``0 <= v < height``)."""
    u, v, z = camera.project_tensor(means)
    inside = (z > 0) & (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
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
