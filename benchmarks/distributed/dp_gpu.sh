#!/usr/bin/env bash
# Data-parallel training on the GPU machine: the same run (DTU scan 24, dtu preset, $IT iterations, 2 views
# per step) on one GPU and on $NPROC GPUs (torchrun, NCCL). Needs Warp staged, benchmarks/device_setup.sh
# sourced and the DTU scene in /tmp/gofdata. Writes $OUT/dp_<n>gpu.json (metrics.json of each run).
set -u
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1  # never NVLink multicast
IT=${IT:-2000}
NPROC=${NPROC:-2}
VIEWS=${VIEWS:-$NPROC}
mkdir -p /tmp/dp
COMMON=(/tmp/gofdata/dtu_scan24 --iterations "$IT" --no-pictures --quiet checkpoint_every=0 "views_per_step=$VIEWS")
# compile Warp's kernels and cache the triangulated points once, outside the timed runs
python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 --out /tmp/dp/warm --iterations 10 --no-pictures --quiet \
  checkpoint_every=0 > /tmp/dp/warm.log 2>&1 || { tail -20 /tmp/dp/warm.log; exit 1; }
python3 -m gof_warp.train "${COMMON[@]}" --out /tmp/dp/one > /tmp/dp/one.log 2>&1
echo "1 GPU rc $?: $(grep -h 'done:' /tmp/dp/one.log)"
python3 -m torch.distributed.run --standalone --nproc_per_node "$NPROC" -m gof_warp.train "${COMMON[@]}" \
  --out /tmp/dp/many > /tmp/dp/many.log 2>&1
echo "$NPROC GPUs rc $?: $(grep -h 'done:' /tmp/dp/many.log)"
tail -5 /tmp/dp/many.log
cp /tmp/dp/one/metrics.json $OUT/dp_1gpu.json 2>/dev/null
cp /tmp/dp/many/metrics.json $OUT/dp_${NPROC}gpu.json 2>/dev/null
nvidia-smi --query-gpu=name --format=csv,noheader
