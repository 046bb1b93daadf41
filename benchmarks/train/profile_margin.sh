#!/usr/bin/env bash
# Trainer profiles with and without the tile-list sizer (tile_list_margin=0: a host-device sync per render, as
# before; 1.25: the default), on the GPU machine, the trained DTU scan 24 model (packed in /tmp/dtugeo, see
# benchmarks/extract/dtu_model.sh) at iterations 20000 (regularised) and 5000 (densifying, densification paused).
# Usage: bash benchmarks/train/profile_margin.sh   (writes $OUT/profile_margin<m>_<start>.json)
set -u
source benchmarks/extract/dtu_model.sh  # $EX/dtu.ply
for start in 20000 5000; do
  for m in 0 1.25; do
    python3 benchmarks/train/profile_train.py /tmp/gofdata/dtu_scan24 --config dtu --ply $EX/dtu.ply --start $start \
      --iterations 300 --trace 30 --out $EX/m${m}_$start --label "tile_list_margin=$m" \
      model.init=random densify.interval=100000 tile_list_margin=$m > $EX/m${m}_$start.log 2>&1
    echo "margin $m start $start rc $?"; grep -E "wall_ms|busy|launches|sync" $EX/m${m}_$start.log | head -6
    cp $EX/m${m}_$start/profile.json $OUT/profile_margin${m}_$start.json
  done
done
