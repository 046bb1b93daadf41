#!/usr/bin/env bash
# Session 36, third lease (two GPUs of one host). Trees carried to /tmp/trees and linked as .s36/<label>:
#   start  = 30d22d8, the code at the session's start;  pwonly = 0b29244, the pointwise activations landed;
#   "."    = the working tree (LeanAdam, the one-process step without its all-reduce stage).
#   STAGE=host: on GPU 0 alone, the CUDA tests of the new code, Adam against its roofline (torch's fused, LeanAdam,
#               WarpAdam), the early step's host profile (a DTU model of 1,000 iterations, step profiled at 1,000),
#               pwonly against the working tree, twice alternating, and the step at 20,000 on session 32's model with
#               the working tree's LeanAdam against optim.adam=warp;
#   STAGE=runs: DTU scan 24, dtu preset, 30k iterations, start on GPU 0 and the working tree (with $NEW_OVERRIDES)
#               on GPU 1 at the same time (the same host, the same contention for both).
#   STAGE=adampair (for the next lease; needs no trees): warp_adam_check.py at DTU's size on GPU 0, then the working
#               tree's DTU 30k with optim.adam=torch on GPU 0 and optim.adam=warp on GPU 1 at the same time; run it
#               twice for the two pairs that decide whether optim.adam=warp can be the default.
# Needs Warp staged, benchmarks/device_setup.sh sourced, /tmp/gofdata/dtu_scan24 (and /tmp/gofdata/s32 for the
# profile at 20,000). Writes $OUT/s36c_$STAGE.tgz.
set -u
R=$OUT/s36c_$STAGE; mkdir -p $R /tmp/hp .s36
mkdir -p .s34data && ln -sfn /tmp/gofdata/dtu_scan24 .s34data/dtu_scan24
for t in start pwonly; do [ -d /tmp/trees/$t ] || continue; ln -sfn /tmp/trees/$t .s36/$t; ln -sfn ../kernels .s36/$t/gof_warp/kernels; \
  ln -sfn ../configs .s36/$t/gof_warp/configs; done
t0=$(date +%s)
pack() { cp $R/../ab/*.json $R/ 2>/dev/null; for r in start new torch warp; do
           cp /tmp/hp/run_$r/metrics.json $R/dtu_30k_${r}_metrics.json 2>/dev/null; done
         (cd $OUT && tar czf s36c_$STAGE.tgz s36c_$STAGE 2>/dev/null); }
if [ "$STAGE" = host ]; then
  export CUDA_VISIBLE_DEVICES=0
  timeout 100 python3 -m pytest -q -p no:cacheprovider -k cuda tests/test_lean_adam.py tests/test_warp_adam.py \
    tests/test_model_ply.py > $R/cuda_tests.txt 2>&1
  echo "tests at $(( $(date +%s) - t0 )) s: $(tail -n 1 $R/cuda_tests.txt)"
  timeout 120 python3 benchmarks/train/adam_roofline.py --gaussians 848237 --out $R/adam_roofline.json > $R/adam.txt 2>&1
  echo "adam at $(( $(date +%s) - t0 )) s:"; grep -E '_ms|GBps' $R/adam.txt | tr '\n' ' '; echo
  mkdir -p /tmp/ex1
  timeout 100 python3 -m gof_warp.train .s34data/dtu_scan24 --config dtu --iterations 1000 --out /tmp/ex1/run \
    --no-pictures --quiet > $R/model1k.txt 2>&1
  cp /tmp/ex1/run/point_cloud.ply /tmp/ex1/dtu.ply
  echo "1k model at $(( $(date +%s) - t0 )) s: $(tail -n 1 $R/model1k.txt)"
  EX=/tmp/ex1 STEP=profile STARTS="1000" REPS=2 DTU=.s34data/dtu_scan24 VARIANTS="pwonly:.s36/pwonly new:." \
    timeout 200 bash benchmarks/train/ab_trees.sh > $R/profile_host.txt 2>&1
  cp /tmp/ex1/prof_new_1000_1/trace.json.gz $R/trace_new_1000.json.gz 2>/dev/null
  echo "profiles at $(( $(date +%s) - t0 )) s"; grep start $R/profile_host.txt; pack
  mkdir -p /tmp/dtugeo && cp /tmp/gofdata/s32/*.npz /tmp/dtugeo/
  EX=/tmp/ex0 STEP="model profile" STARTS="20000" DTU=.s34data/dtu_scan24 VARIANTS="lean:. warp:.::optim.adam=warp" \
    timeout 150 bash benchmarks/train/ab_trees.sh > $R/profile_adam.txt 2>&1
  echo "adam profiles at $(( $(date +%s) - t0 )) s"; grep start $R/profile_adam.txt; pack
elif [ "$STAGE" = adampair ]; then
  CUDA_VISIBLE_DEVICES=0 timeout 120 python3 benchmarks/train/warp_adam_check.py > $R/warp_adam_check.txt 2>&1
  echo "check at $(( $(date +%s) - t0 )) s: $(grep worst $R/warp_adam_check.txt)"
  for a in torch warp; do
    gpu=0; [ $a = warp ] && gpu=1
    (CUDA_VISIBLE_DEVICES=$gpu timeout -s INT -k 20 ${TRAIN_S:-480} python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 \
      --out /tmp/hp/run_$a --quiet optim.adam=$a > $R/dtu_train_$a.log 2>&1; echo "train rc $?" >> $R/dtu_train_$a.log) &
  done
  wait
  for a in torch warp; do grep -E "done|rc" $R/dtu_train_$a.log; done; pack
else
  (cd .s36/start && CUDA_VISIBLE_DEVICES=0 PYTHONPATH="$PWD:/tmp/site" timeout -s INT -k 20 ${TRAIN_S:-500} \
    python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 --out /tmp/hp/run_start --quiet > $R/dtu_train_start.log 2>&1; \
    echo "train rc $?" >> $R/dtu_train_start.log) &
  CUDA_VISIBLE_DEVICES=1 timeout -s INT -k 20 ${TRAIN_S:-500} python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 \
    --out /tmp/hp/run_new --quiet ${NEW_OVERRIDES:-} > $R/dtu_train_new.log 2>&1; echo "train rc $?" >> $R/dtu_train_new.log
  wait
  for r in start new; do grep -E "done|rc" $R/dtu_train_$r.log; done; pack
fi
rm -rf $OUT/s36c_$STAGE $OUT/ab
