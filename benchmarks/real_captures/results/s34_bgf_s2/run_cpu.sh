cd /work/main; . .venv/bin/activate; export WARP_CACHE_PATH=/tmp/wc
t0=$(date +%s)
python -m gof_warp.extract /tmp/s34/s2/point_cloud.ply --scene /tmp/s32/bgf --min-views 2 --binary-steps 8 --no-pictures --quiet --out /tmp/s34/s2/mv2.ply > /tmp/s34/s2/extract.log 2>&1
echo "extract rc $? $(( $(date +%s) - t0 )) s" >> /tmp/s34/s2/status
python -m gof_warp.evaluate --mesh /tmp/s34/s2/mv2.ply --gt /tmp/s32/bgf/gt_mesh.ply --scene /tmp/s32/bgf --json /tmp/s34/s2/eval_seen.json > /tmp/s34/s2/eval_seen.log 2>&1
echo "eval seen rc $? $(( $(date +%s) - t0 )) s" >> /tmp/s34/s2/status
python -m gof_warp.evaluate --mesh /tmp/s34/s2/mv2.ply --gt /tmp/s32/bgf/gt_mesh.ply --scene /tmp/s32/bgf --crop -2 -2 -1.1 2 2 1 --json /tmp/s34/s2/eval_crop.json > /tmp/s34/s2/eval_crop.log 2>&1
echo "eval crop rc $? $(( $(date +%s) - t0 )) s" >> /tmp/s34/s2/status
