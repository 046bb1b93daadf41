#!/usr/bin/env bash
# What the opt-in multi-view term (loss.multiview) costs per training step on a GPU: the synthetic background_full
# scene at 400x400 (100 views, points carried in POINTS/background_full/points3d.ply), 3,000 iterations with and without
# the term from iteration 1,000, each run alone, with the eager loss and compiled (compile_loss=on, as a 30k run has it
# by default); ms per iteration over 1,000-3,000 from metrics.json's history. A variant ending in _on8 compares every
# patch with all 8 candidate neighbours a step (loss.multiview.neighbours_per_step=8) instead of one.
#   POINTS=/tmp/pts [VARIANTS="compiled_off compiled_on compiled_on8"] bash benchmarks/real_captures/multiview_cost.sh
#   (writes $OUT/multiview_cost.json)
set -eu
S=/tmp/mvc/background_full
python3 -m gof_warp.synthetic --preset background_full --out $S --resolution 400 400 --views 100 --force >/dev/null 2>&1
cp "$POINTS/background_full/points3d.ply" $S/
VARIANTS=${VARIANTS:-eager_off eager_on compiled_off compiled_on}
for v in $VARIANTS; do
  w=0; k=1; case $v in *_on) w=0.15 ;; *_on8) w=0.15; k=8 ;; esac
  c=off; case $v in compiled_*) c=on ;; esac
  python3 -m gof_warp.train $S --out /tmp/mvc/run_$v --iterations 3000 checkpoint_every=0 log_every=100 compile_loss=$c \
    loss.multiview.weight=$w loss.multiview.neighbours_per_step=$k loss.multiview.from_iter=1000 --no-pictures \
    --quiet > /tmp/mvc/train_$v.log 2>&1
done
VARIANTS=$VARIANTS python3 - <<'PY'
import json, os
out = {}
for v in os.environ["VARIANTS"].split():
    h = {r["iteration"]: r for r in json.load(open(f"/tmp/mvc/run_{v}/metrics.json"))["history"]}
    out[v] = {"ms_per_iteration_1000_3000": 1000 * (h[3000]["elapsed_s"] - h[1000]["elapsed_s"]) / 2000,
              "multiview_last": h[3000].get("multiview"), "gaussians": h[3000]["num_gaussians"]}
import torch
out["device"] = torch.cuda.get_device_name(0)
print(json.dumps(out, indent=1))
json.dump(out, open(os.path.join(os.environ.get("OUT", "/tmp"), "multiview_cost.json"), "w"), indent=1)
PY
