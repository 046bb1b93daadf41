"""WarpAdam inside a real training run, checked at every step against Adam written out in torch.

    python benchmarks/train/warp_adam_shadow.py [--iterations 1200] [--against-fused] [train options / overrides ...]

Trains with ``optim.adam=warp`` (the README job's built-in scene unless a scene is given) and wraps ``WarpAdam.step``:
before each step it copies every parameter, gradient and moment, after it recomputes the step in torch (float32,
torch's unfused formula) from the copies and records the largest difference from what the kernel wrote, relative to
the size of the step (the kernel does torch's fused CUDA arithmetic, whose 1 − β₂ is 1 − fl(0.999):
expect ~1e-5 of the step against this formula, or one float32 ulp of the parameter where the steps are small); a
parameter without a gradient must come back unchanged, and every step counter must have moved by one.
Densification (new tensors, new launches), opacity resets and the gradients' changing addresses are all in the run.
Prints the worst case every 100 steps and at the end; exits with 3 (a parameter without a gradient moved) or 4
(a step counter is wrong).
"""

from __future__ import annotations

import math
import sys

import torch

from gof_warp.training.optim import WarpAdam
from gof_warp.cli.train import main as train_main

worst = {"relative_to_step": 0.0, "step": None, "group": None}
#: ``--against-fused`` (a CUDA run): the reference is torch's own fused CUDA Adam (``torch._fused_adam_``, what
#: ``LeanAdam`` and ``Adam(fused=True)`` call) on the copies, and every float of the parameter and both moments must
#: equal it bit for bit: ``differing`` counts those that do not (expect 0).
AGAINST_FUSED = [False]
_original = WarpAdam.step
_calls = [0]


def _checked_step(self, closure=None):
    _calls[0] += 1
    before = {p: (p.detach().clone(), None if p.grad is None else p.grad.clone(),
                  {k: (v.clone() if torch.is_tensor(v) else v) for k, v in self.state.get(p, {}).items()})
              for g in self.param_groups for p in g["params"]}
    out = _original(self, closure)
    for g in self.param_groups:
        beta1, beta2 = g["betas"]
        for p in g["params"]:
            p0, grad, st = before[p]
            if grad is None:
                if not torch.equal(p0, p.detach()):
                    print(f"step {_calls[0]}: group {g.get('name')} has no gradient but moved")
                    sys.exit(3)
                continue
            if not st:
                st = {"step": torch.tensor(0.0), "exp_avg": torch.zeros_like(p0), "exp_avg_sq": torch.zeros_like(p0)}
            t = float(st["step"]) + 1
            if float(self.state[p]["step"]) != t:
                print(f"step {_calls[0]}: group {g.get('name')} step counter {float(self.state[p]['step'])}, not {t}")
                sys.exit(4)
            if AGAINST_FUSED[0]:
                p1, m1, v1 = p0.clone(), st["exp_avg"].clone(), st["exp_avg_sq"].clone()
                steps = [torch.tensor(t, dtype=torch.float32, device=p1.device)]
                torch._fused_adam_([p1], [grad], [m1], [v1], [], steps, lr=g["lr"], beta1=beta1, beta2=beta2,
                                   weight_decay=0.0, eps=g["eps"], amsgrad=False, maximize=False)
                state = self.state[p]
                bad = sum(int((a != b).sum()) for a, b in ((p1, p.detach()), (m1, state["exp_avg"]),
                                                          (v1, state["exp_avg_sq"])))
                worst["differing"] = worst.get("differing", 0) + bad
                if bad and worst.get("first_differing") is None:
                    worst["first_differing"] = (_calls[0], g.get("name"), bad)
                continue
            m = st["exp_avg"].lerp(grad, 1 - beta1)
            v = st["exp_avg_sq"] * beta2 + (1 - beta2) * grad * grad
            ref = p0 - (g["lr"] / (1 - beta1**t)) * (m / (v.sqrt() / math.sqrt(1 - beta2**t) + g["eps"]))
            moved = (ref - p0).abs().max().item()
            rel = (ref - p.detach()).abs().max().item() / max(moved, 1e-30)
            if rel > worst["relative_to_step"]:
                worst.update(relative_to_step=rel, step=_calls[0], group=g.get("name"), largest_step=moved)
    if _calls[0] % 100 == 0:
        print("step", _calls[0], "worst so far", worst, flush=True)
    return out


def main() -> None:
    args = sys.argv[1:]
    iterations = "1200"
    if "--iterations" in args:
        i = args.index("--iterations")
        iterations = args[i + 1]
        del args[i : i + 2]
    if "--against-fused" in args:
        args.remove("--against-fused")
        AGAINST_FUSED[0] = True
    WarpAdam.step = _checked_step
    sys.argv = ["train", "--quiet", "--no-pictures", "--iterations", iterations, *args, "optim.adam=warp"]
    if "--out" not in args:
        sys.argv[1:1] = ["--out", "runs/warp_adam_shadow"]
    rc = train_main()
    print("FINAL worst", worst)
    sys.exit(rc or 0)  # a training that failed (e.g. an --out already in use) is not a passed check


if __name__ == "__main__":
    main()
