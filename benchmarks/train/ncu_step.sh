#!/usr/bin/env bash
# Nsight Compute on one kernel of a training step of the DTU model ($EX/dtu.ply, see ab_trees.sh STEP=model), for the
# working tree and/or the snapshot OLD. Needs Warp staged and benchmarks/device_setup.sh sourced.
#   TREES="old new" START=20000 KERNEL=rasterize_backward_tiled bash benchmarks/train/ncu_step.sh  → $OUT/ncu_<tree>_<start>.txt
set -u
OLD=${OLD:-.before}; EX=${EX:-/tmp/ex}; DTU=${DTU:-$PWD/.s18/dtu_scan24}; START=${START:-20000}
KERNEL=${KERNEL:-rasterize_backward_tiled}; SKIP=${SKIP:-22}
SECTIONS=${SECTIONS:-"SpeedOfLight WarpStateStats SchedulerStats LaunchStats Occupancy MemoryWorkloadAnalysis ComputeWorkloadAnalysis InstructionStats SourceCounters"}
NCU=$(command -v ncu || echo /usr/local/cuda/bin/ncu)
ln -sfn ../kernels $OLD/gof_warp/kernels; ln -sfn ../configs $OLD/gof_warp/configs
args=(); for s in $SECTIONS; do args+=(--section "$s"); done
for tree in ${TREES:-old new}; do
  dir=$PWD; [ "$tree" = old ] && dir=$PWD/$OLD
  (cd "$dir" && PYTHONPATH="$dir:/tmp/site" timeout 300 $NCU --kernel-name regex:$KERNEL --launch-skip $SKIP --launch-count 1 \
     "${args[@]}" python3 benchmarks/train/profile_train.py "$DTU" --config dtu --ply $EX/dtu.ply --start $START \
     --iterations 5 --trace 0 --out $EX/ncu_$tree model.init=random densify.interval=100000) \
    > "$OUT/ncu_${tree}_$START.txt" 2>&1
  echo "$tree rc $?"; grep -E "Duration|Registers Per|Achieved Occupancy|Compute \(SM\) Throughput|Memory Throughput" "$OUT/ncu_${tree}_$START.txt" | head -8
done
