#!/usr/bin/env bash
# Session 38 (one H200; issue 14): WarpAdam with torch's fused CUDA arithmetic checked on a GPU, the step's host and
# GPU time on this machine, and DTU 30k runs alone on the GPU.
#   STAGE=checks:  the host's CPU; the CUDA tests of WarpAdam (torch's fused Adam bit for bit); warp_adam_check.py at
#                  DTU's final size (differing_floats); adam_roofline.py at 848,237 Gaussians; the two models the
#                  profiles start from (session 32's 781k DTU model, and 1,000 iterations of the dtu preset)
#   STAGE=profile: profile_train.py (ab_trees.sh) at 1,000 iterations on the small model and at 20,000 on the 781k
#                  one, for VARIANTS_1000 / VARIANTS_20000 (labels:tree[::overrides]); the tree .s38/dst is HEAD with
#                  results/s37/densify_stats_kernel.patch (patch_trees.sh .s38 dst=densify_stats_kernel)
#   STAGE=train:   DTU scan 24, 30k iterations, dtu preset, alone on the GPU, with $OVERRIDES, from the tree $TREE
#                  (default the working tree); files named run_$NAME
# Needs Warp staged, benchmarks/device_setup.sh sourced, /tmp/gofdata/dtu_scan24 and (checks) /tmp/gofdata/s32.
# Writes $OUT/s38_$STAGE.tgz.
set -u
R=$OUT/s38_$STAGE; mkdir -p $R /tmp/hp
mkdir -p .s34data && ln -sfn /tmp/gofdata/dtu_scan24 .s34data/dtu_scan24
export CUDA_VISIBLE_DEVICES=0
t0=$(date +%s)
pack() {
  cp $OUT/ab/*.json $R/ 2>/dev/null; (cd $OUT && tar czf s38_$STAGE.tgz s38_$STAGE 2>/dev/null); rm -rf $R $OUT/ab
}
case $STAGE in
checks)
  { lscpu | grep -E "Model name|^CPU\(s\)|MHz"; nvidia-smi --query-gpu=name,memory.total,driver_version,clocks.max.sm \
      --format=csv,noheader; python3 -c "import torch, warp; print(torch.__version__, warp.__version__)"; } \
    > $R/machine.txt 2>&1
  cat $R/machine.txt
  timeout 90 python3 -m pytest -q -p no:cacheprovider -k cuda tests/test_warp_adam.py > $R/cuda_tests_adam.txt 2>&1
  echo "tests at $(( $(date +%s) - t0 )) s: $(tail -n 1 $R/cuda_tests_adam.txt)"
  timeout 120 python3 benchmarks/train/warp_adam_check.py > $R/warp_adam_check.txt 2>&1
  echo "check at $(( $(date +%s) - t0 )) s: \
    $(grep -E 'differing|worst' $R/warp_adam_check.txt | tail -n 4 | tr '\n' ' ')"
  timeout 90 python3 benchmarks/train/adam_roofline.py --gaussians 848237 --out $R/adam_roofline.json \
    > $R/adam_roofline.txt 2>&1
  echo "roofline at $(( $(date +%s) - t0 )) s:"; tail -n 8 $R/adam_roofline.txt
  mkdir -p /tmp/dtugeo && cp /tmp/gofdata/s32/*.npz /tmp/dtugeo/
  EX=/tmp/ex0 STEP=model DTU=.s34data/dtu_scan24 timeout 100 bash benchmarks/train/ab_trees.sh > $R/model.txt 2>&1
  mv /tmp/dtugeo /tmp/dtugeo_s32  # else ab_trees.sh's model step unpacks session 32's model again
  EX=/tmp/ex1 STEP=model MODEL_ITERS=1000 DTU=.s34data/dtu_scan24 timeout 150 bash benchmarks/train/ab_trees.sh \
    > $R/model_small.txt 2>&1
  mv /tmp/dtugeo_s32 /tmp/dtugeo
  echo "models at $(( $(date +%s) - t0 )) s: \
    $(ls -la /tmp/ex0/dtu.ply /tmp/ex1/dtu.ply 2>&1 | awk '{print $5, $9}' | tr '\n' ' ')"
  pack ;;
profile)
  for start in 1000 20000; do
    [ $start = 1000 ] && { ex=/tmp/ex1; V=${VARIANTS_1000:-"lean:. dst:.s38/dst"}; } \
                      || { ex=/tmp/ex0; V=${VARIANTS_20000:-"lean:. warp:.::optim.adam=warp"}; }
    EX=$ex STEP=profile STARTS=$start DTU=.s34data/dtu_scan24 VARIANTS="$V" REPS=${REPS:-1} \
      timeout ${PROFILE_S:-280} bash benchmarks/train/ab_trees.sh 2>&1 | tee -a $R/profile.txt | grep start
  done
  echo "profiles at $(( $(date +%s) - t0 )) s"; pack ;;
train)
  tree=${TREE:-.}
  [ "$tree" != . ] && ln -sfn ../kernels $tree/gof_warp/kernels && ln -sfn ../configs $tree/gof_warp/configs
  (cd $tree && PYTHONPATH="$PWD:/tmp/site" timeout -s INT -k 20 ${TRAIN_S:-560} python3 -m gof_warp.train \
    /tmp/gofdata/dtu_scan24 --out /tmp/hp/run_$NAME --quiet ${OVERRIDES:-} > $R/run_$NAME.log 2>&1)
  echo "train rc $? overrides: ${OVERRIDES:-}" >> $R/run_$NAME.log
  cp /tmp/hp/run_$NAME/metrics.json $R/run_${NAME}_metrics.json; grep -E "done|rc" $R/run_$NAME.log
  rm -rf /tmp/hp/run_$NAME; pack ;;
esac
