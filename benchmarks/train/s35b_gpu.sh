#!/usr/bin/env bash
# Session 35, second lease (two GPUs of one host): the appearance network's convolutions in float32 proper and with
# its full-resolution layers channels-last.
#   GPU 1: DTU scan 24, dtu preset, 30k iterations with cudnn_tf32=false (the preset's checkpoint cadence);
#   GPU 0: on H200s the same run with the defaults (the baseline on that card); on H100s (baseline: first lease,
#          331.2 s) host_budget.py's appearance and loss parts with TF32 on and off, the step profile at 20,000 with
#          the four settings, Nsight Compute on sh_colour_backward.
# Needs Warp staged, benchmarks/device_setup.sh sourced, /tmp/gofdata/s32 and /tmp/gofdata/dtu_scan24. Writes
# $OUT/s35b.tgz.
set -u
R=$OUT/s35b; mkdir -p $R /tmp/dtugeo /tmp/hp
cp /tmp/gofdata/s32/*.npz /tmp/dtugeo/ 2>/dev/null
mkdir -p .s34data && ln -sfn /tmp/gofdata/dtu_scan24 .s34data/dtu_scan24
t0=$(date +%s)
pack() { for r in fp32 base; do cp /tmp/hp/run_dtu_$r/metrics.json $R/dtu_30k_${r}_metrics.json 2>/dev/null; done
         (cd $OUT && tar czf s35b.tgz s35b ab 2>/dev/null); }
train() {  # train GPU LABEL OVERRIDES...
  local gpu=$1 label=$2; shift 2
  (CUDA_VISIBLE_DEVICES=$gpu timeout -s INT -k 20 ${TRAIN_S:-500} python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 \
    --out /tmp/hp/run_dtu_$label --quiet "$@" > $R/dtu_train_$label.log 2>&1; echo "train rc $?" >> $R/dtu_train_$label.log)
}
train 1 fp32 cudnn_tf32=false &
export CUDA_VISIBLE_DEVICES=0
if nvidia-smi --query-gpu=name --format=csv,noheader | head -1 | grep -q H200; then
  train 0 base
else
  for tf in tf32 fp32; do
    flag=(); [ $tf = fp32 ] && flag=(--no-tf32)
    timeout 150 python3 benchmarks/train/host_budget.py --out $R/host_budget_$tf.json --parts appearance,loss \
      --loss-modes graphs --cudnn-benchmark --kernels 20 "${flag[@]}" > $R/host_budget_$tf.txt 2>&1
    echo "budget $tf at $(( $(date +%s) - t0 )) s"; grep -E "host .* gpu" $R/host_budget_$tf.txt; pack
  done
  EX=/tmp/ex0 STEP="model profile" STARTS="20000" DTU=.s34data/dtu_scan24 VARIANTS="now:. fp32:.::cudnn_tf32=false \
tailcl:.::appearance_tail_channels_last=true both:.::cudnn_tf32=false,appearance_tail_channels_last=true" \
    timeout 230 bash benchmarks/train/ab_trees.sh > $R/profile.txt 2>&1
  echo "profile at $(( $(date +%s) - t0 )) s"; grep start $R/profile.txt; pack
  EX=/tmp/ex0 TREES=new KERNEL=sh_colour_backward START=20000 DTU=$PWD/.s34data/dtu_scan24 OLD=. timeout 100 \
    bash benchmarks/train/ncu_step.sh > $R/ncu.txt 2>&1; cp $OUT/ncu_new_20000.txt $R/ 2>/dev/null; rm -f $OUT/ncu_*.txt
  echo "ncu at $(( $(date +%s) - t0 )) s"; cat $R/ncu.txt; pack
fi
wait
for r in fp32 base; do tail -n 2 $R/dtu_train_$r.log 2>/dev/null; done; pack; rm -rf $OUT/s35b $OUT/ab
