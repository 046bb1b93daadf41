#!/usr/bin/env bash
# Session 35, third lease (two GPUs of one host): the Gaussians' activations compiled (gof_warp.model.Activation) and
# the SH colour backward's new lane layout, against the code before them (.s35/base, a git archive of 22a17b1).
#   GPU 1: DTU scan 24, dtu preset, 30k iterations with the working tree (the preset's own settings);
#   GPU 0: the CUDA tests of the changed kernels, the float64 check of the CUDA renderer, the step profile at 20,000
#          and 12,000, base against new.
# Needs Warp staged, benchmarks/device_setup.sh sourced, /tmp/gofdata/s32 and /tmp/gofdata/dtu_scan24. Writes
# $OUT/s35c.tgz (packed after each stage: a call cut short still returns what it has).
set -u
R=$OUT/s35c; mkdir -p $R /tmp/dtugeo /tmp/hp
cp /tmp/gofdata/s32/*.npz /tmp/dtugeo/ 2>/dev/null
mkdir -p .s34data && ln -sfn /tmp/gofdata/dtu_scan24 .s34data/dtu_scan24
t0=$(date +%s)
pack() { cp /tmp/hp/run_dtu_new/metrics.json $R/dtu_30k_new_metrics.json 2>/dev/null
         cp $R/../ab/*.json $R/ 2>/dev/null; (cd $OUT && tar czf s35c.tgz s35c 2>/dev/null); }
(CUDA_VISIBLE_DEVICES=1 timeout -s INT -k 20 ${TRAIN_S:-470} python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 \
  --out /tmp/hp/run_dtu_new --quiet > $R/dtu_train_new.log 2>&1; echo "train rc $?" >> $R/dtu_train_new.log) &
export CUDA_VISIBLE_DEVICES=0
timeout 100 python3 -m pytest -q -p no:cacheprovider -k cuda tests/test_render_host_glue.py > $R/cuda_tests.txt 2>&1
echo "tests at $(( $(date +%s) - t0 )) s: $(tail -n 1 $R/cuda_tests.txt)"
timeout 120 python3 - > $R/activation_cuda.txt 2>&1 <<'PY'
import torch
from gof_warp.model import Activation, Gaussians
torch.manual_seed(0)
n = 200_003
g = Gaussians(means=torch.randn(n, 3), quats=torch.randn(n, 4), log_scales=torch.randn(n, 3) - 3,
              opacity_logits=torch.randn(n), sh_dc=torch.randn(n, 3), sh_rest=torch.randn(n, 15, 3),
              filter_3d=torch.rand(n) * 0.01).to("cuda")
act = Activation(True, strict=True)
worst = {}
for m in (n, n - 1000):  # a second size: no recompile (dynamic N)
    for fn in (act, None):
        for p in g.params.values():
            p.grad = None
            p.requires_grad_(True)
        a = g.activated(fn)
        out = (a.rotations, a.scales, a.opacities)
        sum((t * torch.linspace(-1, 2, t.numel(), device="cuda").reshape(t.shape)).sum() for t in out).backward()
        res = [t.detach() for t in out] + [g.params[k].grad for k in ("quats", "log_scales", "opacity_logits")]
        if fn is act:
            got = res
    for name, a, b in zip(["rot", "scale", "opacity", "d_quats", "d_log_scales", "d_logits"], got, res):
        worst[name] = max(worst.get(name, 0.0), ((a - b).abs().max() / b.abs().max()).item())
    g.params = {k: v.detach()[:m].clone() for k, v in g.params.items()}
    g.filter_3d = g.filter_3d[:m].clone()
print("compiled vs eager, largest difference / largest value:", worst)
print("ok" if all(v < 1e-5 for v in worst.values()) else "FAIL")
PY
echo "activation at $(( $(date +%s) - t0 )) s: $(tail -n 2 $R/activation_cuda.txt | tr '\n' ' ')"; pack
EX=/tmp/ex0 STEP="check" timeout 80 bash benchmarks/train/ab_trees.sh > $R/check.txt 2>&1
echo "check at $(( $(date +%s) - t0 )) s"; tail -n 8 $R/check.txt; pack
EX=/tmp/ex0 STEP="model profile" STARTS="20000 12000" DTU=.s34data/dtu_scan24 VARIANTS="base:.s35/base new:." \
  timeout 260 bash benchmarks/train/ab_trees.sh > $R/profile.txt 2>&1
echo "profile at $(( $(date +%s) - t0 )) s"; grep start $R/profile.txt; pack
wait
tail -n 2 $R/dtu_train_new.log; pack; rm -rf $OUT/s35c $OUT/ab
