#!/usr/bin/env bash
# Volume mesh vs tetra mesh at several voxel sizes on the GPU machine: for each H:STEPS bake RUN's opacity
# field at voxel size H (extract --volume) and score its mesh (STEPS bisection steps) with volume_vs_tetra.py.
# Usage: RUN=path bash benchmarks/warp_embedding/volume_sweep.sh 0.009:4 0.009:8 ...   (JSON to $OUT)
set -u
RUN=${RUN:-.rdef}
for spec in "$@"; do
  IFS=: read -r h steps <<< "$spec"
  python3 -m gof_warp.extract "$RUN" --volume --voxel-size "$h" --no-pictures --quiet > /tmp/vol_$h.log 2>&1 \
    || { tail -5 /tmp/vol_$h.log; continue; }
  python3 benchmarks/warp_embedding/volume_vs_tetra.py "$RUN" --tetra "$RUN/mesh_full.ply" --gt "$RUN/scene/gt_mesh.ply" \
    --nvdb "$RUN/opacity_volume.nvdb" --binary-steps "$steps" --device "${DEVICE:-cuda:0}" --out "$OUT/volume_vs_tetra_${h}_${steps}.json" 2>&1 | tail -1
  python3 -c "import json; r = json.load(open('$OUT/volume_vs_tetra_${h}_${steps}.json')); print('$spec', r['voxel_size'], round(r['chamfer_gap_relative'], 4), r['volume_mesh']['faces'], r.get('bake_time_s'))"
done
