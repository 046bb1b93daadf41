#!/usr/bin/env bash
# Four 30k trainings at once on a several-GPU host, each alone on its own GPU, then their meshes and scores.
# RUNS: "name|scene|overrides[|patch]" a line. Scenes (session 28 on):
#   bgf, bg, def: synthetic background_full, background, default at 400x400 with 100 views, generated on GPU 0; bgf and
#     bg start from points triangulated on the CPU (.s17pts/<preset>/points3d.ply: the GPU machine has no pycolmap);
#   fox, can, dtu: the real captures fox, colmap_can, dtu_scan24, carried in .data/ or parked in /tmp/gofdata
#     (dtu with its triangulation cache, sfm_known_poses/, made on the CPU by the same split `train` uses there: for
#     the dtu preset all 49 views, e.g. `python -m gof_warp.train .data/dtu_scan24 --iterations 1`; the GPU machine
#     has no pycolmap, so a cache made for other views stops the run there).
# patch (optional, session 30): a patch file (relative to the checkout) applied to a private copy of the code that this
# run alone trains with: an A/B of a code change on two GPUs of one host, each alone on its GPU.
#   PHASE=train TRAIN_S=500 bash benchmarks/real_captures/hidden_prune_gpu.sh    # generate, train (resumable)
#   PHASE=score bash benchmarks/real_captures/hidden_prune_gpu.sh                # finish, mesh, score, pack
# bgf, bg: extract --min-views K for each K of VIEWS (default "2"; session 29: "2 3"), each scored on the whole seen
# region and the ground-and-objects crop; def: extract with the defaults, scored on the seen region; fox, can, dtu:
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
for syn in bgf:background_full bg:background def:default; do
  name=${syn%%:*}; preset=${syn#*:}
  grep -q "|$name|" <<< "$RUNS" || continue
  if [ ! -f $S/$name/transforms_train.json ]; then
    python3 -m gof_warp.synthetic --preset $preset --resolution 400 400 --views 100 --out $S/$name --device cuda:0 \
      --force --quiet || { echo "$name generation failed"; exit 1; }
    if [ "$name" != def ]; then
      cp .s17pts/$preset/points3d.ply $S/$name/ || { echo "no triangulated points for $preset in .s17pts"; exit 1; }
    fi
  fi
done
for real in fox:fox can:colmap_can dtu:dtu_scan24; do
  if grep -q "|${real%%:*}|" <<< "$RUNS" && [ ! -d $S/${real%%:*} ]; then
    src=$(ls -d .data/${real#*:} /tmp/gofdata/${real#*:} 2>/dev/null | head -1)
    [ -n "$src" ] && cp -r "$src" $S/${real%%:*} || { echo "${real#*:} in neither .data nor /tmp/gofdata"; exit 1; }
  fi
done
echo "scenes at $(( $(date +%s) - t0 )) s"
k=0
code_for() {  # the code a run trains with: this checkout, or a private copy with its patch applied
  if [ -z "$1" ]; then echo "$PWD"; return; fi
  local dir=/tmp/code_$2
  if [ ! -d $dir ]; then
    cp -r "$PWD" $dir && (cd $dir && patch -p1 -s < "$PWD/$1") || { echo "patch $1 failed" >&2; rm -rf $dir; return 1; }
  fi
  echo $dir
}
while IFS='|' read -r name scene over patch; do
  [ -n "$name" ] || continue
  run=$S/run_$name
  code=$(code_for "${patch:-}" "$name") || exit 1
  if [ ! -f $run/metrics.json ]; then
    # shellcheck disable=SC2086
    (cd "$code" && CUDA_VISIBLE_DEVICES=$k PYTHONPATH="$code:/tmp/site" timeout -s INT -k 30 \
      $((TRAIN_S - $(date +%s) + t0)) python3 -m gof_warp.train $S/$scene --out $run checkpoint_every=1000 $over \
      --resume --quiet) >> $S/$name.train.log 2>&1 &
  fi
  k=$((k + 1))
done <<< "$RUNS"
wait
echo "training phase ended at $(( $(date +%s) - t0 )) s"
for f in $S/*.train.log; do echo "$f: $(grep -h 'done:' "$f" | tail -1)"; done
for r in $S/run_*; do echo "$r: $(ls $r/checkpoints 2>/dev/null | tail -1)"; done
[ "$PHASE" = score ] || exit 0
k=0
while IFS='|' read -r name scene over patch; do
  [ -n "$name" ] || continue
  run=$S/run_$name; R="$OUT/hp_$name"; mkdir -p "$R"
  (
    export CUDA_VISIBLE_DEVICES=$k
    [ -f $run/metrics.json ] || { echo "$name: not trained"; exit 0; }
    cp $run/metrics.json $run/config.yaml "$R/"
    ev=(python3 -m gof_warp.evaluate --gt $S/$scene/gt_mesh.ply --scene $S/$scene)
    if [ "$scene" = bgf ] || [ "$scene" = bg ]; then
      for v in $VIEWS; do
        python3 -m gof_warp.extract $run --min-views $v --out $run/mesh_views$v.ply >> $R/extract.log 2>&1
        "${ev[@]}" --mesh $run/mesh_views$v.ply --json "$R/evaluate_seen_views$v.json" > /dev/null 2>&1
        "${ev[@]}" --mesh $run/mesh_views$v.ply --crop -2 -2 -1.1 2 2 1 --json "$R/evaluate_crop_views$v.json" \
          > /dev/null 2>&1
        cp $run/mesh_views$v.json "$R/" 2>/dev/null
      done
    elif [ "$scene" = fox ] || [ "$scene" = can ] || [ "$scene" = dtu ]; then
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
