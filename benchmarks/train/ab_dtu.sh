#!/usr/bin/env bash
# Short DTU scan 24 trainings side by side on one GPU, to find which change moves the PSNR. Each argument
# TREE[:override,override...] trains from the source snapshot TREE (a folder with gof_warp/, kernels/,
# configs/) for $ITER iterations (default 3000); all run at once; prints each run's train-view PSNR.
# Usage: ITER=3000 bash benchmarks/train/ab_dtu.sh .before .after .after:optim.fused=false ...
set -u
ITER=${ITER:-3000}
mkdir -p /tmp/ab
run() {  # index tree overrides iterations
  ln -sfn ../kernels $2/gof_warp/kernels; ln -sfn ../configs $2/gof_warp/configs
  (cd $2 && python3 -m gof_warp.train /tmp/gofdata/dtu_scan24 --out /tmp/ab/$1 --iterations $4 --no-pictures --quiet \
     checkpoint_every=0 ${3//,/ } > /tmp/ab/$1.log 2>&1)
}
first="${1%%:*}"
run warmup "$first" "" 10  # the triangulated points are cached beside the scene by this first run
i=0
for spec in "$@"; do
  i=$((i+1))
  IFS=: read -r tree ov <<< "$spec"
  run $i "$tree" "${ov:-}" $ITER &
done
wait
i=0
for spec in "$@"; do
  i=$((i+1)); echo "$spec: $(grep -h 'done:' /tmp/ab/$i.log || tail -2 /tmp/ab/$i.log)"
  cp /tmp/ab/$i/metrics.json $OUT/ab_$i.json 2>/dev/null
done
