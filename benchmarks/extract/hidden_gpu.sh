#!/usr/bin/env bash
# Session 32, one GPU: the extraction's hidden-face drop (MeshConfig.drop_hidden, the default; --keep-hidden turns
# it off) on the parked models: bgf_tail_s1 (background_full; exact surface generated here, scored on the whole seen
# region and the ground-and-objects crop), fox_tail_s1 and can_tail_s1 (with their scenes, mesh pictures), and the
# DTU run folder that dtu_command_gpu.sh rebuilds (the whole default command timed twice). Each step has its own time
# limit so that the script ends and packs what it has. Writes $OUT/hidden.tgz.
set -u
S=/tmp/hg; R=$S/out; mkdir -p $R
t0=$(date +%s)
stamp() { echo "$1 at $(( $(date +%s) - t0 )) s" | tee -a $R/timeline.txt; }
timed() {  # name, limit, command...: one whole command, its wall time into $R/times.txt
  local name=$1 limit=$2; shift 2
  local a=$(date +%s.%N)
  timeout $limit "$@" > $R/$name.log 2>&1
  echo "$name rc $? wall $(python3 -c "print(round($(date +%s.%N) - $a, 2))") s" | tee -a $R/times.txt
}
for m in bgf_tail_s1 fox_tail_s1 can_tail_s1; do
  [ -f $S/$m.ply ] || python3 benchmarks/extract/pack_model.py unpack /tmp/gofdata/models/${m}_geometry.npz $S/$m.ply
done
[ -f $S/bgf/gt_mesh.ply ] || python3 -m gof_warp.synthetic --preset background_full --resolution 400 400 --views 100 \
  --out $S/bgf --device cuda:0 --force --quiet
stamp "ready"
for v in drop keep; do
  flag=$([ $v = keep ] && echo --keep-hidden)
  # shellcheck disable=SC2086
  timed bgf_$v 120 python3 -m gof_warp.extract $S/bgf_tail_s1.ply --scene $S/bgf --out $S/bgf_$v.ply --no-pictures $flag
  cp $S/bgf_$v.json $R/ 2>/dev/null
  ev=(timeout 200 python3 -m gof_warp.evaluate --gt $S/bgf/gt_mesh.ply --scene $S/bgf --mesh $S/bgf_$v.ply)
  ("${ev[@]}" --json $R/bgf_${v}_seen.json > /dev/null 2>&1 &)
  ("${ev[@]}" --crop -2 -2 -1.1 2 2 1 --json $R/bgf_${v}_crop.json > /dev/null 2>&1 &)
done
stamp "bgf meshed"
for scene in fox:fox; do
  name=${scene%%:*}; src=/tmp/gofdata/${scene#*:}
  timed ${name}_drop 120 python3 -m gof_warp.extract $S/${name}_tail_s1.ply --scene $src --out $S/${name}_drop.ply
  timed ${name}_keep 120 python3 -m gof_warp.extract $S/${name}_tail_s1.ply --scene $src --out $S/${name}_keep.ply \
    --keep-hidden --no-pictures
  cp $S/${name}_drop.json $S/${name}_keep.json $R/ 2>/dev/null
done
stamp "real captures meshed"
D=/tmp/dturun
if [ ! -f $D/point_cloud.ply ]; then
  mkdir -p $D && cp /tmp/gofdata/s32/cameras.json /tmp/gofdata/s32/config.yaml $D/ &&
    python3 benchmarks/extract/pack_model.py unpack /tmp/gofdata/s32/dtu_s32_geometry.part0.npz $D/point_cloud.ply
fi
for k in 1; do
  timed dtu_drop_$k 150 python3 -m gof_warp.extract $D
  cp $D/mesh_tetra.json $R/dtu_drop_$k.json 2>/dev/null
done
timed dtu_keep 150 python3 -m gof_warp.extract $D --keep-hidden --no-pictures --out $D/mesh_keep.ply
cp $D/mesh_keep.json $R/dtu_keep.json 2>/dev/null
stamp "dtu meshed"
while pgrep -f "gof_warp.evaluate" > /dev/null; do sleep 2; done
stamp "scored"
python3 - "$R" <<'PY'
import sys, pathlib
from PIL import Image  # pictures back as half-size JPEGs
root = pathlib.Path(sys.argv[1])
pngs = list(pathlib.Path("/tmp/hg").glob("pictures/*.png")) + list(pathlib.Path("/tmp/dturun").glob("pictures/*.png"))
for png in pngs:
    im = Image.open(png).convert("RGB")
    im.resize((im.width // 2, im.height // 2)).save(root / f"{png.parent.parent.name}_{png.stem}.jpg", quality=85)
PY
(cd $S && tar czf "$OUT/hidden.tgz" out)
ls -la "$OUT"
