#!/usr/bin/env bash
# Session 18: what `extract --min-views K` (K = 1, GOF's default; 2; 3) changes on one trained synthetic run, scored on
# the region any camera sees (the issue's bar) and on the region at least two see (`evaluate --min-views 2`), on the
# GPU machine:   bash benchmarks/real_captures/min_views_eval.sh SCENE RUN "CROP (6 numbers)"
# The evaluations run at once (the GPU host has 16 cores). Results in $OUT/min_views/; steps already done are skipped.
set -u
scene=$1; run=$2; crop=$3
R=$OUT/min_views; mkdir -p "$R"
for k in 1 2 3; do
  m=$run/mesh_views$k.ply
  [ -f "$m" ] || python3 -m gof_warp.extract "$run" --min-views "$k" --out "$m" --quiet --no-pictures > /dev/null
  cp "${m%.ply}.json" "$R/extract_views$k.json" 2>/dev/null
done
ev() {  # ev NAME MESH ARGS...
  local name=$1 mesh=$2; shift 2
  [ -f "$R/$name.json" ] || python3 -m gof_warp.evaluate --mesh "$mesh" --gt "$scene/gt_mesh.ply" --scene "$scene" \
    --json "$R/$name.json" "$@" > /dev/null 2>&1 || echo "evaluate $name failed"
}
for k in 1 2 3; do
  ev "views${k}_seen1" "$run/mesh_views$k.ply" &
  ev "views${k}_seen2" "$run/mesh_views$k.ply" --min-views 2 &
  # shellcheck disable=SC2086  # the crop is six numbers
  ev "views${k}_crop" "$run/mesh_views$k.ply" --crop $crop &
done
for k in 1 2; do
  [ -f "$R/offsurface_views$k.json" ] || python3 benchmarks/real_captures/seen_offsurface.py "$run/mesh_views$k.ply" "$scene" \
    --out "$R/offsurface_views$k.json" --samples-out "$R/off_views$k.npz" > /dev/null 2>&1 || echo "offsurface $k failed" &
done
wait
python3 - "$R" <<'PY'
import json, sys
from pathlib import Path
for f in sorted(Path(sys.argv[1]).glob("views*.json")):
    d = json.loads(f.read_text()); m = d["metrics"]
    print(f.stem, "F", [round(x, 4) for x in m["fscore"]], "P", round(m["precision"][0], 4), "R", round(m["recall"][0], 4),
          "floor", [round(x, 4) for x in d["floor"]["metrics"]["fscore"]])
for f in sorted(Path(sys.argv[1]).glob("offsurface_*.json")):
    d = json.loads(f.read_text()); print(f.stem, d["precision"], {k: (v["pred_area"], v["off_area"]) for k, v in d["parts"].items()})
PY
