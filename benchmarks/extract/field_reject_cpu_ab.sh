#!/bin/bash
# Session 33: CPU A/B of the README job's extraction (extract RUN --binary-steps 4, no pictures): "before" = a git archive
# of e178f80 in /tmp/s33b4 (with gof_warp/kernels and gof_warp/configs linked to its own kernels/ and configs/: an editable
# install would otherwise serve the working tree's kernels to it), "after" = the working tree (the opacity field's early
# reject); alternated twice; the meshes' sha256 at the end.
RUN=/tmp/s32/readme/runs/default
cd /work/main; . .venv/bin/activate; export WARP_CACHE_PATH=/tmp/wc
for k in 1 2; do
  for t in before after; do
    if [ $t = before ]; then dir=/tmp/s33b4; else dir=/work/main; fi
    a=$(date +%s.%N)
    (cd $dir && PYTHONPATH=$dir python -m gof_warp.extract $RUN --binary-steps 4 --out /tmp/s33ab_$t.ply --no-pictures --quiet)
    echo "$t $k wall $(python -c "print(round($(date +%s.%N) - $a, 2))")"
    python -c "
import json; j=json.load(open('/tmp/s33ab_$t.json')); s=j['stages']
print('  total', j['total_time_s'], {k: v['time_s'] for k, v in s.items() if isinstance(v, dict) and 'time_s' in v}, j['meshes'][0]['faces'])"
  done
done
sha256sum /tmp/s33ab_before.ply /tmp/s33ab_after.ply
