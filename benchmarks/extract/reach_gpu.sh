#!/usr/bin/env bash
# Session 32, on a 2-GPU host: the octree grid's reach filter (OctreeConfig.reach_filter, --reach-filter) on and off.
# GPU 1 trains DTU scan 24 (dtu preset, 30k, resumable; TRAIN_S caps it) and then meshes it with `extract
# --reach-filter` (with the mesh picture) and with the default (the filter off since this session; no picture), each
# timed as a whole command. GPU 0 meanwhile meshes the packed models
# parked in /tmp/gofdata/models (bgf_tail_s1: background_full, whose exact surface is generated here; fox_tail_s1 and
# can_tail_s1 with their scenes in /tmp/gofdata) on and off, and bgf also on the Delaunay grid (one Qhull call), each
# bgf mesh scored against the exact surface on the whole seen region and on the ground-and-objects crop.
# Writes $OUT/reach.tgz (stage JSONs, scores, logs, half-size mesh pictures) and the DTU model's packed geometry.
set -u
S=/tmp/rg; mkdir -p $S; R=$S/out; mkdir -p $R
TRAIN_S=${TRAIN_S:-440}
t0=$(date +%s)
stamp() { echo "$1 at $(( $(date +%s) - t0 )) s" | tee -a $R/timeline.txt; }
timed() {  # name, command...: the whole command's wall time into $R/<name>.time (its JSON has the memory peaks)
  local name=$1; shift
  local a=$(date +%s.%N)
  "$@" > $R/$name.log 2>&1
  local rc=$?
  echo "rc $rc wall $(python3 -c "print(round($(date +%s.%N) - $a, 2))") s" > $R/$name.time
}
[ -d $S/dtu ] || cp -r /tmp/gofdata/dtu_scan24 $S/dtu
if [ ! -f $S/run_dtu/metrics.json ]; then
  (CUDA_VISIBLE_DEVICES=1 timeout -s INT -k 30 $TRAIN_S python3 -m gof_warp.train $S/dtu --out $S/run_dtu \
    checkpoint_every=1000 --resume --quiet >> $S/dtu.train.log 2>&1; echo "dtu training ended") &
fi
(
  export CUDA_VISIBLE_DEVICES=0
  for m in bgf_tail_s1 fox_tail_s1 can_tail_s1; do
    [ -f $S/$m.ply ] || python3 benchmarks/extract/pack_model.py unpack /tmp/gofdata/models/${m}_geometry.npz $S/$m.ply
  done
  [ -f $S/bgf/gt_mesh.ply ] || python3 -m gof_warp.synthetic --preset background_full --resolution 400 400 --views 100 \
    --out $S/bgf --device cuda:0 --force --quiet
  stamp "models and bgf scene ready"
  for scene in fox:fox can:colmap_can; do
    name=${scene%%:*}; src=/tmp/gofdata/${scene#*:}
    for v in reach noreach; do
      [ -f $R/${name}_$v.json ] && continue  # done by an earlier call
      flag=$([ $v = reach ] && echo --reach-filter)
      # shellcheck disable=SC2086
      timed ${name}_$v python3 -m gof_warp.extract $S/${name}_tail_s1.ply --scene $src --out $S/${name}_$v.ply $flag
      cp $S/${name}_$v.json $R/ 2>/dev/null
    done
    stamp "$name meshed"
  done
  for v in reach noreach delaunay; do
    [ -f $R/bgf_${v}_crop.json ] && continue
    flag=$([ $v = reach ] && echo --reach-filter; [ $v = delaunay ] && echo --grid delaunay --delaunay-workers 1)
    # shellcheck disable=SC2086
    [ -f $R/bgf_$v.json ] || timed bgf_$v python3 -m gof_warp.extract $S/bgf_tail_s1.ply --scene $S/bgf --out $S/bgf_$v.ply --no-pictures $flag
    cp $S/bgf_$v.json $R/ 2>/dev/null
    stamp "bgf $v meshed"
    ev=(python3 -m gof_warp.evaluate --gt $S/bgf/gt_mesh.ply --scene $S/bgf --mesh $S/bgf_$v.ply)
    ("${ev[@]}" --json $R/bgf_${v}_seen.json > /dev/null 2>&1; "${ev[@]}" --crop -2 -2 -1.1 2 2 1 \
      --json $R/bgf_${v}_crop.json > /dev/null 2>&1) &
  done
  wait
  stamp "bgf scored"
) &
wait
stamp "training and GPU 0 done"
for f in $S/dtu.train.log; do cp $f $R/; done
if [ -f $S/run_dtu/metrics.json ]; then
  export CUDA_VISIBLE_DEVICES=1
  cp $S/run_dtu/metrics.json $R/dtu_metrics.json
  timed dtu_reach python3 -m gof_warp.extract $S/run_dtu --reach-filter
  cp $S/run_dtu/mesh_tetra.json $R/dtu_reach.json
  timed dtu_noreach python3 -m gof_warp.extract $S/run_dtu --out $S/run_dtu/mesh_noreach.ply \
    --no-pictures
  cp $S/run_dtu/mesh_noreach.json $R/dtu_noreach.json
  python3 benchmarks/extract/compare_in_box.py $S/run_dtu/mesh_tetra.ply $S/run_dtu/mesh_noreach.ply \
    --box -1 -1 -1 1 1 1 --out $R/dtu_compare_reach_vs_noreach.json > /dev/null 2>&1
  cp -r $S/run_dtu/pictures $R/dtu_pictures 2>/dev/null
  python3 benchmarks/extract/pack_model.py pack $S/run_dtu "$OUT/dtu_s32_geometry.npz" > /dev/null 2>&1
  stamp "dtu meshed"
fi
python3 - "$R" <<'PY'
import sys, pathlib
from PIL import Image  # pictures back as half-size JPEGs (the device returns files of at most 16 MiB)
root = pathlib.Path(sys.argv[1])
for png in list(root.rglob("*.png")) + list(pathlib.Path("/tmp/rg").glob("pictures/*.png")):
    im = Image.open(png).convert("RGB")
    im.resize((im.width // 2, im.height // 2)).save(root / (png.parent.name + "_" + png.stem + ".jpg"), quality=85)
    if png.is_relative_to(root):
        png.unlink()
PY
(cd $S && tar czf "$OUT/reach.tgz" out)
ls -la "$OUT"
