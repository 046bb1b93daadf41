"""The Gaussians of the `background` scene's shell (radius 6): ``shell_gaussians.py MODEL [MODEL ...]``.

MODEL is a run's ``point_cloud.ply`` or a checkpoint (``ckpt_*.pt``). Per model: how many Gaussians have their
centre 5-7 from the origin and above the ground's neighbourhood (z > -0.5), their centres' radius (p10/50/90: where
the shell's Gaussians sit against the true radius 6), their smallest and largest scale (median), the smallest over
the largest, the median opacity and how well the smallest axis (the normal) lines up with the radial direction.
Written in session 15 for the flattening experiment (README, session 15)."""

import sys
from pathlib import Path

import numpy as np
import torch

from gof_warp.model import Gaussians, quat_to_rotmat


def load(path: Path) -> dict[str, torch.Tensor]:
    if path.suffix == ".pt":
        return torch.load(path, weights_only=True, map_location="cpu")["params"]
    return {k: v.detach() for k, v in Gaussians.load_ply(path).params.items()}


def shell_stats(p: dict[str, torch.Tensor]) -> str:
    means = p["means"].double()
    r = means.norm(dim=1)
    shell = (r > 5) & (r < 7) & (means[:, 2] > -0.5)
    s = torch.exp(p["log_scales"][shell].double())
    smin, smax = s.min(dim=1), s.max(dim=1).values
    rot = quat_to_rotmat(p["quats"][shell].double())
    normal = rot[torch.arange(len(rot)), :, smin.indices]  # the axis of the smallest scale
    cos = (normal * means[shell] / r[shell, None]).sum(dim=1).abs()
    opacity = torch.sigmoid(p["opacity_logits"][shell].double())
    q = lambda x, *qs: np.round(np.quantile(x.numpy(), qs), 4).tolist()  # noqa: E731
    return (f"N {len(means)}, shell {int(shell.sum())}, radius p10/50/90 {q(r[shell], 0.1, 0.5, 0.9)}, "
            f"min scale p50/p90 {q(smin.values, 0.5, 0.9)}, max scale p50 {q(smax, 0.5)}, opacity p50 {q(opacity, 0.5)}, "
            f"|cos(normal, radial)| p50 {q(cos, 0.5)}, min/max p50 {q(smin.values / smax, 0.5)}")


if __name__ == "__main__":
    for arg in sys.argv[1:]:
        print(f"{arg}: {shell_stats(load(Path(arg)))}")
