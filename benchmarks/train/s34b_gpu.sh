#!/usr/bin/env bash
# Session 34, second lease (two GPUs of one host): the warp mask of the CUDA tile kernels (rasterize_tiled.
# warp_rows_mask: a warp skips a list entry whose silhouette misses all its pixels, worked out once per entry and block).
#   GPU 1: DTU scan 24, dtu preset, 30k iterations with the working tree (checkpoint_every 1000, as sessions 31 and 34);
#   GPU 0: the CUDA tests of the reject, the float64 check of the CUDA kernels, the step profile and the renderer
#          benchmark, the code before (.s34/before, a git archive of 6f0f107: the renderer as at HEAD~) against the
#          working tree, alternating.
# Needs Warp staged, benchmarks/device_setup.sh sourced, /tmp/gofdata/s32 (session 32's packed DTU model) and the DTU
# scene in /tmp/gofdata/dtu_scan24. Writes $OUT/s34b.tgz.
set -u
R=$OUT/s34b; mkdir -p $R /tmp/dtugeo /tmp/hp
cp /tmp/gofdata/s32/*.npz /tmp/dtugeo/ 2>/dev/null
mkdir -p .s34data && ln -sfn /tmp/gofdata/dtu_scan24 .s34data/dtu_scan24
t0=$(date +%s)
pack() { cp /tmp/hp/run_dtu_wm/metrics.json $R/dtu_30k_metrics.json 2>/dev/null; (cd $OUT && tar czf s34b.tgz s34b ab 2>/dev/null); }
(CUDA_VISIBLE_DEVICES=1 timeout -s INT -k 20 ${TRAIN_S:-450} python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 \
  --out /tmp/hp/run_dtu_wm checkpoint_every=1000 --quiet > $R/dtu_train.log 2>&1; echo "train rc $?" >> $R/dtu_train.log) &
export CUDA_VISIBLE_DEVICES=0
timeout 100 python3 -m pytest -q -p no:cacheprovider -k cuda tests/test_early_reject.py > $R/cuda_tests.txt 2>&1
echo "tests at $(( $(date +%s) - t0 )) s: $(tail -n 1 $R/cuda_tests.txt)"; pack
EX=/tmp/ex0 STEP="check" timeout 90 bash benchmarks/train/ab_trees.sh > $R/check.txt 2>&1
echo "check at $(( $(date +%s) - t0 )) s"; pack
EX=/tmp/ex0 STEP="model profile" STARTS="20000 12000" VARIANTS="old:.s34/before new:." DTU=.s34data/dtu_scan24 \
  timeout 230 bash benchmarks/train/ab_trees.sh > $R/profile.txt 2>&1
echo "profile at $(( $(date +%s) - t0 )) s"; grep start $R/profile.txt; pack
EX=/tmp/ex0 STEP="render" RENDER_TREES=".s34/before ." POINTS="1000000:1920x1080 1000000:800x600" timeout 100 \
  bash benchmarks/train/ab_trees.sh > $R/render.txt 2>&1
echo "render at $(( $(date +%s) - t0 )) s"; cat $R/render.txt | cut -c1-150
pack; wait
tail -n 2 $R/dtu_train.log; pack; rm -rf $OUT/s34b $OUT/ab
