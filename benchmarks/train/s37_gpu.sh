#!/usr/bin/env bash
# Session 37 (two GPUs of one host; issue 14): the appearance network kept channel-last, and WarpAdam's 30k pairs.
# The probe ran with results/s37/appearance_channels_last.patch applied (the appearance_channels_last key and its tests
# exist only with it; measured no faster and not landed); pair 1 with that tree and the key set to false (the code
# before), pair 2 on main as it is (OLD_OVERRIDES="" NEW_OVERRIDES="optim.adam=warp" SWAP=1 PAIR=2).
#   STAGE=probe: on GPU 0 the CUDA tests of the loss (both layouts, and no layout conversions at DTU's size) and of
#                WarpAdam, then warp_adam_check.py at DTU's size; then the step at 20,000 on session 32's DTU model
#                (781k Gaussians) for three variants on both GPUs at once (GPU 1 in the reverse order):
#                nchw = appearance_channels_last=false (the code before), cl = the working tree's default,
#                clwarp = cl with optim.adam=warp.
#   STAGE=pair:  DTU scan 24, 30k iterations, two runs at the same time (the same host and contention for both):
#                "old" with $OLD_OVERRIDES and "new" with $NEW_OVERRIDES; old on GPU 0 unless SWAP=1. PAIR names the
#                files (pair$PAIR_old / pair$PAIR_new).
# Needs Warp staged, benchmarks/device_setup.sh sourced, /tmp/gofdata/dtu_scan24 and (probe) /tmp/gofdata/s32.
# Writes $OUT/s37_$STAGE.tgz.
set -u
R=$OUT/s37_$STAGE; mkdir -p $R /tmp/hp
mkdir -p .s34data && ln -sfn /tmp/gofdata/dtu_scan24 .s34data/dtu_scan24
t0=$(date +%s)
pack() { cp $R/../ab/*.json $R/ 2>/dev/null; (cd $OUT && tar czf s37_$STAGE.tgz s37_$STAGE 2>/dev/null); }
if [ "$STAGE" = probe ]; then
  export CUDA_VISIBLE_DEVICES=0
  timeout 200 python3 -m pytest -q -p no:cacheprovider tests/test_losses.py -k "cuda or channel_last" \
    > $R/cuda_tests_loss.txt 2>&1
  timeout 60 python3 -m pytest -q -p no:cacheprovider -k cuda tests/test_warp_adam.py > $R/cuda_tests_adam.txt 2>&1
  echo "tests at $(( $(date +%s) - t0 )) s: $(tail -n 1 $R/cuda_tests_loss.txt) / $(tail -n 1 $R/cuda_tests_adam.txt)"
  timeout 120 python3 benchmarks/train/warp_adam_check.py > $R/warp_adam_check.txt 2>&1
  echo "check at $(( $(date +%s) - t0 )) s: $(grep -i worst $R/warp_adam_check.txt | tail -n 3 | tr '\n' ' ')"
  mkdir -p /tmp/dtugeo && cp /tmp/gofdata/s32/*.npz /tmp/dtugeo/
  EX=/tmp/ex0 STEP=model DTU=.s34data/dtu_scan24 timeout 100 bash benchmarks/train/ab_trees.sh > $R/model.txt 2>&1
  unset CUDA_VISIBLE_DEVICES
  for g in 0 1; do
    if [ $g = 0 ]; then V="nchw:.::appearance_channels_last=false cl:. clwarp:.::optim.adam=warp"
    else V="clwarp_b:.::optim.adam=warp cl_b:. nchw_b:.::appearance_channels_last=false"; fi
    (CUDA_VISIBLE_DEVICES=$g EX=/tmp/ex0 STEP=profile STARTS=20000 DTU=.s34data/dtu_scan24 VARIANTS="$V" \
      timeout 300 bash benchmarks/train/ab_trees.sh > $R/profile_gpu$g.txt 2>&1) &
  done
  wait
  echo "profiles at $(( $(date +%s) - t0 )) s"; cat $R/profile_gpu0.txt $R/profile_gpu1.txt | grep start; pack
else
  for r in old new; do
    gpu=0; { [ $r = new ] && [ "${SWAP:-0}" = 0 ]; } || { [ $r = old ] && [ "${SWAP:-0}" = 1 ]; } && gpu=1
    [ $r = old ] && ov=${OLD_OVERRIDES:-} || ov=${NEW_OVERRIDES:-}
    (CUDA_VISIBLE_DEVICES=$gpu timeout -s INT -k 20 ${TRAIN_S:-500} python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 \
      --out /tmp/hp/run_$r --quiet $ov > $R/pair${PAIR}_$r.log 2>&1; echo "train rc $? gpu $gpu overrides: $ov" \
      >> $R/pair${PAIR}_$r.log; cp /tmp/hp/run_$r/metrics.json $R/pair${PAIR}_${r}_metrics.json) &
  done
  wait
  for r in old new; do grep -E "done|rc" $R/pair${PAIR}_$r.log; done; pack
  rm -rf /tmp/hp/run_old /tmp/hp/run_new
fi
rm -rf $OUT/s37_$STAGE $OUT/ab
