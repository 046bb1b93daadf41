#!/usr/bin/env bash
# DTU scan 24 on a GPU (issue 58): the `dtu` preset with every 8th view held out, extraction with the collision mesh,
# then the textured-mesh fidelity at 1M, 200k and 50k faces. Each step is skipped when its output exists, and a
# training stopped by SIGTERM (a time limit) checkpoints and resumes at the next call.
#   bash benchmarks/texture/dtu_gpu.sh DTU_SCENE ROOT OUT_JSON
set -uo pipefail
scene=${1:?DTU scene folder}; root=${2:?work folder}; out=${3:?fidelity json}
py=${PYTHON:-python}; run=$root/run
mkdir -p "$root"
if [ ! -f "$run/metrics.json" ]; then
  resume=(--overwrite); ls "$run"/checkpoints/ckpt_*.pt >/dev/null 2>&1 && resume=(--resume)
  "$py" -m gof_warp.train "$scene" --config dtu --out "$run" data.test_every=8 "${resume[@]}" --no-pictures \
    >> "$root/train.log" 2>&1 &
  pid=$!; trap 'kill -TERM $pid 2>/dev/null' TERM; wait $pid; wait $pid 2>/dev/null; trap - TERM
  [ -f "$run/metrics.json" ] || exit 3
fi
if [ ! -f "$run/mesh_tetra.ply" ] || [ ! -f "$run/mesh_collision.ply" ]; then
  t0=$SECONDS; "$py" -m gof_warp.extract "$run" --collision > "$root/extract.log" 2>&1 || exit 4
  echo "extract command wall: $((SECONDS - t0)) s" >> "$root/extract.log"
fi
[ -f "$out" ] && grep -q '"bar"' "$out" && exit 0
"$py" benchmarks/texture/texture_fidelity.py "$run" "$out" --full-faces 1000000 --max-faces 200000 50000 \
  --no-variants --device cuda > "$root/fidelity.log" 2>&1
