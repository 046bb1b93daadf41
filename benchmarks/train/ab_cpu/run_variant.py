"""Train with one variant patched in: ``run_variant.py prod|none TRAIN_ARGS...`` (prod: the 3D filter's opacity
compensation with ``torch.prod``, as before session 5). For benchmarks/train/ab_cpu/ab_seeds.sh only."""
import sys, torch
mode = sys.argv[1]
if mode == "prod":
    from gof_warp import model

    def opacities(self):
        o = self.raw_opacities
        if self.filter_3d is None:
            return o
        s2 = self.raw_scales ** 2
        ratio = torch.prod(s2, dim=1) / torch.prod(s2 + self.filter_3d[:, None] ** 2, dim=1)
        return o * torch.sqrt(ratio)

    model.Gaussians.opacities = property(opacities)
from gof_warp.train import main
sys.exit(main(sys.argv[2:]))
