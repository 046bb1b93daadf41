"""Gaussians hidden behind the surface the renders show: what ``DensifyConfig.hidden_prune_iters`` removes.

The renderer composites each Gaussian at its peak ``t*`` along the ray, so a Gaussian whose centre lies behind an
opaque surface adds (almost) nothing to any photo and no loss moves it away. GOF's opacity field counts every
Gaussian before its peak too, by its tail ``α G(t)`` (``kernels.opacity_field``): a large Gaussian behind a surface
reaches through it and raises the field in front of it. On the synthetic ``background_full`` scene (session 28,
``benchmarks/real_captures/README.md``) ~2,900 round Gaussians of 12–19 cm that training left 5–100 cm behind the
far shell put the field at 0.41 five centimetres in front of the shell (0.04 without them): the mesh stood ~5 cm in
front of the photographed surface. Removed during training, the renders go on without them (the ground's rim there
was complete in both runs); left out of a finished model at extraction instead, they open surfaces behind the
half-transparent layer they backed (session 28's measurements).

* :func:`surface_depth_ratio` — each centre's depth over the rendered median depth at its pixel, the least over the
  training views whose image holds it where the render shows a surface.
* :func:`behind_surface` — the Gaussians whose centres lie behind the rendered median depth by more than
  ``margin`` × that depth in every such view (that ratio above ``1 + margin``).

Shapes: ``means [N, 3]``; returns ``[N]`` bool. The test reads the centre's pixel only: a Gaussian whose centre is
hidden but whose body shows beside an edge is kept only if some view's median depth at its centre is within the
margin (in practice a view that sees it from the side).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from .camera import Camera
from .render import RenderConfig, render


@torch.no_grad()
def surface_depth_ratio(gaussians, cameras: Sequence[Camera], *, config: RenderConfig | None = None) -> torch.Tensor:
    """``[N]`` float: the least ``z / D`` of each Gaussian's centre over the views that see where it is (``+inf``
    where none does); above 1 the centre lies behind the rendered surface in every such view.

    For each camera, the model's median depth ``D`` (:func:`gof_warp.render.render`) is read at the pixel of each
    centre that projects into the image (camera depth ``z > 0``, pixel ``(⌊u⌋, ⌊v⌋)``). The view *sees where it is*
    when ``D > 0`` there (a surface is rendered). One render per camera, whatever margin is applied afterwards.

    Args:
        gaussians: a model (:class:`gof_warp.model.Gaussians`), on any device.
        cameras: the views to test (the training views).
        config: the renderer's settings (the trainer's).
    """
    if len(cameras) == 0:
        raise ValueError("behind_surface: no cameras")
    means = gaussians.means.detach()
    least = torch.full((means.shape[0],), math.inf, device=means.device)
    for cam in cameras:
        depth = render(gaussians, cam, config=config)["median_depth"]
        u, v, z = cam.project_tensor(means)
        inside = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        col = torch.where(inside, u, 0.0).floor().long().clamp_(0, cam.width - 1)
        row = torch.where(inside, v, 0.0).floor().long().clamp_(0, cam.height - 1)
        d = depth[row, col]
        sees = inside & (d > 0)
        least = torch.minimum(least, torch.where(sees, z / torch.where(sees, d, 1.0), math.inf))
    return least


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
