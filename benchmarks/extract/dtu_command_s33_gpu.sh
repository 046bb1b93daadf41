#!/usr/bin/env bash
# Session 33: the default `python -m gof_warp.extract RUN` on session 32's DTU scan 24 model (781,428 Gaussians),
# whole commands timed, the code before this session's change ("before": session 32's panels/pictures/extract/
# extraction/ply, carried in .s33/old/gof_warp) and after it, alternated three times on the same warm GPU; then the
# same after `compileall` of torch and Warp (the GPU machine's torch and the carried Warp have no .pyc files, so every
# command there first compiles ~1,600 modules to bytecode, ~3 s that a pip-installed package does not spend). Each
# command runs from its own tree (`python -m` puts the working folder first on sys.path). Needs parked: /tmp/gofdata/s32
# (the packed model parts, cameras.json, config.yaml; see dtu_command_gpu.sh) and /tmp/gofdata/dtu_scan24.
# Writes $OUT/s33c/ (times.txt, summary.txt: per command the JSON's total, load/save/picture and stage times).
set -u
D=/tmp/dturun; R=$OUT/s33c; mkdir -p $R
if [ ! -f $D/point_cloud.ply ]; then
  mkdir -p $D && cp /tmp/gofdata/s32/cameras.json /tmp/gofdata/s32/config.yaml $D/ &&
    python3 benchmarks/extract/pack_model.py unpack /tmp/gofdata/s32/dtu_s32_geometry.part0.npz $D/point_cloud.ply ||
    { echo "cannot rebuild the run folder"; exit 1; }
fi
OLD=/tmp/oldtree
if [ ! -d $OLD ]; then
  mkdir -p $OLD && cp -rL gof_warp $OLD/ && cp -r kernels configs $OLD/ && cp .s33/old/gof_warp/*.py $OLD/gof_warp/
fi
t() {  # name, tree: one whole extract command run from that tree
  local name=$1 dir=$2; local a=$(date +%s.%N)
  (cd $dir && PYTHONPATH=$dir:/tmp/site python3 -m gof_warp.extract $D > /tmp/$name.log 2>&1)
  echo "$name rc $? wall $(python3 -c "print(round($(date +%s.%N) - $a, 2))") s" | tee -a $R/times.txt
  cp $D/mesh_tetra.json /tmp/js_$name.json
}
t warm_up $PWD  # loads (or compiles) every kernel once: not counted
for k in 1 2 3; do t before_$k $OLD; t after_$k $PWD; done
a=$(date +%s.%N)
python3 -m compileall -q -j 16 /opt/torch/.venv/lib/python3.12/site-packages/torch /tmp/site/warp > /dev/null 2>&1
echo "compileall $(python3 -c "print(round($(date +%s.%N) - $a, 2))") s" | tee -a $R/times.txt
for k in 1 2; do t before_pyc_$k $OLD; t after_pyc_$k $PWD; done
python3 - <<'PY' > $R/summary.txt
import glob
import json
for p in sorted(glob.glob('/tmp/js_*.json')):
    j = json.load(open(p)); s = j['stages']
    print(p.split('js_')[1][:-5], j['total_time_s'], j['command'],
          {k: v['time_s'] for k, v in s.items() if isinstance(v, dict) and 'time_s' in v}, j['meshes'][0]['faces'])
PY
cp /tmp/js_after_1.json /tmp/js_before_1.json $R/
