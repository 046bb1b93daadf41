#!/usr/bin/env bash
# Session 28: the hidden prune (densify.hidden_prune_iters) on the far shell of background_full and on a compact scene,
# each run alone on its own GPU of a several-GPU host (RUNS: "name|scene|overrides" a line; scenes bgf and def are
# generated on GPU 0: background_full 400x400 with the session-19 points from .s17pts, default 400x400; 100 views each;
# session 29: scenes fox and can are the real captures carried in .data/ or parked in /tmp/gofdata, copied).
#   PHASE=train TRAIN_S=500 bash benchmarks/real_captures/hidden_prune_gpu.sh    # generate, train (resumable)
#   PHASE=score bash benchmarks/real_captures/hidden_prune_gpu.sh                # finish, mesh, score, pack
# bgf: extract --min-views K for each K of VIEWS (default "2"; session 29: "2 3", then "3"), each scored on the whole
# seen region and the ground-and-objects crop; def: extract with the defaults, scored on the seen region; fox, can:
# extract with the defaults and draw the mesh pictures (returned as half-size JPEGs).
# Writes $OUT/hp_<name>/ (metrics, mesh json, scores) and packed geometry.
set -u
S=/tmp/hp; mkdir -p $S
PHASE=${PHASE:-train}; TRAIN_S=${TRAIN_S:-500}; VIEWS=${VIEWS:-2}
HID='densify.hidden_prune_iters=[15000,20000,25000,29000]'
RUNS=${RUNS:-"bgf_hidden|bgf|$HID
bgf_hidden005|bgf|$HID densify.hidden_margin=0.005
def_base|def|
def_hidden|def|$HID"}
t0=$(date +%s)
if [ ! -f $S/bgf/transforms_train.json ]; then
  python3 -m gof_warp.synthetic --preset background_full --resolution 400 400 --views 100 --out $S/bgf --device cuda:0 \
    --force --quiet && cp .s17pts/background_full/points3d.ply $S/bgf/ || { echo "bgf generation failed"; exit 1; }
fi
if [ ! -f $S/def/transforms_train.json ]; then
  python3 -m gof_warp.synthetic --preset default --resolution 400 400 --views 100 --out $S/def --device cuda:0 \
    --force --quiet || { echo "def generation failed"; exit 1; }
fi
for real in fox:fox can:colmap_can; do
  if grep -q "|${real%%:*}|" <<< "$RUNS" && [ ! -d $S/${real%%:*} ]; then
    src=$(ls -d .data/${real#*:} /tmp/gofdata/${real#*:} 2>/dev/null | head -1)
    [ -n "$src" ] && cp -r "$src" $S/${real%%:*} || { echo "${real#*:} in neither .data nor /tmp/gofdata"; exit 1; }
  fi
done
echo "scenes at $(( $(date +%s) - t0 )) s"
k=0
while IFS='|' read -r name scene over; do
  [ -n "$name" ] || continue
  run=$S/run_$name
  if [ ! -f $run/metrics.json ]; then
    # shellcheck disable=SC2086
    CUDA_VISIBLE_DEVICES=$k timeout -s INT -k 30 $((TRAIN_S - $(date +%s) + t0)) python3 -m gof_warp.train $S/$scene \
      --out $run checkpoint_every=1000 $over --resume --quiet >> $S/$name.train.log 2>&1 &
  fi
  k=$((k + 1))
done <<< "$RUNS"
wait
echo "training phase ended at $(( $(date +%s) - t0 )) s"
for f in $S/*.train.log; do echo "$f: $(grep -h 'done:' "$f" | tail -1)"; done
for r in $S/run_*; do echo "$r: $(ls $r/checkpoints 2>/dev/null | tail -1)"; done
[ "$PHASE" = score ] || exit 0
k=0
while IFS='|' read -r name scene over; do
  [ -n "$name" ] || continue
  run=$S/run_$name; R="$OUT/hp_$name"; mkdir -p "$R"
  (
    export CUDA_VISIBLE_DEVICES=$k
    [ -f $run/metrics.json ] || { echo "$name: not trained"; exit 0; }
    cp $run/metrics.json $run/config.yaml "$R/"
    ev=(python3 -m gof_warp.evaluate --gt $S/$scene/gt_mesh.ply --scene $S/$scene)
    if [ "$scene" = bgf ]; then
      for v in $VIEWS; do
        python3 -m gof_warp.extract $run --min-views $v --out $run/mesh_views$v.ply >> $R/extract.log 2>&1
        "${ev[@]}" --mesh $run/mesh_views$v.ply --json "$R/evaluate_seen_views$v.json" > /dev/null 2>&1
        "${ev[@]}" --mesh $run/mesh_views$v.ply --crop -2 -2 -1.1 2 2 1 --json "$R/evaluate_crop_views$v.json" \
          > /dev/null 2>&1
        cp $run/mesh_views$v.json "$R/" 2>/dev/null
      done
    elif [ "$scene" = fox ] || [ "$scene" = can ]; then
      python3 -m gof_warp.extract $run > $R/extract.log 2>&1
      python3 -m gof_warp.pictures $run --mesh $run/mesh_tetra.ply --quiet >> $R/extract.log 2>&1
      python3 -m gof_warp.pictures $run --quiet >> $R/extract.log 2>&1
      cp $run/mesh_tetra.json "$R/" 2>/dev/null
      python3 - "$run/pictures" "$R" <<'PY' || cp $run/pictures/*.png "$R/"
import sys, pathlib
from PIL import Image  # the pictures come back as half-size JPEGs: full-size PNGs passed the device's file limit
for png in pathlib.Path(sys.argv[1]).glob("*.png"):
    im = Image.open(png).convert("RGB")
    im.resize((im.width // 2, im.height // 2)).save(pathlib.Path(sys.argv[2]) / (png.stem + ".jpg"), quality=85)
PY
    else
      python3 -m gof_warp.extract $run > $R/extract.log 2>&1
      "${ev[@]}" --mesh $run/mesh_tetra.ply --json "$R/evaluate_seen.json" > /dev/null 2>&1
      cp $run/mesh_tetra.json "$R/" 2>/dev/null
    fi
    python3 benchmarks/extract/pack_model.py pack $run "$OUT/${name}_geometry.npz" > /dev/null 2>&1
    echo "$name scored at $(( $(date +%s) - t0 )) s"
  ) &
  k=$((k + 1))
done <<< "$RUNS"
wait
for f in $S/*.train.log; do cp "$f" "$OUT/" 2>/dev/null; done
(cd "$OUT" && tar czf hp_results.tgz hp_* ./*.train.log && rm -rf hp_*/ ./*.train.log)
ls -la "$OUT"
