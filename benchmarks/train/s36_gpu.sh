#!/usr/bin/env bash
# Session 36, first lease (two GPUs of one host): session 35's two prepared patches (benchmarks/train/results/s35/),
# each alone and both, against HEAD. Trees from patch_trees.sh, carried to /tmp/trees and linked as .s36/<label>.
#   GPU 1: DTU scan 24, dtu preset, 30k iterations with both patches (the preset's own settings);
#   GPU 0: the patched kernels' and activations' tests on CUDA, the float64 check of the patched CUDA renderer, the
#          step profile at 20,000 for base / pw / sh4 / both, and at 12,000 with the run's densification (every 100
#          iterations) for base and both.
# Needs Warp staged, benchmarks/device_setup.sh sourced, /tmp/gofdata/s32 and /tmp/gofdata/dtu_scan24. Writes
# $OUT/s36.tgz (packed after each stage: a call cut short still returns what it has).
set -u
R=$OUT/s36; mkdir -p $R /tmp/dtugeo /tmp/hp .s36
cp /tmp/gofdata/s32/*.npz /tmp/dtugeo/ 2>/dev/null
mkdir -p .s34data && ln -sfn /tmp/gofdata/dtu_scan24 .s34data/dtu_scan24
for t in pw sh4 both; do ln -sfn /tmp/trees/$t .s36/$t; ln -sfn ../kernels .s36/$t/gof_warp/kernels; \
  ln -sfn ../configs .s36/$t/gof_warp/configs; done
t0=$(date +%s)
pack() { cp /tmp/hp/run_dtu_both/metrics.json $R/dtu_30k_both_metrics.json 2>/dev/null
         cp $R/../ab/*.json $R/ 2>/dev/null; (cd $OUT && tar czf s36.tgz s36 2>/dev/null); }
(cd .s36/both && CUDA_VISIBLE_DEVICES=1 PYTHONPATH="$PWD:/tmp/site" timeout -s INT -k 20 ${TRAIN_S:-480} \
  python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 --out /tmp/hp/run_dtu_both --quiet > $R/dtu_train_both.log 2>&1; \
  echo "train rc $?" >> $R/dtu_train_both.log) &
export CUDA_VISIBLE_DEVICES=0
(cd .s36/both && PYTHONPATH="$PWD:/tmp/site" timeout 150 python3 -m pytest -q -p no:cacheprovider -x \
  tests/test_project_backward.py tests/test_model_ply.py > $R/cuda_tests.txt 2>&1)
echo "tests at $(( $(date +%s) - t0 )) s: $(tail -n 1 $R/cuda_tests.txt)"; pack
CHECK_TREE=.s36/both EX=/tmp/ex0 STEP="check" timeout 80 bash benchmarks/train/ab_trees.sh > $R/check.txt 2>&1
echo "check at $(( $(date +%s) - t0 )) s"; tail -n 8 $R/check.txt; pack
EX=/tmp/ex0 STEP="model profile" STARTS="20000" DTU=.s34data/dtu_scan24 \
  VARIANTS="base:. pw:.s36/pw sh4:.s36/sh4 both:.s36/both" timeout 250 bash benchmarks/train/ab_trees.sh > $R/profile.txt 2>&1
echo "profile 20k at $(( $(date +%s) - t0 )) s"; grep start $R/profile.txt; pack
EX=/tmp/ex0 STEP="profile" STARTS="12000" DTU=.s34data/dtu_scan24 \
  VARIANTS="base_d:.::densify.interval=100 both_d:.s36/both::densify.interval=100" timeout 130 \
  bash benchmarks/train/ab_trees.sh > $R/profile12.txt 2>&1
echo "profile 12k at $(( $(date +%s) - t0 )) s"; grep start $R/profile12.txt; pack
wait
tail -n 2 $R/dtu_train_both.log; pack; rm -rf $OUT/s36 $OUT/ab
