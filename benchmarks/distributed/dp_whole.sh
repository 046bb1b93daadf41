#!/usr/bin/env bash
# Whole trainings on 1, 2, ... GPUs of one host (issue 17): the synthetic garden at RES (SCENE_VIEWS train views, the
# preset's test views) from SFM pseudo-SfM points (pseudo_sfm.py: visible GT-surface points, 2 mm noise),
# trained with CONFIG (garden_3k.yaml: the unbounded preset's schedule compressed 10x, densification and every
# regulariser on) at VIEWS views a step: one GPU renders them one after another, n GPUs VIEWS/n each. The 1-GPU run
# compiles Warp's kernels in its warm-up, outside its timed loop. Needs Warp staged, benchmarks/device_setup.sh
# sourced, trimesh among the carried wheels. Writes $OUT/dp_whole.json (+ each run's metrics.json) and a table.
# A GPU count listed twice is run twice (g1, g1_2, ...): the spread of two runs of the same setting, the yardstick for
# the PSNR differences between settings. EXTRA: further overrides for every run. Per run also the ms per step before
# and after SPLIT (the regularisers' start), from the history.
#   GPUS="1 2 4 1" VIEWS=4 SEED=0 bash benchmarks/distributed/dp_whole.sh
set -u
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1  # never NVLink multicast
GPUS=${GPUS:-"1 2 4"}; VIEWS=${VIEWS:-4}; RES=${RES:-"1024 768"}; SCENE_VIEWS=${SCENE_VIEWS:-48}; SFM=${SFM:-5000}
CONFIG=${CONFIG:-benchmarks/distributed/garden_3k.yaml}; SEED=${SEED:-0}; EXTRA=${EXTRA:-}; SPLIT=${SPLIT:-1500}
S=/tmp/dp_steady/scene; W=/tmp/dp_whole; rm -rf $W; mkdir -p $W "$OUT/dp_whole"
t0=$(date +%s)
if [ ! -f $S/transforms_train.json ]; then
  python3 -m gof_warp.synthetic --preset garden --resolution $RES --views $SCENE_VIEWS --out $S --device cuda:0 --quiet \
    || { echo "scene generation failed"; exit 1; }
fi
if [ ! -f $S/points3d.ply ]; then
  python3 benchmarks/distributed/pseudo_sfm.py $S $SFM || { echo "pseudo-SfM failed"; exit 1; }
fi
echo "scene and points at $(( $(date +%s) - t0 )) s"
ARGS=($S --config "$CONFIG" --no-pictures --quiet "views_per_step=$VIEWS" "seed=$SEED" $EXTRA)
LABELS=""
for n in $GPUS; do
  tag=g$n; k=2; while [[ " $LABELS " == *" $tag "* ]]; do tag=g${n}_$k; k=$((k + 1)); done; LABELS="$LABELS $tag"
  if [ "$n" = 1 ]; then
    python3 -m gof_warp.train "${ARGS[@]}" --out $W/$tag > $W/$tag.log 2>&1
  else
    python3 -m torch.distributed.run --standalone --nproc_per_node "$n" -m gof_warp.train "${ARGS[@]}" --out $W/$tag \
      > $W/$tag.log 2>&1
  fi
  echo "$tag: $n GPU(s) rc $? at $(( $(date +%s) - t0 )) s: $(grep -h 'done:' $W/$tag.log)"
  cp $W/$tag/metrics.json "$OUT/dp_whole/metrics_$tag.json" 2>/dev/null || tail -n 20 $W/$tag.log
done
python3 - "$OUT" "$LABELS" "$VIEWS" "$RES" "$SCENE_VIEWS" "$CONFIG" "$SEED" "$SPLIT" "$EXTRA" <<'PY'
import json, subprocess, sys
from pathlib import Path
out, labels, views, res, sv, config, seed, split, extra = Path(sys.argv[1]), sys.argv[2].split(), *sys.argv[3:]
split = int(split)


def ms_per_step(history, lo, hi):
    """Mean ms per step between the history rows at iterations lo and hi (None if either is missing)."""
    at = {h["iteration"]: h["elapsed_s"] for h in history}
    return round((at[hi] - at[lo]) / (hi - lo) * 1000.0, 2) if lo in at and hi in at else None


rows = {}
for tag in labels:
    f = out / "dp_whole" / f"metrics_{tag}.json"
    if not f.is_file():
        continue
    d = json.loads(f.read_text())
    spikes = d.get("loss_spikes", {})
    h, last = d.get("history", []), d.get("iterations")
    rows[tag] = {"train_time_s": d["train_time_s"], "warmup_s": d.get("warmup_s"), "num_gaussians": d["num_gaussians"],
                 "test_psnr": d["test"]["psnr"], "test_ssim": d["test"].get("ssim"), "processes": d.get("processes"),
                 "loss_compiled": d.get("loss_compiled"), "largest_loss_ratio": spikes.get("max_ratio"),
                 "gpu_peak_allocated_mb": d.get("gpu_peak_allocated_mb"),
                 "ms_per_step_before_split": ms_per_step(h, 100, split), "ms_per_step_after_split": ms_per_step(h, split, last)}
base = rows.get("g1", {}).get("train_time_s")
for r in rows.values():
    r["speedup_vs_1"] = round(base / r["train_time_s"], 3) if base else None
    r["psnr_minus_1gpu"] = round(r["test_psnr"] - rows["g1"]["test_psnr"], 3) if "g1" in rows else None
gpu = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True, text=True).stdout
result = {"what": "whole trainings on 1..n GPUs (benchmarks/distributed/dp_whole.sh)", "config": config, "seed": int(seed),
          "extra_overrides": extra, "split_iteration": split,
          "scene": f"synthetic garden, {res.replace(' ', 'x')}, {sv} train views", "views_per_step": int(views),
          "gpus": gpu.strip().splitlines(), "runs": rows}
(out / "dp_whole.json").write_text(json.dumps(result, indent=1))
for g, r in rows.items():
    print(f"{g}: {r['train_time_s']} s x{r['speedup_vs_1']} ({r['ms_per_step_before_split']} / "
          f"{r['ms_per_step_after_split']} ms a step), test PSNR {r['test_psnr']:.3f} ({r['psnr_minus_1gpu']:+}), "
          f"{r['num_gaussians']} Gaussians, loss ratio {r['largest_loss_ratio']}, compiled {r['loss_compiled']}")
PY
