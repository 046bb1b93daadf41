#!/usr/bin/env bash
# Session 36, second lease (one GPU): where the step's time goes outside the GPU's busy time.
#   1. densify_cost.py: one densification event's cost (100-iteration windows with and without one, alternating) on
#      session 32's DTU model at iteration 12,000, and a trace of a window with one;
#   2. the host's share of an early step: a DTU model of 1,000 iterations (38k Gaussians, as a run has then), the step
#      profiled at 1,000 and at 20,000 on it (the GPU waits for the host there: the host's stage times are its own).
# Needs Warp staged, benchmarks/device_setup.sh sourced, /tmp/gofdata/s32 and /tmp/gofdata/dtu_scan24. Writes
# $OUT/s36b.tgz (packed after each stage).
set -u
R=$OUT/s36b; mkdir -p $R /tmp/dtugeo
cp /tmp/gofdata/s32/*.npz /tmp/dtugeo/ 2>/dev/null
mkdir -p .s34data && ln -sfn /tmp/gofdata/dtu_scan24 .s34data/dtu_scan24
t0=$(date +%s)
pack() { cp $R/../ab/*.json $R/ 2>/dev/null; (cd $OUT && tar czf s36b.tgz s36b 2>/dev/null); }
EX=/tmp/ex0 STEP=model bash benchmarks/train/ab_trees.sh > $R/model.txt 2>&1
timeout 150 python3 benchmarks/train/densify_cost.py .s34data/dtu_scan24 --config dtu --ply /tmp/ex0/dtu.ply \
  --start 12000 --reps 3 --out /tmp/dc > $R/densify_cost.txt 2>&1
cp /tmp/dc/densify_cost.json $R/ 2>/dev/null
echo "densify cost at $(( $(date +%s) - t0 )) s:"; tail -n 9 $R/densify_cost.txt; pack
mkdir -p /tmp/ex1
timeout 120 python3 -m gof_warp.train .s34data/dtu_scan24 --config dtu --iterations 1000 --out /tmp/ex1/run \
  --no-pictures --quiet > $R/model1k.txt 2>&1
cp /tmp/ex1/run/point_cloud.ply /tmp/ex1/dtu.ply
echo "1k model at $(( $(date +%s) - t0 )) s: $(tail -n 1 $R/model1k.txt)"
EX=/tmp/ex1 STEP=profile STARTS="1000 20000" DTU=.s34data/dtu_scan24 VARIANTS="small:." timeout 150 \
  bash benchmarks/train/ab_trees.sh > $R/profile_small.txt 2>&1
cp /tmp/ex1/prof_small_1000_1/trace.json.gz $R/trace_small_1000.json.gz 2>/dev/null
echo "profiles at $(( $(date +%s) - t0 )) s"; grep start $R/profile_small.txt; pack
rm -rf $OUT/s36b $OUT/ab
