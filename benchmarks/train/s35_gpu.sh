#!/usr/bin/env bash
# Session 35, first lease (two GPUs of one host): where the step's time goes with today's code.
#   GPU 1: DTU scan 24, dtu preset, 30k iterations with the working tree at the preset's own checkpoint cadence (5000);
#   GPU 0: the CUDA tests of the reject and host glue, host_budget.py's loss and appearance parts with their kernels
#          (TF32 on and off for cuDNN, cudnn.benchmark on as a run sets it), the step profile at 20,000 and 12,000.
# Needs Warp staged, benchmarks/device_setup.sh sourced, /tmp/gofdata/s32 (session 32's packed DTU model) and the DTU
# scene in /tmp/gofdata/dtu_scan24. Writes $OUT/s35.tgz.
set -u
R=$OUT/s35; mkdir -p $R /tmp/dtugeo /tmp/hp
cp /tmp/gofdata/s32/*.npz /tmp/dtugeo/ 2>/dev/null
mkdir -p .s34data && ln -sfn /tmp/gofdata/dtu_scan24 .s34data/dtu_scan24
t0=$(date +%s)
pack() { cp /tmp/hp/run_dtu/metrics.json $R/dtu_30k_metrics.json 2>/dev/null; (cd $OUT && tar czf s35.tgz s35 ab 2>/dev/null); }
(CUDA_VISIBLE_DEVICES=1 timeout -s INT -k 20 ${TRAIN_S:-480} python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 \
  --out /tmp/hp/run_dtu --quiet > $R/dtu_train.log 2>&1; echo "train rc $?" >> $R/dtu_train.log) &
export CUDA_VISIBLE_DEVICES=0
timeout 120 python3 -m pytest -q -p no:cacheprovider -k cuda tests/test_early_reject.py tests/test_render_host_glue.py \
  > $R/cuda_tests.txt 2>&1
echo "tests at $(( $(date +%s) - t0 )) s: $(tail -n 1 $R/cuda_tests.txt)"; pack
timeout 200 python3 benchmarks/train/host_budget.py --out $R/host_budget.json --parts appearance,loss --cudnn-benchmark \
  --fp32-conv --kernels 25 > $R/host_budget.txt 2>&1
echo "budget at $(( $(date +%s) - t0 )) s"; grep -E "host .* gpu" $R/host_budget.txt; pack
EX=/tmp/ex0 STEP="model profile" STARTS="20000 12000" VARIANTS="now:." DTU=.s34data/dtu_scan24 \
  timeout 200 bash benchmarks/train/ab_trees.sh > $R/profile.txt 2>&1
echo "profile at $(( $(date +%s) - t0 )) s"; grep start $R/profile.txt; pack
wait
tail -n 3 $R/dtu_train.log; pack; rm -rf $OUT/s35 $OUT/ab
