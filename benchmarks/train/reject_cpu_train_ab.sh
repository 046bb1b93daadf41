#!/bin/bash
# Session 33: the README job's training (python -m gof_warp.train, built-in default scene, quick preset) on the 2-core
# CPU, before the early reject (a git archive of d876290 in /tmp/s33pre, gof_warp/kernels and gof_warp/configs linked to
# its own kernels/ and configs/) and after it (the working tree); run as k=1 (before, after) and k=2 (after, before);
# the two point_cloud.ply files' sha256 at the end.
cd /work/main; . .venv/bin/activate; export WARP_CACHE_PATH=/tmp/wc
for k in 2; do
  for t in after before; do
    if [ $t = before ]; then dir=/tmp/s33pre; else dir=/work/main; fi
    rm -rf /tmp/s33tr_$t
    a=$(date +%s.%N)
    (cd $dir && PYTHONPATH=$dir python -m gof_warp.train --out /tmp/s33tr_$t --quiet --no-pictures)
    echo "$t $k wall $(python -c "print(round($(date +%s.%N) - $a, 2))")"
    python -c "
import json; j=json.load(open('/tmp/s33tr_$t/metrics.json'))
print('  train_time_s', j['train_time_s'], 'gaussians', j['num_gaussians'], 'test', j['test'])"
  done
done
sha256sum /tmp/s33tr_before/point_cloud.ply /tmp/s33tr_after/point_cloud.ply
