#!/usr/bin/env bash
# Test PSNR of n-GPU trainings against one GPU's, several seeds a side (issue 17: "within 0.1 dB of one GPU"). Each
# GPU count n of GPUS trains SEEDS with CONFIG (default_3k.yaml) on the synthetic PRESET scene at RES with SCENE_VIEWS
# training views, VIEWS views a step (one GPU renders them one after another, n GPUs VIEWS/n each). Runs of one GPU
# count share the host's GPUs: NGPU/n runs at once, each on its own GPUs, so their times are NOT speed figures.
# Resumable across calls while the machine stays warm: finished runs (under /tmp/dp_psnr) are skipped, and no new
# wave starts after BUDGET_S seconds. Needs Warp staged and benchmarks/device_setup.sh sourced. Writes
# $OUT/dp_psnr$TAG/metrics_g{n}_s{seed}.json and psnr_equivalence.py's summary. ALONE=1 TAG=_alone runs one at a
# time (speed figures).
#   GPUS="1 2 4" SEEDS="0 1 2 3" BUDGET_S=420 bash benchmarks/distributed/dp_psnr.sh
set -u
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1  # never NVLink multicast
GPUS=${GPUS:-"1 2 4"}; SEEDS=${SEEDS:-"0 1 2 3"}; VIEWS=${VIEWS:-4}; PRESET=${PRESET:-default}; RES=${RES:-"800 800"}
SCENE_VIEWS=${SCENE_VIEWS:-100}; CONFIG=${CONFIG:-benchmarks/distributed/default_3k.yaml}; BUDGET_S=${BUDGET_S:-420}
EXTRA=${EXTRA:-}; NGPU=$(nvidia-smi -L | wc -l); TAG=${TAG:-}
S=/tmp/dp_psnr/scene_$PRESET; W=/tmp/dp_psnr/runs$TAG; R="$OUT/dp_psnr$TAG"; mkdir -p $W "$R"
t0=$(date +%s)
if [ ! -f $S/transforms_train.json ]; then
  python3 -m gof_warp.synthetic --preset $PRESET --resolution $RES --views $SCENE_VIEWS --out $S --device cuda:0 \
    --force --quiet || { echo "scene generation failed"; exit 1; }
fi
echo "scene at $(( $(date +%s) - t0 )) s"

run() {  # n seed first_gpu
  local n=$1 seed=$2 g=$3 tag=g$1_s$2 devs
  devs=$(seq -s, "$g" $((g + n - 1)))
  local args=($S --config "$CONFIG" --no-pictures --quiet "views_per_step=$VIEWS" "seed=$seed" $EXTRA --out $W/$tag)
  if [ "$n" = 1 ]; then
    CUDA_VISIBLE_DEVICES=$devs python3 -m gof_warp.train "${args[@]}" > $W/$tag.log 2>&1
  else
    CUDA_VISIBLE_DEVICES=$devs python3 -m torch.distributed.run --standalone --nproc_per_node "$n" -m gof_warp.train \
      "${args[@]}" > $W/$tag.log 2>&1
  fi
  echo "$tag on GPUs $devs: rc $? at $(( $(date +%s) - t0 )) s: $(grep -h 'done:' $W/$tag.log)"
}

for n in $GPUS; do
  slots=$((NGPU / n)); [ "${ALONE:-0}" = 1 ] && slots=1; [ "$slots" -ge 1 ] || { echo "$n GPUs asked, $NGPU here"; continue; }
  todo=(); for s in $SEEDS; do [ -f $W/g${n}_s$s/metrics.json ] || todo+=("$s"); done
  while [ ${#todo[@]} -gt 0 ]; do
    if [ $(( $(date +%s) - t0 )) -gt "$BUDGET_S" ]; then echo "budget spent: ${#todo[@]} run(s) of $n GPU(s) left"; break 2; fi
    wave=("${todo[@]:0:$slots}"); todo=("${todo[@]:$slots}")
    k=0; for s in "${wave[@]}"; do run "$n" "$s" $((k * n)) & k=$((k + 1)); done; wait
    for s in "${wave[@]}"; do
      [ -f $W/g${n}_s$s/metrics.json ] || { echo "g${n}_s$s failed:"; tail -n 15 $W/g${n}_s$s.log; }
    done
  done
done
for f in $W/g*_s*/metrics.json; do [ -f "$f" ] && cp "$f" "$R/metrics_$(basename "$(dirname "$f")").json"; done
nvidia-smi --query-gpu=name --format=csv,noheader > "$R/gpus.txt"
python3 benchmarks/distributed/psnr_equivalence.py "$R" --out "$R/summary.json"
