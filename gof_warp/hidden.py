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

* :func:`behind_surface` — the Gaussians whose centres lie behind the rendered median depth by more than
  ``margin`` × that depth in every training view whose image holds them where the render shows a surface.

Shapes: ``means [N, 3]``; returns ``[N]`` bool. The test reads the centre's pixel only: a Gaussian whose centre is
hidden but whose body shows beside an edge is kept only if some view's median depth at its centre is within the
margin (in practice a view that sees it from the side).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from .camera import Camera
from .render import RenderConfig, render


@torch.no_grad()
def behind_surface(gaussians, cameras: Sequence[Camera], *, margin: float, config: RenderConfig | None = None
                   ) -> torch.Tensor:
    """``[N]`` bool: Gaussian ``i`` lies behind the surface in every view that sees where it is.

    For each camera, the model's median depth ``D`` (:func:`gof_warp.render.render`) is read at the pixel of each
    centre that projects into the image (camera depth ``z > 0``, pixel ``(⌊u⌋, ⌊v⌋)``). The view *sees where it is*
    when ``D > 0`` there (a surface is rendered); it finds the centre *behind* when ``z > (1 + margin) · D``. A
    Gaussian is returned True when at least one view sees where it is and every such view finds it behind.

    Args:
        gaussians: a model (:class:`gof_warp.model.Gaussians`), on any device.
        cameras: the views to test (the training views).
        margin: relative depth margin, ``> 0`` (0.01: 1 % of the surface's depth).
        config: the renderer's settings (the trainer's).
    """
    if not margin > 0:
        raise ValueError(f"behind_surface: margin must be > 0, got {margin}")
    if len(cameras) == 0:
        raise ValueError("behind_surface: no cameras")
    means = gaussians.means.detach()
    n = means.shape[0]
    seen = torch.zeros(n, dtype=torch.int32, device=means.device)
    not_behind = torch.zeros(n, dtype=torch.bool, device=means.device)
    for cam in cameras:
        depth = render(gaussians, cam, config=config)["median_depth"]
        u, v, z = cam.project_tensor(means)
        inside = (z > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        col = torch.where(inside, u, 0.0).floor().long().clamp_(0, cam.width - 1)
        row = torch.where(inside, v, 0.0).floor().long().clamp_(0, cam.height - 1)
        d = depth[row, col]
        sees = inside & (d > 0)
        seen += sees.to(torch.int32)
        not_behind |= sees & (z <= (1.0 + margin) * d)
    return (seen > 0) & ~not_behind
