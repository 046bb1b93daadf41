#!/usr/bin/env bash
# After variants.sh: mesh and score each finished variant of a synthetic scene, all at once on one GPU:
#   bash benchmarks/real_captures/variants_score.sh SCENE "x0 y0 z0 x1 y1 z1" NAME1 NAME2 ...
# For /tmp/variants/NAME: extract (the defaults; it writes the mesh picture), evaluate the seen region and the
# ground-and-objects crop (sampling inside each region, with the exact-vs-exact floor and the ground's completeness
# and flatness). Steps already done are skipped (their output exists). Results next to the variant's in
# $OUT/variants/NAME/; a summary in $OUT/variants/scores.json.
set -u
scene=$1; crop=$2; shift 2
W=/tmp/variants; R=$OUT/variants; mkdir -p "$R"
score() {
  local v=$1 run=$W/$1
  [ -f "$run/metrics.json" ] || { echo "$v: not trained"; return; }
  mkdir -p "$R/$v"
  [ -f "$run/mesh_tetra.ply" ] || python3 -m gof_warp.extract "$run" --quiet > "$run/extract.log" 2>&1
  [ -f "$run/evaluate_seen.json" ] || python3 -m gof_warp.evaluate --mesh "$run/mesh_tetra.ply" --gt "$scene/gt_mesh.ply" \
      --scene "$scene" --json "$run/evaluate_seen.json" > /dev/null 2>&1
  # shellcheck disable=SC2086  # the crop is six separate numbers
  [ -f "$run/evaluate_crop.json" ] || python3 -m gof_warp.evaluate --mesh "$run/mesh_tetra.ply" --gt "$scene/gt_mesh.ply" \
      --scene "$scene" --crop $crop --json "$run/evaluate_crop.json" > /dev/null 2>&1
  for f in mesh_tetra.json extract.log evaluate_seen.json evaluate_crop.json; do
    [ -f "$run/$f" ] && cp "$run/$f" "$R/$v/"
  done
  cp "$run"/pictures/*.png "$R/$v/" 2>/dev/null
}
for v in "$@"; do score "$v" & done
wait
python3 - "$R" "$@" <<'PY'
import json, sys
from pathlib import Path
R = Path(sys.argv[1]); rows = {}
for v in sys.argv[2:]:
    row = {}
    for name in ("evaluate_seen", "evaluate_crop"):
        p = R / v / f"{name}.json"
        if p.is_file():
            d = json.loads(p.read_text())
            m, fl = d["metrics"], d.get("floor", {}).get("metrics", {})
            row[name] = {k: m.get(k) for k in ("chamfer", "accuracy", "completeness", "fscore", "precision", "recall")}
            row[name]["floor_fscore"] = fl.get("fscore")
            g = d.get("ground")
            if g:
                row[name]["ground"] = {k: g.get(k) for k in ("patches", "patches_over_limit", "flat_fraction",
                                                             "height_error_p95")}
    p = R / v / "mesh_tetra.json"
    if p.is_file():
        row["faces"] = sum(m["faces"] for m in json.loads(p.read_text())["meshes"])
    rows[v] = row
(R / "scores.json").write_text(json.dumps(rows, indent=1))
print(json.dumps(rows)[:3000])
PY
