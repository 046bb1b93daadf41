#!/usr/bin/env bash
# Trainer profiles on the GPU machine: the trained DTU scan 24 model (packed halves in /tmp/dtugeo, see
# benchmarks/extract/pack_model.py), the DTU scene in /tmp/gofdata. Each TREE is a source snapshot folder
# (gof_warp/, kernels/, configs/) in the working tree, e.g. .before (the commit before a change) and .after.
# Usage: bash benchmarks/train/profile_gpu.sh TREE:START[:TRACE] ...   (writes $OUT/<tree>_<start>/)
set -u
source benchmarks/extract/dtu_model.sh  # $EX/dtu.ply
for spec in "$@"; do
  IFS=: read -r tree start trace <<< "$spec"
  ln -sfn ../kernels $tree/gof_warp/kernels
  ln -sfn ../configs $tree/gof_warp/configs
  PYTHONPATH=$PWD/$tree:/tmp/site python3 benchmarks/train/profile_train.py /tmp/gofdata/dtu_scan24 --config dtu \
    --ply $EX/dtu.ply --start $start --iterations 300 --trace ${trace:-30} --out $EX/${tree#.}_$start --label ${tree#.} \
    model.init=random densify.interval=100000 > $EX/${tree#.}_$start.log 2>&1
  echo "$spec rc $?"; grep -E "wall_ms|busy|launches" $EX/${tree#.}_$start.log; tail -14 $EX/${tree#.}_$start.log | grep " ms "
  cp $EX/${tree#.}_$start/profile.json $OUT/profile_${tree#.}_$start.json
  [ -f $EX/${tree#.}_$start/trace.json.gz ] && [ "$start" = 20000 ] && cp $EX/${tree#.}_$start/trace.json.gz $OUT/trace_${tree#.}_$start.json.gz
done
